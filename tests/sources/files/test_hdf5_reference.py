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

import numpy as np
import pytest

from tectum import EventPacket
from tectum.sources.files.hdf5 import Hdf5Source

h5py = pytest.importorskip("h5py")


def test_an_events_dataset_at_the_root(tmp_path: Path) -> None:
    """An MVSEC-style ``(N, 4)`` dataset named ``events`` at the root is read
    as such (it was taken for a DSEC group and failed inside h5py)."""
    path = tmp_path / "e.h5"
    with h5py.File(path, "w") as h:
        h["events"] = np.array([[3.0, 4.0, 0.000007, 1.0], [5.0, 6.0, 0.0000125, -1.0]])
    got = [e for q in Hdf5Source(str(path)).packets() if isinstance(q, EventPacket)
           for e in zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), q.p.tolist())]
    assert got == [(7, 3, 4, 1), (12, 5, 6, -1)]  # 12.5 µs: numpy rounds half to even
