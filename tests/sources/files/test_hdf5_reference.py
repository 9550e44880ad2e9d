"""HDF5 event layouts against h5py's datasets read whole and the layouts as
``sources/files/hdf5.py`` describes them.

Hypothesis draws a file: DSEC (``events/{t,x,y,p}`` of drawn integer types,
p 0/1 or bool, with or without ``t_offset`` (µs, added to t), ``ms_to_idx``
and a ``sensor`` attribute on the root or the events group) or MVSEC-style
(an ``(N, 4)`` float dataset of x, y, t in seconds, p -1/1, under a drawn
group path), chunked and compressed or not, read in drawn chunk sizes and
time windows. The reference reads each dataset whole with h5py and applies
the layout's rules; tectum's events must equal it value by value, and the
sensor be the attribute or the coordinates' extent.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum import EventPacket
from tectum.sources.files._common import FROM_EXTENT
from tectum.sources.files.hdf5 import Hdf5Source

h5py = pytest.importorskip("h5py")


def reference(path: Path, apply_t0: bool, lo: int | None, hi: int | None) -> tuple[list, tuple[int, int] | None]:
    """(events (t, x, y, p) in [lo, hi), the sensor attribute or None)."""
    with h5py.File(path, "r") as h:
        sensor = None
        for obj in (h, h.get("events")):
            if obj is not None and "sensor" in obj.attrs:
                sensor = tuple(int(v) for v in obj.attrs["sensor"])
        if "events" in h and isinstance(h["events"], h5py.Group):
            ev = h["events"]
            off = int(h["t_offset"][()]) if "t_offset" in h and apply_t0 else 0
            t, x, y, p = (ev[k][()] for k in "txyp")
            rows = [(int(a) + off, int(b), int(c), 1 if d > 0 else -1) for a, b, c, d in zip(t, x, y, p)]
        else:
            found: list[Any] = []
            h.visititems(lambda name, o: found.append(o) if name.endswith("events") and getattr(o, "ndim", 0) == 2
                         else None)
            a = found[0][()].astype(np.float64)
            rows = [(int(np.round(r[2] * 1e6)), int(r[0]), int(r[1]), 1 if r[3] > 0 else -1) for r in a]
    return [e for e in rows if (lo is None or e[0] >= lo) and (hi is None or e[0] < hi)], sensor


@st.composite
def files(draw: st.DrawFn) -> dict[str, Any]:
    n = draw(st.integers(1, 80))
    rel = np.cumsum(draw(st.lists(st.integers(0, 700), min_size=n, max_size=n)), dtype=np.int64)
    x = np.array(draw(st.lists(st.integers(0, 345), min_size=n, max_size=n)))
    y = np.array(draw(st.lists(st.integers(0, 259), min_size=n, max_size=n)))
    on = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    compression = draw(st.sampled_from([None, "gzip", "lzf"]))
    chunks = draw(st.sampled_from([None, 7, 32])) if compression is None else draw(st.sampled_from([True, 7, 32]))
    return dict(layout=draw(st.sampled_from(["dsec", "mvsec"])), rel=rel, x=x, y=y, on=on,
                t_offset=draw(st.one_of(st.none(), st.integers(0, 10**12))),
                ms_to_idx=draw(st.booleans()), sensor_at=draw(st.sampled_from([None, "/", "events"])),
                t_type=draw(st.sampled_from(["u4", "i8", "u8"])), xy_type=draw(st.sampled_from(["u2", "i4", "u4"])),
                p_type=draw(st.sampled_from(["u1", "i1", "?"])), group=draw(st.sampled_from(["davis/left", "", "a"])),
                float_type=draw(st.sampled_from(["f8", "f4"])), t0_s=draw(st.sampled_from([0.0, 1.25, 1_500_000_000.0])),
                compression=compression, chunks=chunks)


def write(path: Path, d: dict[str, Any]) -> Path:
    c = d["chunks"] if not isinstance(d["chunks"], int) or d["chunks"] is True else min(d["chunks"], len(d["rel"]))
    kw: dict[str, Any] = dict(compression=d["compression"], chunks=c)
    with h5py.File(path, "w") as h:
        if d["layout"] == "dsec":
            g = h.create_group("events")
            g.create_dataset("t", data=d["rel"].astype(d["t_type"]), **kw)
            g.create_dataset("x", data=d["x"].astype(d["xy_type"]), **kw)
            g.create_dataset("y", data=d["y"].astype(d["xy_type"]), **kw)
            g.create_dataset("p", data=d["on"].astype(d["p_type"]), **kw)
            if d["t_offset"] is not None:
                h["t_offset"] = np.int64(d["t_offset"])
            if d["ms_to_idx"]:  # index of the first event at or after each millisecond (relative time)
                h["ms_to_idx"] = np.searchsorted(d["rel"], np.arange(int(d["rel"][-1]) // 1000 + 2) * 1000).astype(
                    np.uint64)
            if d["sensor_at"] is not None:
                h[d["sensor_at"]].attrs["sensor"] = np.array([346, 260])
        else:
            a = np.stack([d["x"], d["y"], d["t0_s"] + d["rel"] / 1e6, np.where(d["on"], 1.0, -1.0)], axis=1)
            g = h.require_group(d["group"]) if d["group"] else h
            if isinstance(c, int) and c is not True:
                kw["chunks"] = (c, 4)
            g.create_dataset("events", data=a.astype(d["float_type"]), **kw)
            h.create_dataset("image_raw_events", data=np.zeros(3))  # a decoy: not (N, 4)
    return path


@settings(max_examples=60, deadline=None)
@given(d=files(), chunk=st.sampled_from([64, 200, 1 << 20]), window=st.booleans(), apply_t0=st.booleans(),
       cut=st.tuples(st.floats(0, 1), st.floats(0, 1)))
def test_hdf5_equals_h5py(tmp_path_factory: pytest.TempPathFactory, d: dict[str, Any], chunk: int, window: bool,
                          apply_t0: bool, cut: tuple[float, float]) -> None:
    path = write(tmp_path_factory.mktemp("h5") / "e.h5", d)
    everything, sensor = reference(path, apply_t0, None, None)
    lo = hi = None
    if window:
        ts = [e[0] for e in everything]
        lo, hi = sorted(int(ts[0] + c * (ts[-1] - ts[0] + 2)) for c in cut)
    want, sensor = reference(path, apply_t0, lo, hi)
    src = Hdf5Source(str(path), chunk_bytes=chunk, t_start_us=lo, t_end_us=hi, apply_t0=apply_t0)
    pkts = [q for q in src.packets() if isinstance(q, EventPacket)]
    got = [e for q in pkts for e in zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), q.p.tolist())]
    assert got == want
    extent = (max(e[1] for e in everything) + 1, max(e[2] for e in everything) + 1)
    assert {q.sensor for q in pkts} <= {sensor or extent}
    assert src.sensor_from == (None if sensor else FROM_EXTENT)


def test_an_events_dataset_at_the_root(tmp_path: Path) -> None:
    """An MVSEC-style ``(N, 4)`` dataset named ``events`` at the root is read
    as such (it was taken for a DSEC group and failed inside h5py)."""
    path = tmp_path / "e.h5"
    with h5py.File(path, "w") as h:
        h["events"] = np.array([[3.0, 4.0, 0.000007, 1.0], [5.0, 6.0, 0.0000125, -1.0]])
    got = [e for q in Hdf5Source(str(path)).packets() if isinstance(q, EventPacket)
           for e in zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), q.p.tolist())]
    assert got == [(7, 3, 4, 1), (12, 5, 6, -1)]  # 12.5 µs: numpy rounds half to even


def test_float32_seconds_convert_in_double(tmp_path: Path) -> None:
    """An MVSEC-style float32 dataset: each stored time, exactly as stored,
    to the nearest µs (computed in float32, 1.5e9 s came out 14 s late)."""
    path = tmp_path / "e.h5"
    t = np.array([1.5e9, 1.5e9 + 256], np.float32)
    with h5py.File(path, "w") as h:
        h["davis/events"] = np.stack([[1, 2], [3, 4], t, [1, -1]], axis=1).astype(np.float32)
    got = [int(v) for q in Hdf5Source(str(path)).packets() if isinstance(q, EventPacket) for v in q.t]
    assert got == [int(np.round(float(v) * 1e6)) for v in t] == [1_500_000_000_000_000, 1_500_000_256_000_000]
