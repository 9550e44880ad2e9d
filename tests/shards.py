"""Shared pieces of the time-sharding tests: recordings written as DAT files,
an in-process executor, and an output comparison column by column."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

import tectum
from tectum.scale import ShardTask, run_shard
from tectum.testing import ListSink, ListSource

from helpers import bars


def write_dat(path: Path, events: tectum.EventPacket) -> Path:
    """``events`` as a Prophesee DAT file (indexed by bisection) at ``path``."""
    p = tectum.Pipeline()
    p.sink(str(path), p.source(ListSource([events.without_columns(*events.column_names[4:])])))
    tectum.run(p)
    return path


def recording(path: Path, duration_us: int = 300_000, **kw: Any) -> Path:
    """A moving-bars recording with noise (48x36), as a DAT file."""
    return write_dat(path, bars(duration_us=duration_us, sensor="48x36", noise_hz=20.0, speed=300.0, **kw))


class Inline:
    """An executor running the shards in this process, one after another
    (fast; the process pool and Dask are tested on their own)."""

    def run(self, tasks: Sequence[ShardTask]) -> Iterator[Any]:
        for t in tasks:
            yield run_shard(t)


def chain(path: Path, ops: Sequence[tuple[str, dict[str, Any]]], max_events: int = 997) -> tuple[tectum.Pipeline, ListSink]:
    """A pipeline reading ``path`` through ``ops`` into a list sink."""
    p = tectum.Pipeline(max_events=max_events)
    node = p.source(str(path), id="cam")
    for i, (name, params) in enumerate(ops):
        node = p.op(name, node, id=f"op{i}", **params)
    sink = ListSink()
    p.sink(sink, node, id="out")
    return p, sink


def assert_same_output(a: ListSink, b: ListSink) -> None:
    """The same streams, kind by kind, sample for sample and column for
    column (NaN equal to NaN), however they were cut into packets."""
    kinds = sorted({str(p.kind) for p in a.packets} | {str(p.kind) for p in b.packets})
    for kind in kinds:
        pa = tectum.concat([p for p in a.packets if str(p.kind) == kind])
        pb = tectum.concat([p for p in b.packets if str(p.kind) == kind])
        assert len(pa) == len(pb), f"{kind}: {len(pa)} samples in one run, {len(pb)} sharded"
        assert pa.column_names == pb.column_names, kind
        for c in pa.column_names:
            x, y = np.asarray(pa[c]), np.asarray(pb[c])
            nan = x.dtype.kind == "f"
            if not np.array_equal(x, y, equal_nan=nan):
                off = (x != y) & ~(np.isnan(x) & np.isnan(y)) if nan else x != y
                i = np.flatnonzero(off.reshape(len(x), -1).any(axis=1))
                raise AssertionError(f"{kind}: column {c!r} differs at {len(i)} samples, first at t = "
                                     f"{np.asarray(pa.t)[i[:5]]} µs")
