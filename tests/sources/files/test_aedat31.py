"""AEDAT 3.1 packets built byte by byte from libcaer's layouts: polarity
events, special events, frames (grey and RGB, an invalid one skipped, an
oversized one named) and IMU6 samples, with the timestamp overflow applied."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from tectum import EventPacket, FormatError, FramePacket, ImuPacket, TriggerPacket, concat
from tectum.sources.files.aedat31 import Aedat31Source

OVF = 3  # packets' timestamp overflow: times are offset by 3 << 31 µs
HEADER = b"#!AER-DAT3.1\r\n#Source 1: DAVIS346\r\n#!END-HEADER\r\n"


def _packet(etype: int, size: int, events: list[bytes]) -> bytes:
    head = struct.pack("<hhiiiiii", etype, 1, size, 4, OVF, len(events), len(events), len(events))
    return head + b"".join(e.ljust(size, b"\0") for e in events)


def _frame(valid: bool, channels: int, w: int, h: int, exposure: tuple[int, int], pixels: np.ndarray) -> bytes:
    info = int(valid) | (channels << 1)
    head = struct.pack("<Iiiiiiiii", info, exposure[0] - 5, exposure[1] + 5, *exposure, w, h, 7, 9)
    return head + pixels.astype("<u2").tobytes()


def _file(path: Path, frames: list[bytes], frame_size: int) -> Path:
    pol = [struct.pack("<Ii", 1 | (1 << 1) | (2 << 2) | (3 << 17), 100),
           struct.pack("<Ii", 1 | (4 << 2) | (5 << 17), 200)]
    imu = [struct.pack("<Ii7f", 1, 150, 0.0, 0.0, -1.0, 90.0, 0.0, 0.0, 25.0)]
    special = [struct.pack("<Ii", 1 | (2 << 1) | (17 << 8), 110), struct.pack("<Ii", 1 | (0 << 1), 111),
               struct.pack("<Ii", 1 | (3 << 1), 160)]  # rising edge, a timestamp wrap (skipped), falling edge
    path.write_bytes(HEADER + _packet(1, 8, pol) + _packet(0, 8, special)
                     + _packet(2, frame_size, frames) + _packet(3, 36, imu))
    return path


def _read(path: Path, **kw) -> dict:
    out: dict = {}
    for q in Aedat31Source(str(path), **kw).packets():
        out.setdefault(type(q), []).append(q)
    return out


def test_events_frames_and_imu(tmp_path: Path) -> None:
    grey = np.arange(12).reshape(3, 4) * 1000
    rgb = np.arange(36).reshape(3, 4, 3)
    size = 36 + 2 * 4 * 3 * 3
    frames = [_frame(True, 1, 4, 3, (120, 140), grey), _frame(False, 1, 4, 3, (150, 160), grey),
              _frame(True, 1, 4, 3, (170, 190), grey + 1), _frame(True, 3, 4, 3, (210, 230), rgb)]
    got = _read(_file(tmp_path / "a.aedat", frames, size))
    base = OVF << 31
    ev = concat(got[EventPacket])
    assert ev.t.tolist() == [base + 100, base + 200] and ev.x.tolist() == [3, 5] and ev.p.tolist() == [1, -1]
    grey_run, rgb_run = got[FramePacket]
    assert grey_run.t.tolist() == [base + 130, base + 180] and rgb_run.t.tolist() == [base + 220]
    assert grey_run.images.dtype == np.uint16 and np.array_equal(grey_run.images, np.stack([grey, grey + 1]))
    assert np.array_equal(rgb_run.images[0], rgb) and grey_run.data["position"].tolist() == [[7, 9], [7, 9]]
    assert grey_run.data["exposure_start"].tolist() == [base + 120, base + 170]
    trig = got[TriggerPacket][0]
    assert trig.t.tolist() == [base + 110, base + 160] and trig.data["channel"].tolist() == [2, 3]
    assert trig.data["value"].tolist() == [1, 0]
    imu = got[ImuPacket][0]
    assert imu.t.tolist() == [base + 150] and np.allclose(imu.accel, [[0, 0, -9.80665]])
    assert np.allclose(imu.gyro, [[np.pi / 2, 0, 0]])


def test_frame_larger_than_its_event_is_named(tmp_path: Path) -> None:
    frames = [_frame(True, 1, 40, 30, (120, 140), np.zeros(12))]  # 40x30 pixels declared, room for 4x3
    f = _file(tmp_path / "b.aedat", frames, 36 + 2 * 12)
    with pytest.raises(FormatError, match="do not fit") as e:
        _read(f)
    assert e.value.offset == len(HEADER) + 28 + 16 + 28 + 24 + 28  # the frame packet's first event
    got = _read(f, skip_bad=True)
    assert FramePacket not in got and len(concat(got[EventPacket])) == 2
