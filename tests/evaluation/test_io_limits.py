"""``tectum bench io``'s AEDAT 4.0 floor: LZ4 decompression alone, on one
thread and on the reader's threads, measured rather than assumed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tectum import EventPacket
from tectum.evaluation.suites import io
from tectum.sinks.files import SINKS
from tectum.sinks.files._common import write_all
from tectum.sources.files import _lz4
from tectum.sources.files._common import thread_count


def test_lz4_alone_on_threads_decompresses_every_packet_once(tmp_path: Path) -> None:
    if not _lz4.AVAILABLE:
        pytest.skip("no compiled LZ4")
    n = 30_000
    rng = np.random.default_rng(0)
    pkt = EventPacket.from_arrays(np.cumsum(rng.integers(0, 3, n)), rng.integers(0, 64, n), rng.integers(0, 48, n),
                                  rng.choice([-1, 1], n), sensor=(64, 48))
    path = tmp_path / "e.aedat4"
    write_all(next(c for c in SINKS if c.name == "aedat4")(str(path), packet_events=700), [pkt])
    one, three = io._lz4_alone(str(path)), io._lz4_alone(str(path), 3)
    assert one is not None and three is not None
    assert one() == three() >= 16 * n  # the same bytes, each packet once (16 B an event, and the table's)


def test_wall_limit_is_the_measured_threaded_figure(tmp_path: Path) -> None:
    path = tmp_path / "f.aedat4"
    path.write_bytes(b"x" * 1000)
    k = thread_count(0)
    r = {io.LZ4_ALONE: {"mev_s": 100.0, "cpu_mev_s": 100.0}}
    assert io._limits("aedat4", path, 1000, 1e12, r)["wall"][0] == pytest.approx(100.0 * k)
    if k > 1:
        r[io.LZ4_ALONE_THREADS.format(k)] = {"mev_s": 130.0, "cpu_mev_s": 60.0}
        assert io._limits("aedat4", path, 1000, 1e12, r)["wall"][0] == pytest.approx(130.0)
    assert io._limits("aedat4", path, 1000, 1e12, r)["cpu"][0] == pytest.approx(100.0)
