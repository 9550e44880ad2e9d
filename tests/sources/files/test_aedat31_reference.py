"""AEDAT 3.1 files against a decoder written from iniVation's format description.

AEDAT 3.1 (iniVation's format page, libcaer's event layouts): ``#`` header
lines up to ``#!END-HEADER``, then packets, little-endian: a 28-byte header
(int16 type, int16 source, int32 event size, int32 timestamp offset, int32
timestamp overflow, int32 capacity, int32 number, int32 valid), then
``capacity`` events of ``size`` bytes; an event's time is ``overflow << 31``
plus its int32 timestamp (µs).

* special (type 0, 8 bytes): uint32 (bit 0 valid, bits 1-7 the special
  type, bits 8-31 data), int32 timestamp;
* polarity (type 1, 8 bytes): uint32 (bit 0 valid, bit 1 polarity, bits 2-16
  y, bits 17-31 x), int32 timestamp;
* frame (type 2, 36 bytes + 2 bytes per pixel of the largest frame): uint32
  info (bit 0 valid, bits 1-3 colour channels, bits 4-6 colour filter,
  bits 7-13 ROI), int32 start and end of frame, start and end of exposure,
  size x, size y, position x, position y, then the uint16 pixels row by row;
* IMU6 (type 3, 36 bytes): uint32 info (bit 0 valid), int32 timestamp,
  float32 accel x, y, z (g), gyro x, y, z (°/s), temperature (°C).

:func:`reference` decodes a file's bytes the slow, obvious way with tectum's
conventions (invalid events skipped; special types 0 timestamp wrap and 5
row-only are bookkeeping; a trigger's channel is its special type, its value
0 for a falling edge (type 3), else 1; a frame's time is mid-exposure;
accelerations in m/s², rotation rates in rad/s; other packet types
skipped). Hypothesis draws packets of every kind (valid and invalid events,
frames of one to four channels and varying sizes, another packet type)
across timestamp overflows; the reference must read what was meant, and
tectum's reader the same values: every event's t, x, y, p, every trigger,
IMU sample and frame (time, exposure, position, pixels).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FramePacket, ImuPacket, TriggerPacket
from tectum.sources.files.aedat31 import Aedat31Source

HEADER = b"#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: DAVIS346\r\n#!END-HEADER\r\n"
W, H = 346, 260
G = 9.80665


def reference(raw: bytes) -> dict[str, list]:
    """Every stream's samples, as tuples, from an AEDAT 3.1 file's bytes."""
    out: dict[str, list] = {"events": [], "triggers": [], "imu": [], "frames": []}
    pos = raw.index(b"#!END-HEADER\r\n") + len(b"#!END-HEADER\r\n")
    while pos < len(raw):
        kind, _, size, _, overflow, capacity, number, _ = struct.unpack_from("<hhiiiiii", raw, pos)
        base = overflow << 31
        for k in range(number):
            at = pos + 28 + k * size
            info = struct.unpack_from("<I", raw, at)[0]
            if not info & 1:
                continue
            if kind == 0:
                special, t = (info >> 1) & 0x7F, struct.unpack_from("<i", raw, at + 4)[0]
                if special not in (0, 5):
                    out["triggers"].append((base + t, special, 0 if special == 3 else 1))
            elif kind == 1:
                t = struct.unpack_from("<i", raw, at + 4)[0]
                out["events"].append((base + t, info >> 17, (info >> 2) & 0x7FFF, 1 if info >> 1 & 1 else -1))
            elif kind == 3:
                t, *v = struct.unpack_from("<i7f", raw, at + 4)
                out["imu"].append((base + t, *(a * G for a in v[0:3]), *(np.radians(g) for g in v[3:6]), v[6]))
            elif kind == 2:
                _, _, e0, e1, w, h, px, py = struct.unpack_from("<8i", raw, at + 4)
                ch = (info >> 1) & 7
                pixels = struct.unpack_from(f"<{w * h * ch}H", raw, at + 36)
                out["frames"].append((base + (e0 + e1) // 2, base + e0, base + e1, px, py, pixels))
        pos += 28 + capacity * size
    return out


@st.composite
def files(draw: st.DrawFn) -> tuple[bytes, dict[str, list]]:
    """(file bytes, what was meant)."""
    clock = draw(st.one_of(st.integers((1 << 31) - 3000, (1 << 31) - 1), st.integers(0, 1 << 40)))
    body = b""
    meant: dict[str, list] = {"events": [], "triggers": [], "imu": [], "frames": []}

    def packet(kind: int, size: int, events: list[bytes], overflow: int) -> bytes:
        spare = draw(st.integers(0, 2))  # capacity beyond the events: zero bytes
        head = struct.pack("<hhiiiiii", kind, 1, size, 4, overflow, len(events) + spare, len(events), len(events))
        return head + b"".join(e.ljust(size, b"\0") for e in events) + b"\0" * size * spare

    for _ in range(draw(st.integers(1, 10))):
        kind = draw(st.sampled_from(["polarity", "polarity", "special", "imu", "frame", "other"]))
        clock += draw(st.integers(0 if kind == "polarity" else 1, 3000))
        overflow, events = clock >> 31, []
        for _ in range(draw(st.integers(1, 12))):
            if (clock >> 31) != overflow or (clock + 100) >> 31 != overflow:
                break  # one packet, one overflow
            valid = draw(st.integers(0, 4)) > 0
            t = clock & 0x7FFFFFFF
            if kind == "polarity":
                x, y, on = draw(st.integers(0, W - 1)), draw(st.integers(0, H - 1)), draw(st.booleans())
                events.append(struct.pack("<Ii", int(valid) | int(on) << 1 | y << 2 | x << 17, t))
                if valid:
                    meant["events"].append((clock, x, y, 1 if on else -1))
            elif kind == "special":
                special = draw(st.sampled_from([0, 1, 2, 3, 4, 5, 6, 9]))
                events.append(struct.pack("<Ii", int(valid) | special << 1 | draw(st.integers(0, 0xFFFFFF)) << 8, t))
                if valid and special not in (0, 5):
                    meant["triggers"].append((clock, special, 0 if special == 3 else 1))
            elif kind == "imu":
                v = [draw(st.floats(-100, 100, width=32)) for _ in range(7)]
                events.append(struct.pack("<Ii7f", int(valid), t, *v))
                if valid:
                    meant["imu"].append((clock, *(a * G for a in v[0:3]), *(np.radians(g) for g in v[3:6]), v[6]))
            elif kind == "frame":
                w, h, ch = draw(st.integers(1, 4)), draw(st.integers(1, 3)), draw(st.sampled_from([1, 3, 4]))
                pixels = draw(st.lists(st.integers(0, 65535), min_size=w * h * ch, max_size=w * h * ch))
                e0, e1 = t + 1, t + 1 + draw(st.integers(0, 50))
                px, py = draw(st.integers(0, 300)), draw(st.integers(0, 200))
                info = int(valid) | ch << 1 | draw(st.integers(0, 7)) << 4 | draw(st.integers(0, 127)) << 7
                events.append(struct.pack(f"<I8i{len(pixels)}H", info, t, e1 + 1, e0, e1, w, h, px, py, *pixels))
                if valid:
                    hi = overflow << 31
                    meant["frames"].append((hi + (e0 + e1) // 2, hi + e0, hi + e1, px, py, tuple(pixels)))
                clock += e1 + 1 - t
            else:
                events.append(draw(st.binary(min_size=8, max_size=8)))
            clock += draw(st.integers(0 if kind == "polarity" else 1, 40))
        if not events:
            continue
        if kind == "frame":
            body += packet(2, 36 + 2 * 4 * 3 * 4, events, overflow)
        else:
            body += packet({"polarity": 1, "special": 0, "imu": 3, "other": 5}[kind],
                           36 if kind == "imu" else 8, events, overflow)
    return HEADER + body, meant


def read(path: Path) -> dict[str, list]:
    out: dict[str, list] = {"events": [], "triggers": [], "imu": [], "frames": []}
    for q in Aedat31Source(str(path)).packets():
        if isinstance(q, EventPacket):
            out["events"] += zip(*(getattr(q, c).tolist() for c in "txyp"))
        elif isinstance(q, TriggerPacket):
            out["triggers"] += zip(q.t.tolist(), q.data["channel"].tolist(), q.data["value"].tolist())
        elif isinstance(q, ImuPacket):
            out["imu"] += [(t, *a, *g, c) for t, a, g, c in zip(q.t.tolist(), q.data["accel"].tolist(),
                                                                 q.data["gyro"].tolist(),
                                                                 q.data["temperature"].tolist())]
        elif isinstance(q, FramePacket):
            out["frames"] += [(t, s, e, int(p[0]), int(p[1]), tuple(np.asarray(im).ravel().tolist()))
                              for t, s, e, p, im in zip(q.t.tolist(), q.data["exposure_start"].tolist(),
                                                        q.data["exposure_end"].tolist(), q.data["position"],
                                                        q.images)]
    return out


def same(got: dict[str, list], want: dict[str, list]) -> None:
    for key in ("events", "triggers", "frames"):
        assert got[key] == want[key], key
    assert len(got["imu"]) == len(want["imu"])
    if want["imu"]:
        np.testing.assert_allclose(np.array(got["imu"]), np.array(want["imu"]), rtol=1e-12, atol=0)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=files())
def test_aedat31_equals_the_reference(tmp_path: Path, case: tuple) -> None:
    raw, meant = case
    same(reference(raw), meant)  # the reference reads what was meant
    path = tmp_path / "r.aedat"
    path.write_bytes(raw)
    same(read(path), meant)
