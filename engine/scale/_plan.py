"""Cutting a recording into time shards.

A shard owns ``[start_us, end_us)`` of the output, by the time the input had
reached when it was emitted (its watermark), and reads its sources from
``read_us``: the warm-up (see :mod:`._memory`) before ``start_us``, rounded
down onto the window grid counted from the stream's start. The first shard
starts with the stream and the last ends with it, so their bounds are None
(the sources' own ``t_start_us``/``t_end_us``, if any). Bounds are spread
evenly over the stream's time span: its start is the first event packet's
(exact: windows are counted from it), its end comes from the file's ends
where the format allows (:meth:`FileSource.time_span`: DAT's last record,
EVT 2.0's last time base) and from one pass over the file otherwise.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from tectum._pipeline import Plan, PlanNode

from ._memory import NotShardable, Warmup

__all__ = ["Shard", "plan_shards", "stream_span", "span_of_source"]


@dataclass(frozen=True)
class Shard:
    """One time range of a recording. ``start_us``/``end_us``: the output it
    owns (None: the stream's start or end); ``read_us``: where its sources
    start reading (None: where the whole stream starts)."""

    index: int
    start_us: int | None
    end_us: int | None
    read_us: int | None

    @property
    def last(self) -> bool:
        return self.end_us is None

    def describe(self) -> str:
        """``[a, b) µs`` (``start``/``end`` for open bounds), and where its
        reading starts when a warm-up comes before ``a``."""
        a = "start" if self.start_us is None else f"{self.start_us}"
        b = "end" if self.end_us is None else f"{self.end_us}"
        if self.start_us is None:
            return f"[{a}, {b}) µs"
        return f"[{a}, {b}) µs (read from {'the start' if self.read_us is None else self.read_us})"


def plan_shards(n: int, span: tuple[int, int], warmup: Warmup) -> list[Shard]:
    """``n`` shards over ``span`` (first µs of the stream, µs after its last
    event), the bounds spread evenly in time; a warm-up that reaches back to
    the stream's start reads from there."""
    if n < 1:
        raise ValueError(f"shards must be >= 1, got {n}")
    t0, t1 = span
    n = max(1, min(n, t1 - t0))  # no empty shards on a short stream
    bounds: list[int | None] = [None, *(t0 + (t1 - t0) * k // n for k in range(1, n)), None]
    shards = []
    for k in range(n):
        a = bounds[k]
        read = None
        if a is not None:
            g = max(1, warmup.grid_us)
            read = t0 + (a - warmup.span_us - t0) // g * g
            if read <= t0:
                read = None
        shards.append(Shard(k, a, bounds[k + 1], read))
    return shards


def file_sources(plan: Plan) -> list[PlanNode]:
    """The plan's sources, each a file that reads a time range
    (``t_start_us``/``t_end_us``); :class:`NotShardable` otherwise."""
    from tectum._operator import component_params

    out = []
    for node in plan.of_role("source"):
        if node.spec.component is not None or "t_start_us" not in component_params(node.cls):
            raise NotShardable(f"source {node.id!r} ({node.spec.name}) cannot read a time range: shards need "
                               "recordings in files, given by path")
        if node.spec.repair is not None:
            raise NotShardable(f"source {node.id!r}: repair re-sorts events across a shard's start; "
                               "convert the recording first (tectum convert ... with --repair)")
        out.append(node)
    return out


def stream_span(plan: Plan) -> tuple[tuple[int, int], float]:
    """The time span all the plan's sources cover together (first µs, µs
    after the last event) and the seconds it took to find."""
    began = time.perf_counter()
    spans = [span_of_source(n.cls, n.spec.name, n.params) for n in file_sources(plan)]
    return (min(s[0] for s in spans), max(s[1] for s in spans)), time.perf_counter() - began


def span_of_source(cls: type, path: str, params: Mapping[str, Any]) -> tuple[int, int]:
    """First µs and µs after the last event of one file source with
    ``params``, as one sequential run would see them. The start is exact
    (windows are counted from it): the first event packet's start, from the
    first chunk. The end only balances the shards: from the format's index
    or ends when it has them (:meth:`FileSource.time_span`), by a pass over
    the file otherwise."""
    from tectum._operator import component_params
    from tectum._packet import EventPacket

    lo, hi = params.get("t_start_us"), params.get("t_end_us")
    small = {"chunk_bytes": 1 << 16} if "chunk_bytes" in component_params(cls) else {}
    src: Any = cls(path, **{**params, **small})  # the first packet only: a small chunk
    try:
        it = iter(src.packets())
        first = next((p.t_start for p in it if isinstance(p, EventPacket)), None)
        src.close()
        if first is None:
            return (int(lo or 0),) * 2
        known = src.time_span() if hasattr(src, "time_span") else None
        if known is not None:
            end = known[1] + 1
        else:
            end = first
            src = cls(path, **params)
            for pkt in src.packets():
                end = max(end, pkt.t_end)
    finally:
        src.close()
    a = int(lo) if lo is not None else first
    b = min(int(hi), end) if hi is not None else end
    return a, max(a, b)
