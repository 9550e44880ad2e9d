"""The sample streams of a tectum HDF5 file (frames, IMU, triggers, poses
beside the DSEC events), read back value by value: every field of every
sample, a stream of ticks only, a time range clipping the packets, and the
damaged layouts (a field whose rows differ from ``t``, an unknown kind,
fields a packet refuses) named as FormatErrors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tectum import EventPacket, FormatError, FramePacket, ImuPacket, PosePacket, TriggerPacket
from tectum.sinks.files._common import write_all
from tectum.sinks.files.hdf5 import Hdf5Sink
from tectum.sources.files.hdf5 import Hdf5Source

h5py = pytest.importorskip("h5py")
FIELDS = {ImuPacket: ("accel", "gyro", "temperature"), FramePacket: ("images", "exposure_start"),
          TriggerPacket: ("channel", "value"), PosePacket: ("position", "orientation")}


def written(t0: int = 1_000) -> list:
    rng = np.random.default_rng(7)
    out: list = []
    for k in range(3):  # three windows of 1000 µs
        a, b = t0 + 1000 * k, t0 + 1000 * (k + 1)
        t = np.sort(rng.integers(a, b, 20))
        out.append(EventPacket.from_arrays(t, rng.integers(0, 64, 20), rng.integers(0, 48, 20),
                                           rng.choice([-1, 1], 20), sensor=(64, 48), t_start=a, t_end=b))
        ts = np.array([a + 100, a + 600], np.int64)
        out.append(ImuPacket(ts, accel=rng.normal(size=(2, 3)), gyro=rng.normal(size=(2, 3)),
                             temperature=rng.normal(size=2), t_start=a, t_end=b))
        out.append(FramePacket(ts[:1], images=rng.integers(0, 255, (1, 4, 5), dtype=np.uint8),
                               exposure_start=ts[:1] - 50, t_start=a, t_end=b))
        q = rng.normal(size=(2, 4))
        out.append(PosePacket(ts, position=rng.normal(size=(2, 3)),
                              orientation=q / np.linalg.norm(q, axis=1, keepdims=True), t_start=a, t_end=b))
        out.append(TriggerPacket.empty(a, b))  # ticks only
    return out


def read(path: Path, **kw) -> dict[type, list]:
    out: dict[type, list] = {}
    for q in Hdf5Source(str(path), **kw).packets():
        out.setdefault(type(q), []).append(q)
    return out


def columns(pkts: list, name: str) -> np.ndarray:
    return np.concatenate([np.asarray(q.t if name == "t" else q.data[name]) for q in pkts])


@pytest.mark.parametrize("window", [None, (1_650, 3_150)], ids=["whole", "clipped"])
def test_sample_streams_equal_what_was_written(tmp_path: Path, window: tuple[int, int] | None) -> None:
    path = tmp_path / "s.h5"
    pkts = written()
    write_all(Hdf5Sink(str(path)), pkts)
    kw = {} if window is None else {"t_start_us": window[0], "t_end_us": window[1]}
    got = read(path, **kw)
    lo, hi = window or (0, 1 << 62)
    for cls, names in FIELDS.items():
        want = [q for q in pkts if isinstance(q, cls)]
        keep = (columns(want, "t") >= lo) & (columns(want, "t") < hi)
        have = got.get(cls, [])
        if cls is TriggerPacket:  # ticks: no samples, the interval still covered
            assert sum(len(q) for q in have) == 0
            assert have[0].t_start == (1_000 if window is None else lo)
            assert have[-1].t_end == (4_000 if window is None else hi)
            continue
        assert columns(have, "t").tolist() == columns(want, "t")[keep].tolist(), cls
        for name in names:
            np.testing.assert_array_equal(columns(have, name), columns(want, name)[keep], err_msg=f"{cls} {name}")
        assert all(lo <= q.t_start and q.t_end <= hi for q in have)
        assert all(a.t_end <= b.t_start for a, b in zip(have, have[1:]))


def test_times_relative_to_the_file_offset(tmp_path: Path) -> None:
    """``apply_t0=False``: events and samples alike count from the file's ``t_offset``."""
    path = tmp_path / "o.h5"
    pkts = written(t0=5_000_000)
    write_all(Hdf5Sink(str(path)), pkts)
    with h5py.File(path, "r") as h:
        off = int(h["t_offset"][()])
    assert off > 0
    got = read(path, apply_t0=False)
    for cls in (EventPacket, ImuPacket, PosePacket):
        want = columns([q for q in pkts if isinstance(q, cls)], "t") if cls is not EventPacket else \
            np.concatenate([q.t for q in pkts if isinstance(q, EventPacket)])
        have = np.concatenate([q.t for q in got[cls]])
        assert have.tolist() == (want - off).tolist(), cls


@pytest.mark.parametrize("damage,message", [
    (lambda h: (h["imu"].__delitem__("gyro"), h["imu"].create_dataset("gyro", data=np.zeros((5, 3)))),
     r"/imu/gyro has shape \(5, 3\), /imu/t has 6 rows"),
    (lambda h: h["poses"].attrs.__setitem__("kind", "no_such_kind"), "no_such_kind"),
    (lambda h: (h["imu"].__delitem__("accel"), h["imu"].create_dataset("accel", data=np.zeros((6, 2)))),
     "imu"),
], ids=["rows", "kind", "fields"])
def test_damaged_sample_groups_are_named(tmp_path: Path, damage, message: str) -> None:
    path = tmp_path / "d.h5"
    write_all(Hdf5Sink(str(path)), written())
    with h5py.File(path, "r+") as h:
        damage(h)
    with pytest.raises(FormatError, match=message):
        read(path)
