"""The trio scheduler: sources and sinks are tasks, operators plain calls.

Each source runs in its own task: it reads packets, cuts or paces them by the
pipeline's :class:`BatchPolicy`, checks them (or repairs them), then pushes
them through the operator graph as ordinary function calls. What reaches a
sink goes through a bounded :class:`Edge` into the sink's task. An error in
any node cancels the others, aborts the sinks (no half-written files) and is
raised as :class:`NodeError` naming the node.
"""

from __future__ import annotations

import math
import time
from collections.abc import AsyncIterator, Iterable, Mapping
from contextlib import asynccontextmanager
from typing import Any

import trio

from ._boundary import Guard, Repair
from ._edge import Edge
from ._graph import END, Delivery, Graph
from ._operator import Sink, Source
from ._packet import Packet
from ._pipeline import BatchPolicy, EdgePolicy, Pipeline, Plan
from ._registry import Registry
from ._stats import Stats
from .errors import NodeError, TectumError

__all__ = ["run", "arun", "open_pipeline", "RunningPipeline"]


class RunningPipeline:
    """A pipeline running in a nursery (from :func:`open_pipeline`)."""

    def __init__(self, plan: Plan, graph: Graph, taps: Mapping[str, Edge], cancel: trio.CancelScope) -> None:
        self.plan = plan
        self.graph = graph
        self._taps = taps
        self._cancel = cancel

    @property
    def stats(self) -> Stats:
        return self.graph.stats

    async def outputs(self, node_id: str) -> AsyncIterator[Packet]:
        """The packets node ``node_id`` emits (it must be tapped when opened);
        an async iterator that ends with the stream."""
        edge = self._taps.get(node_id)
        if edge is None:
            raise TectumError(f"node {node_id!r} is not tapped; open the pipeline with taps=[{node_id!r}]")
        async for pkt, _arrival in edge:
            yield pkt

    def cancel(self) -> None:
        """Stop the pipeline: sources stop, sinks are closed cleanly."""
        self._cancel.cancel()


async def arun(pipeline: Pipeline | Plan, *, registry: Registry | None = None) -> Stats:
    """Run a pipeline to the end inside the current trio run; returns its stats."""
    async with open_pipeline(pipeline, registry=registry) as running:
        pass
    return running.stats


def run(pipeline: Pipeline | Plan, *, registry: Registry | None = None, clock: Any = None) -> Stats:
    """Run a pipeline to the end (starts trio); returns its :class:`Stats`."""
    return trio.run(lambda: arun(pipeline, registry=registry), clock=clock)


@asynccontextmanager
async def open_pipeline(
    pipeline: Pipeline | Plan,
    *,
    taps: Iterable[str] = (),
    tap_buffer: int = 64,
    tap_policy: EdgePolicy = "block",
    registry: Registry | None = None,
) -> AsyncIterator[RunningPipeline]:
    """Start a pipeline in a nursery and hand back a :class:`RunningPipeline`.

    Leaving the block waits for the pipeline to finish (iterate the taps you
    need before leaving, or call :meth:`RunningPipeline.cancel`). ``taps``
    names nodes whose outputs :meth:`RunningPipeline.outputs` yields, through
    an edge of ``tap_buffer`` packets with ``tap_policy``.
    """
    plan = pipeline if isinstance(pipeline, Plan) else pipeline.validate(registry)
    taps = tuple(taps)
    stats = Stats()
    graph = Graph(plan, taps=taps, stats=stats)
    edges: dict[str, Edge] = {}
    for node in plan.of_role("sink"):
        edges[node.id] = Edge(node.spec.buffer, node.spec.policy)
    tap_edges = {t: Edge(tap_buffer, tap_policy) for t in taps}
    for t, e in tap_edges.items():
        edges["tap:" + t] = e
    t_wall = time.perf_counter()
    failure: list[BaseException] = []
    try:
        async with trio.open_nursery() as nursery:
            scope = trio.CancelScope()
            running = RunningPipeline(plan, graph, tap_edges, scope)
            nursery.start_soon(_main, plan, graph, edges, scope, failure)
            yield running
    except BaseExceptionGroup as eg:
        err = _unwrap(eg)
        err.__suppress_context__ = True  # keep __cause__ (the node's own error)
        raise err
    finally:
        stats.wall_s = time.perf_counter() - t_wall
        for k, e in tap_edges.items():
            stats.node(k).drops += e.drops
    if failure:
        raise failure[0]


def _unwrap(eg: BaseExceptionGroup) -> BaseException:
    """The first NodeError of a group (the node that failed first), else the group."""
    leaves: list[BaseException] = []

    def walk(e: BaseException) -> None:
        if isinstance(e, BaseExceptionGroup):
            for x in e.exceptions:
                walk(x)
        else:
            leaves.append(e)

    walk(eg)
    for e in leaves:
        if isinstance(e, NodeError):
            return e
    others = [e for e in leaves if not isinstance(e, trio.Cancelled)]
    return others[0] if len(others) == 1 else eg


