"""Time shards give what one sequential run gives, event for event and column
for column, for every built-in operator that states a finite memory (found
in the registry, so a new one is covered without touching this file), for
chains of them, on the process pool and on Dask; operators that state none
refuse, saying why."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from shards import Inline, assert_same_output, chain, recording

import tectum
from tectum.scale import NotShardable, Warmup, warmup_of
from tectum.testing import ListSink, ListSource

from helpers import bars, builtin_operators, conformance_case

BUILTIN = builtin_operators()


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return recording(tmp_path_factory.mktemp("scale") / "bars.dat")


def _memory(name: str) -> tuple[type, dict, int | None]:
    cls, _, params = conformance_case(name)
    return cls, params, cls(**params).memory_us()


def test_the_registry_has_operators_of_both_sorts():
    finite = [n for n in BUILTIN if _memory(n)[2] is not None]
    assert {"filter.background_activity", "flow.plane_fit", "repr.event_frame"} <= set(finite)
    assert "filter.refractory" not in finite and "filter.hot_pixel" not in finite


@pytest.mark.parametrize("name", BUILTIN)
def test_sharded_equals_sequential(name, rec):
    cls, params, memory = _memory(name)
    if memory is None:
        _refuses(name, cls, params)
        return
    seq_p, seq = chain(rec, [(name, params)])
    tectum.run(seq_p)
    sh_p, sharded = chain(rec, [(name, params)])
    stats = tectum.run(sh_p, shards=4, executor=Inline())
    assert len(stats.jobs[0].shards) == 4
    assert_same_output(seq, sharded)


def _refuses(name: str, cls: type, params: dict) -> None:
    """An operator without a finite memory: the run refuses to shard,
    naming the node and the reason."""
    p = tectum.Pipeline()
    if cls.inputs is not None:
        stream = cls.conformance_stream()
        srcs = {port: p.source(ListSource([pkt]), id=f"s_{port}") for port, pkt in stream.items()}
        p.op(name, srcs, id="op", **params)
    else:
        p.op(name, p.source(ListSource([bars()]), id="cam"), id="op", **params)
    with pytest.raises(NotShardable, match=r"node 'op' .* cannot be split in time: "):
        warmup_of(p.validate())


def test_a_chain_of_stateful_operators_on_the_process_pool(rec):
    ops = [("filter.background_activity", {"dt_us": 4000}), ("flow.plane_fit", {"window_us": 20_000}),
           ("repr.event_frame", {"window_us": 7000})]
    seq_p, seq = chain(rec, ops)
    tectum.run(seq_p)
    sh_p, sharded = chain(rec, ops)
    stats = tectum.run(sh_p, shards=3, executor="local", workers=2)
    assert_same_output(seq, sharded)
    # memories add along the chain (+1 µs each), read from the window grid
    assert stats.jobs[0].warmup == Warmup(4001 + 20_001 + 7001, 7000)
    assert sum(r["warmup_events"] for r in stats.shard_rows()) > 0


def test_the_warm_up_is_what_makes_it_exact(rec, monkeypatch):
    """Without the warm-up the shards' starts differ (the test can fail)."""
    from tectum.scale import _run

    monkeypatch.setattr(_run, "warmup_of", lambda plan: Warmup(0))
    ops = [("filter.background_activity", {"dt_us": 4000})]
    seq_p, seq = chain(rec, ops)
    tectum.run(seq_p)
    sh_p, sharded = chain(rec, ops)
    tectum.run(sh_p, shards=4, executor=Inline())
    with pytest.raises(AssertionError):
        assert_same_output(seq, sharded)


def test_a_window_grid_counts_from_the_stream_start(rec, monkeypatch):
    """Warm-ups start on the grid of windows: off it, frames differ."""
    from tectum.scale import _run

    ops = [("repr.count", {"window_us": 9000})]
    seq_p, seq = chain(rec, ops)
    tectum.run(seq_p)
    monkeypatch.setattr(_run, "warmup_of", lambda plan: Warmup(9001, 1))
    sh_p, sharded = chain(rec, ops)
    tectum.run(sh_p, shards=3, executor=Inline())
    with pytest.raises(AssertionError):
        assert_same_output(seq, sharded)


def test_dask_client(rec):
    distributed = pytest.importorskip("distributed", reason="dask.distributed is not installed (pip install '.[dask]')")
    ops = [("filter.spatiotemporal_correlation", {"dt_us": 5000}), ("flow.edge_speed", {}),
           ("repr.voxel_grid", {"window_us": 11_000})]
    seq_p, seq = chain(rec, ops)
    tectum.run(seq_p)
    with distributed.Client(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=":0") as client:
        sh_p, sharded = chain(rec, ops)
        stats = tectum.run(sh_p, shards=4, executor=client)
    assert_same_output(seq, sharded)
    assert len(stats.shard_rows()) == 4 and not stats.rerun


