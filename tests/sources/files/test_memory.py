"""Streaming keeps memory flat: reading a file several times larger than the
chunk size does not grow the process's resident memory with the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tectum import EventPacket
from tectum.sources.files import open_file

psutil = pytest.importorskip("psutil", reason="psutil not installed")


def _write(sink, chunks: int, n: int = 1_000_000) -> None:
    """``chunks`` x ``n`` random events, 1 s each, through ``sink``."""
    sink.open()
    rng = np.random.default_rng(0)
    t0 = 0
    for _ in range(chunks):
        t = t0 + np.sort(rng.integers(0, 1_000_000, n))
        sink.write(EventPacket(t.astype(np.int64), rng.integers(0, 640, n).astype(np.uint16),
                               rng.integers(0, 480, n).astype(np.uint16), np.ones(n, np.int8),
                               sensor=(640, 480), t_start=t0, t_end=t0 + 1_000_000))
        t0 += 1_000_000
    sink.close()


@pytest.mark.parametrize("fmt, chunks", [("evt2", 40), ("aedat4", 24)])  # 40 M events, ~170 MB; 24 M, ~330 MB
def test_peak_rss_stays_flat(tmp_path: Path, fmt: str, chunks: int) -> None:
    """The AEDAT 4.0 reader decodes on worker threads into pooled buffers:
    memory stays bounded by its read and run sizes too."""
    from tectum.sinks.files import SINKS

    f = tmp_path / f"big.{fmt}"
    _write(next(c for c in SINKS if c.name == fmt)(str(f)), chunks)
    n = 1_000_000
    proc = psutil.Process()
    src = open_file(str(f), chunk_bytes=1 << 22)
    base = proc.memory_info().rss
    peak = base
    total = 0
    for pkt in src.packets():
        total += len(pkt)
        peak = max(peak, proc.memory_info().rss)
    assert total == chunks * n
    assert peak - base < 120 * 2**20, f"RSS grew by {(peak - base) / 2**20:.0f} MiB reading a {f.stat().st_size >> 20} MiB file"


def _write_big_evt2(path: Path, n_chunks: int, words_per_chunk: int = 1 << 24) -> int:
    """A RAW EVT 2.0 file of ``n_chunks`` x 64 MiB, fast: one template chunk of
    groups [EV_TIME_HIGH, 63 CD events], its TIME_HIGH words shifted per
    chunk. Returns the number of events."""
    g = words_per_chunk // 64
    rng = np.random.default_rng(0)
    tmpl = np.empty((g, 64), np.uint32)
    lsb = np.arange(63, dtype=np.uint32)
    x = rng.integers(0, 640, (g, 63)).astype(np.uint32)
    y = rng.integers(0, 480, (g, 63)).astype(np.uint32)
    tmpl[:, 1:] = ((lsb & 1) << 28) | (lsb << 22) | (x << 11) | y
    high = np.arange(g, dtype=np.uint32)
    with open(path, "wb") as f:
        f.write(b"% evt 2.0\n% format EVT2\n% geometry 640x480\n% end\n")
        for c in range(n_chunks):
            tmpl[:, 0] = (8 << 28) | (high + c * g)
            f.write(tmpl.tobytes())
    return n_chunks * g * 63


def test_multi_gb_evt2_peak_rss_flat(tmp_path: Path) -> None:
    """The issue's check: a >= 2 GiB file streams with flat memory (RSS
    growth bounded by the chunk size and the column pool, not the file)."""
    import os
    import shutil

    n_chunks = 32  # 32 x 64 MiB = 2 GiB
    size = n_chunks << 26
    if os.environ.get("TECTUM_SKIP_BIG"):
        pytest.skip("TECTUM_SKIP_BIG is set: multi-GB file test skipped")
    free = shutil.disk_usage(tmp_path).free
    if free < 3 * size:
        pytest.skip(f"needs {3 * size >> 20} MiB free in {tmp_path}, has {free >> 20} MiB")
    f = tmp_path / "big2g.raw"
    try:
        n = _write_big_evt2(f, n_chunks)
        assert f.stat().st_size >= 2 << 30
        proc = psutil.Process()
        src = open_file(str(f))
        base = proc.memory_info().rss
        peak, total, last = base, 0, -1
        for k, pkt in enumerate(src.packets()):
            total += len(pkt)
            if len(pkt):
                assert int(pkt.t[0]) >= last
                last = int(pkt.t[-1])
            if k % 8 == 0:
                peak = max(peak, proc.memory_info().rss)
        peak = max(peak, proc.memory_info().rss)
        assert total == n
        assert peak - base < 150 * 2**20, f"RSS grew by {(peak - base) / 2**20:.0f} MiB reading a 2 GiB file"
    finally:
        f.unlink(missing_ok=True)
