"""LZ4 AEDAT 4.0 packets read with numba's JIT disabled (the coverage run).

The compiled LZ4 path calls liblz4 through a numba intrinsic, which has no
plain-Python form: with ``NUMBA_DISABLE_JIT=1`` the reader must take the
Python path (``lz4.block``/``lz4.frame``). A file written by tectum's own
writer, events, IMU samples and a frame, LZ4-compressed, is read in a
subprocess with the JIT disabled and compared value by value with what was
written.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tectum import EventPacket, FramePacket, ImuPacket
from tectum.sinks.files.aedat4 import write_aedat4

pytest.importorskip("lz4")

READ = """
import json, sys
import numpy as np
from tectum import EventPacket, FramePacket, ImuPacket
from tectum.sources.files import _lz4
from tectum.sources.files.aedat4 import Aedat4Source
pkts = list(Aedat4Source(sys.argv[1]).packets())
def cat(kind, col):
    return np.concatenate([np.asarray(getattr(q, col) if col in "txyp" else q.data[col]).ravel()
                           for q in pkts if isinstance(q, kind) and len(q)]).tolist()
print(json.dumps({"available": _lz4.AVAILABLE, **{c: cat(EventPacket, c) for c in "txyp"},
                  "imu_t": cat(ImuPacket, "t"), "gyro": cat(ImuPacket, "gyro"),
                  "frame_t": cat(FramePacket, "t"),
                  "pixels": [int(v) for q in pkts if isinstance(q, FramePacket) for v in q.images[0].ravel()]}))
"""


def test_lz4_aedat4_reads_with_the_jit_disabled(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    n = 300
    t = np.cumsum(rng.integers(0, 20, n)) + 1000
    ev = EventPacket.from_arrays(t, rng.integers(0, 346, n), rng.integers(0, 260, n), rng.choice([-1, 1], n),
                                 sensor=(346, 260), t_start=1000, t_end=int(t[-1]) + 1)
    gyro = rng.normal(size=(5, 3))
    imu = ImuPacket(np.arange(5, dtype=np.int64) * 100 + 1000, accel=rng.normal(size=(5, 3)), gyro=gyro,
                    t_start=1000, t_end=int(t[-1]) + 1)
    img = rng.integers(0, 256, (1, 3, 5), dtype=np.uint8)
    fr = FramePacket(np.array([1500], np.int64), images=img, t_start=1000, t_end=int(t[-1]) + 1)
    path = tmp_path / "lz4.aedat4"
    write_aedat4(str(path), [ev, imu, fr], compression="lz4")
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    out = subprocess.run([sys.executable, "-c", READ, str(path)], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout)
    assert got["available"] is False
    for c in "txyp":
        assert got[c] == getattr(ev, c).tolist(), c
    assert got["imu_t"] == imu.t.tolist()
    np.testing.assert_allclose(got["gyro"], gyro.ravel(), rtol=1e-6)
    assert got["frame_t"] == [1500]
    assert got["pixels"] == img.ravel().tolist()