def test_what_cannot_be_sharded_is_refused_with_the_reason(rec):
    p, _ = chain(rec, [("filter.refractory", {})])
    with pytest.raises(NotShardable, match=r"'op0' \(filter.refractory\) cannot be split in time: its memory has "
                                           r"no bound \(whether an event is kept depends on the last kept one"):
        tectum.run(p, shards=2, executor=Inline())
    p = tectum.Pipeline()
    p.sink(ListSink(), p.op("filter.background_activity", p.source(ListSource([bars()]))))
    with pytest.raises(NotShardable, match="cannot read a time range: shards need recordings in files"):
        tectum.run(p, shards=2, executor=Inline())
    p = tectum.Pipeline()
    p.sink(ListSink(), p.op("filter.time_window", p.source(str(rec)), relative=True))
    with pytest.raises(NotShardable, match="relative counts from the stream's first packet"):
        tectum.run(p, shards=2, executor=Inline())


def test_one_shard_and_more_shards_than_microseconds(rec, tmp_path):
    short = recording(tmp_path / "short.dat", duration_us=150)
    for path, n in ((rec, 1), (short, 1000)):
        seq_p, seq = chain(path, [("filter.background_activity", {})])
        tectum.run(seq_p)
        sh_p, sharded = chain(path, [("filter.background_activity", {})])
        tectum.run(sh_p, shards=n, executor=Inline())
        assert_same_output(seq, sharded)


@pytest.mark.parametrize("ext", [".dat", ".raw", ".evt3.raw", ".aedat4", ".h5", ".txt"])
def test_every_seekable_format(ext, tmp_path):
    """Each format's way to a shard's start (DAT and EVT 2.0 bisection,
    AEDAT 4 packet table, DSEC ms_to_idx; EVT 3.0 and text decode from the
    start) gives the sequential run's output."""
    if ext == ".h5":
        pytest.importorskip("h5py", reason="h5py is not installed (pip install '.[hdf5]')")
    ev = bars(duration_us=400_000, sensor="48x36", noise_hz=20.0, speed=300.0)
    p = tectum.Pipeline()
    p.sink(str(tmp_path / f"rec{ext}"), p.source(ListSource([ev.without_columns(*ev.column_names[4:])])))
    tectum.run(p)
    ops = [("filter.background_activity", {"dt_us": 3000}), ("repr.accumulate", {"window_us": 6000})]
    seq_p, seq = chain(tmp_path / f"rec{ext}", ops)
    tectum.run(seq_p)
    sh_p, sharded = chain(tmp_path / f"rec{ext}", ops)
    stats = tectum.run(sh_p, shards=3, executor=Inline())
    assert_same_output(seq, sharded)
    assert [s.read_us is not None for s in stats.jobs[0].shards] == [False, True, True]


def test_evt2_seeks_by_bisection(tmp_path):
    """An EVT 2.0 range starts at a time base found by bisection: the same
    events as decoding from the start, far fewer bytes read."""
    from tectum.sources.files.prophesee import Evt2Source

    ev = bars(duration_us=2_000_000, sensor="64x48", noise_hz=20.0, speed=300.0)
    ev = ev.without_columns(*ev.column_names[4:])
    p = tectum.Pipeline()
    p.sink(str(tmp_path / "r.raw"), p.source(ListSource([ev])))
    tectum.run(p)
    size = (tmp_path / "r.raw").stat().st_size
    for t in (0, 63, 64, 700_001, 1_999_000):
        src = Evt2Source(str(tmp_path / "r.raw"), t_start_us=t, chunk_bytes=4096)
        got = tectum.concat(list(src.packets()))
        keep = ev.t >= t
        for c in ("t", "x", "y", "p"):
            assert np.array_equal(got[c], ev[c][keep]), (t, c)
        src = Evt2Source(str(tmp_path / "r.raw"))
        f = src._open()
        _, start, _ = src._header(f)
        at = src._seek_evt2(f, start, t)
        src.close()
        # never after the range's first event: its word follows idx events and at most t / 64 + 1 time bases
        assert at <= start + 4 * (np.searchsorted(ev.t, t) + t // 64 + 1)
        assert t < 700_000 or at > size // 3  # and well into the file for a late range
