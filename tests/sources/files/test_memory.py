"""Streaming keeps memory flat: reading a file several times larger than the
chunk size does not grow the process's resident memory with the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tectum import EventPacket
from tectum.sinks.files.prophesee import Evt2Sink
from tectum.sources.files import open_file

psutil = pytest.importorskip("psutil", reason="psutil not installed")


def test_evt2_peak_rss_stays_flat(tmp_path: Path) -> None:
    f = tmp_path / "big.raw"
    sink = Evt2Sink(str(f))
    sink.open()
    rng = np.random.default_rng(0)
    n, t0 = 1_000_000, 0
    for _ in range(40):  # 40 M events, ~170 MB on disk
        t = t0 + np.sort(rng.integers(0, 1_000_000, n))
        sink.write(EventPacket(t.astype(np.int64), rng.integers(0, 640, n).astype(np.uint16),
                               rng.integers(0, 480, n).astype(np.uint16), np.ones(n, np.int8),
                               sensor=(640, 480), t_start=t0, t_end=t0 + 1_000_000))
        t0 += 1_000_000
    sink.close()
    proc = psutil.Process()
    src = open_file(str(f), chunk_bytes=1 << 22)
    base = proc.memory_info().rss
    peak = base
    total = 0
    for pkt in src.packets():
        total += len(pkt)
        peak = max(peak, proc.memory_info().rss)
    assert total == 40 * n
    assert peak - base < 120 * 2**20, f"RSS grew by {(peak - base) / 2**20:.0f} MiB reading a {f.stat().st_size >> 20} MiB file"