async def _main(plan: Plan, graph: Graph, edges: dict[str, Edge], scope: trio.CancelScope,
                failure: list[BaseException]) -> None:
    sinks = {n.id: n.instantiate() for n in plan.of_role("sink")}
    opened: list[str] = []
    ok = False
    try:
        for sid, sink in sinks.items():
            try:
                sink.open()
            except Exception as e:
                raise NodeError(sid, e) from e
            opened.append(sid)
        async with trio.open_nursery() as nursery:
            for sid, sink in sinks.items():
                nursery.start_soon(_sink_task, sid, sink, edges[sid], graph.stats)
            with scope:
                async with trio.open_nursery() as sources:
                    for node in plan.of_role("source"):
                        sources.start_soon(_source_task, node, plan.batch, graph, edges)
            if scope.cancelled_caught:  # user cancel: end every edge so sinks drain
                for e in edges.values():
                    e.close()
        ok = True
    finally:
        for sid in opened:
            sink = sinks[sid]
            try:
                with trio.CancelScope(shield=True):
                    if ok:
                        sink.close()
                    else:
                        sink.abort()
            except Exception as e:  # closing failed: report it, unless another error is on the way
                if ok:
                    failure.append(NodeError(sid, e))
        for e in edges.values():
            e.close()


async def _sink_task(sid: str, sink: Sink, edge: Edge, stats: Stats) -> None:
    st = stats.node(sid)
    lat = stats.latency_of(sid)
    async for pkt, arrival in edge:
        st.packets_in += 1
        st.events_in += len(pkt)
        t0 = time.perf_counter_ns()
        try:
            await sink.awrite(pkt)
        except Exception as e:
            raise NodeError(sid, e) from e
        st.busy_ns += time.perf_counter_ns() - t0
        lat.add(trio.current_time() - arrival)
    st.drops += edge.drops


async def _deliver(deliveries: list[Delivery], edges: Mapping[str, Edge], arrival: float) -> None:
    for target, pkt in deliveries:
        if pkt is END:  # queued items are still drained by the receiver
            edges[target].close()
        else:
            await edges[target].send((pkt, arrival))


async def _source_task(node: Any, batch: BatchPolicy, graph: Graph, edges: Mapping[str, Edge]) -> None:
    sid = node.id
    st = graph.stats.node(sid)
    source: Source = node.instantiate()
    guard = Guard(sid)
    repair = Repair(window_us=node.spec.repair) if node.spec.repair is not None else None
    if repair is not None:
        st.repairs = repair.counts
    paced = batch.pace is not None and not source.live
    pacer = _Pacer(batch) if paced else None
    try:
        async for raw in _read(source, sid):
            fixed = repair(raw) if repair is not None else [raw]
            for pkt in fixed:
                pkt = guard(pkt)
                pieces = pacer.release(pkt) if pacer else _unpaced(pkt, batch)
                async for piece, arrival in pieces:
                    st.packets_out += 1
                    st.events_out += len(piece)
                    await _deliver(graph.push(sid, piece), edges, arrival)
        if repair is not None:
            for pkt in repair.flush():
                await _deliver(graph.push(sid, guard(pkt)), edges, trio.current_time())
        await _deliver(graph.end(sid), edges, trio.current_time())
    except NodeError:
        raise
    except Exception as e:
        raise NodeError(sid, e) from e
    finally:
        source.close()


async def _read(source: Source, sid: str) -> AsyncIterator[Packet]:
    if source.is_async:
        async for pkt in source.apackets():
            yield pkt
        return
    for pkt in source.packets():
        yield pkt
        await trio.lowlevel.checkpoint()


async def _unpaced(pkt: Packet, batch: BatchPolicy) -> AsyncIterator[tuple[Packet, float]]:
    for piece in pkt.batches(batch.max_events):
        yield piece, trio.current_time()


class _Pacer:
    """Releases a recorded stream at (a multiple of) real time on trio's clock.

    With ``max_latency_us == 0`` each event goes out as soon as it is due, so
    under light load packets hold one timestamp and under load they grow by
    themselves; otherwise events go out in windows of ``max_latency_us``. A
    piece's arrival time is when its newest event was due: latency measured
    from there is what the engine adds.
    """

    def __init__(self, batch: BatchPolicy) -> None:
        self.batch = batch
        self.speed = float(batch.pace or 1.0)
        self.t0: int | None = None
        self.c0 = 0.0

    def clock(self, t_us: float) -> float:
        return self.c0 + (t_us - self.t0) / 1e6 / self.speed  # type: ignore[operator]

    def sensor_now(self) -> float:
        return self.t0 + (trio.current_time() - self.c0) * 1e6 * self.speed  # type: ignore[operator]

    async def release(self, pkt: Packet) -> AsyncIterator[tuple[Packet, float]]:
        if self.t0 is None:
            self.t0 = pkt.t_start
            self.c0 = trio.current_time()
        win = self.batch.max_latency_us
        cursor = pkt.t_start
        t = pkt.t
        while cursor < pkt.t_end:
            now = self.sensor_now()
            if win:
                upto = self.t0 + math.floor((now - self.t0) / win) * win  # type: ignore[operator]
            else:
                upto = math.floor(now) + 1
            upto = min(upto, pkt.t_end)
            if upto > cursor:
                piece = pkt.slice_time(cursor, upto)
                cursor = upto
                for b in piece.batches(self.batch.max_events):
                    due = self.clock(int(b.t[-1]) if len(b) else b.t_end - 1)
                    yield b, due
                continue
            if win:
                nxt = self.t0 + (math.floor((now - self.t0) / win) + 1) * win  # type: ignore[operator]
            else:
                i = int(t.searchsorted(cursor))
                nxt = int(t[i]) if i < len(t) else pkt.t_end - 1
            await trio.sleep_until(self.clock(min(nxt, pkt.t_end)))
