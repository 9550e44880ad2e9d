"""The trio scheduler: sources and sinks are tasks, operators plain calls.

Each source runs in its own task: it reads packets, cuts or paces them by the
pipeline's :class:`BatchPolicy`, checks them (or repairs them), then pushes
them through the operator graph as ordinary function calls. What reaches a
sink with a plain ``write`` and the ``block`` policy is written there and
then, by the task that made it (:class:`_InlineSink`); what reaches any
other sink goes through a bounded :class:`Edge` into the sink's task. An
error in any node cancels the others, aborts the sinks (no half-written
files) and is raised as :class:`NodeError` naming the node.
"""

from __future__ import annotations

import math
import time
from collections.abc import AsyncGenerator, AsyncIterator, Awaitable, Callable, Iterable, Mapping
from contextlib import aclosing, asynccontextmanager
from time import perf_counter_ns
from typing import Any

import trio
import trio.testing

from ._boundary import Guard, Repair
from ._edge import Edge
from ._fused import fused_push
from ._graph import END, Delivery, Graph
from ._operator import Sink, Source
from ._packet import _NO_COLUMNS, EventPacket, Kind, Packet, _built, join_consecutive
from ._pipeline import BatchPolicy, EdgePolicy, Pipeline, Plan
from ._registry import Registry
from ._stats import LatencyRecorder, Stats, _add
from ._worker import NodeThread
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

    async def outputs(self, node_id: str) -> AsyncGenerator[Packet, None]:
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
    """Run a pipeline to the end (starts trio); returns its :class:`Stats`.

    A pipeline with nothing to run concurrently (one source with a plain
    ``packets()``, not paced, no offloaded operator, every sink written
    inline: see :func:`_writes_inline`) runs the same source task without
    starting trio (:func:`_run_inline`): starting trio and its tasks costs
    about 0.5 ms of CPU per run, a scheduler pass 5-20 µs."""
    plan = pipeline if isinstance(pipeline, Plan) else pipeline.validate(registry)
    if clock is None and _inline_only(plan):
        return _run_inline(plan)
    return trio.run(lambda: arun(plan), clock=clock)


def _inline_only(plan: Plan) -> bool:
    """True when ``plan`` needs no task besides its one source's: see :func:`run`."""
    sources = plan.of_role("source")
    if len(sources) != 1 or plan.batch.pace is not None or any(n.offload for n in plan.of_role("operator")):
        return False
    cls = _class_of(sources[0])
    if not (isinstance(cls, type) and issubclass(cls, Source)) or any(
            getattr(cls, a) is not getattr(Source, a) for a in ("apackets", "is_async", "live")):
        return False
    for node in plan.of_role("sink"):
        cls = _class_of(node)
        if not (isinstance(cls, type) and issubclass(cls, Sink) and node.spec.policy == "block"
                and all(getattr(cls, a) is getattr(Sink, a) for a in ("awrite", "aclose", "aabort"))):
            return False
    return True


def _class_of(node: Any) -> Any:
    comp = node.spec.component
    return node.cls if comp is None else type(comp)


def _run_inline(plan: Plan) -> Stats:
    """:func:`run` for a plan that :func:`_inline_only` passes: the source
    task's coroutine driven to its end in one step (none of its awaits
    waits: the source is a plain iterator, nothing is paced, every sink is
    written inline, so nothing is ever queued), the sinks opened before and
    closed after (aborted on an error, as under trio)."""
    stats = Stats()
    graph = Graph(plan, stats=stats)
    sinks = {n.id: n.instantiate() for n in plan.of_role("sink")}
    opened: list[str] = []
    ok = False
    failure: list[BaseException] = []
    t_wall = time.perf_counter()
    out = _Outbox({})
    try:
        _open_sinks(sinks, stats, opened)
        now = time.perf_counter
        out.write_inline(graph, sinks, stats, now)
        task = _source_task(plan.of_role("source")[0], plan.batch, graph, out, checkpoint=_no_wait, now=now)
        try:
            task.send(None)
        except StopIteration:
            pass
        else:  # it waited on something: a bug in _inline_only
            task.close()
            raise TectumError("internal error: a pipeline run without trio waited")
        if plan.loops:  # every source has ended: loops that wait on themselves run on (as _LoopWatch does)
            out.arrival = now()
            out.add(graph.unstall(), out.arrival)
        ok = True
    finally:
        out.flush_latency()
        for sid in opened:
            sink = sinks[sid]
            try:
                if ok:
                    sink.close()
                else:
                    sink.abort()
            except Exception as e:
                if ok:
                    failure.append(NodeError(sid, e))
            _count_not_written(sid, sink, stats)
        stats.wall_s = time.perf_counter() - t_wall
        graph.collect_counters()
    if failure:
        raise failure[0]
    return stats


def _open_sinks(sinks: Mapping[str, Sink], stats: Stats, opened: list[str]) -> None:
    """Bind and open ``sinks`` in order, adding each opened one's id to
    ``opened`` (so that a failure aborts those already open); a failure is
    a :class:`NodeError` naming the sink."""
    for sid, sink in sinks.items():
        try:
            sink.bind_stats(stats)
            sink.open()
        except Exception as e:
            raise NodeError(sid, e) from e
        opened.append(sid)


def _count_not_written(sid: str, sink: Sink, stats: Stats) -> None:
    """Count what sink ``sid`` took and did not store (its ``not_written``,
    by kind) as refused."""
    own = getattr(sink, "not_written", None)
    if isinstance(own, dict):
        for kind, n in own.items():
            stats.node(sid).refuse(kind, n)


async def _no_wait() -> None:
    """The checkpoint of a source task run without trio (no other task to let run)."""


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
    for nid in graph.offloaded:
        edges["offload:" + nid] = Edge(plan.nodes[nid].spec.buffer, "block")
    loops = {"offload:" + n: k for k, loop in enumerate(plan.loops) for n in loop if n in graph.offloaded}
    t_wall = time.perf_counter()
    failure: list[BaseException] = []
    try:
        async with trio.open_nursery() as nursery:
            scope = trio.CancelScope()
            running = RunningPipeline(plan, graph, tap_edges, scope)
            nursery.start_soon(_main, plan, graph, edges, scope, failure, loops)
            yield running
    except BaseExceptionGroup as eg:
        err = _unwrap(eg)
        err.__suppress_context__ = True  # keep __cause__ (the node's own error)
        raise err from err.__cause__
    finally:
        stats.wall_s = time.perf_counter() - t_wall
        graph.collect_counters()
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
                failure: list[BaseException], loops: Mapping[str, int]) -> None:
    sinks = {n.id: n.instantiate() for n in plan.of_role("sink")}
    opened: list[str] = []
    ok = False
    outbox = _Outbox(edges, loops)
    try:
        _open_sinks(sinks, graph.stats, opened)
        now = trio.lowlevel.current_clock().current_time
        outbox.write_inline(graph, {sid: sink for sid, sink in sinks.items()
                                    if _writes_inline(sink, plan.nodes[sid].spec.policy)}, graph.stats, now)
        inline = outbox.inline
        watch = _LoopWatch(graph, edges, outbox, len(plan.of_role("source"))) if plan.loops else None
        async with trio.open_nursery() as nursery:
            for sid, sink in sinks.items():
                if sid not in inline:
                    nursery.start_soon(_sink_task, sid, sink, edges[sid], graph.stats)
            with scope:
                async with trio.open_nursery() as sources:
                    for nid in sorted(graph.offloaded):
                        sources.start_soon(_offload_task, nid, graph, edges["offload:" + nid], outbox, watch)
                    pace = _PaceClock()  # one replay origin for every paced source
                    for node in plan.of_role("source"):
                        sources.start_soon(_source_task, node, plan.batch, graph, outbox, watch, pace)
            if scope.cancelled_caught:  # user cancel: end every edge so sinks drain
                for edge in edges.values():
                    edge.close()
        ok = True
    finally:
        outbox.flush_latency()
        for sid in opened:
            sink = sinks[sid]
            try:
                with trio.CancelScope(shield=True):
                    if ok:
                        await sink.aclose()
                    else:
                        await sink.aabort()
            except Exception as e:  # closing failed: report it, unless another error is on the way
                if ok:
                    failure.append(NodeError(sid, e))
            _count_not_written(sid, sink, graph.stats)
        for edge in edges.values():
            edge.close()


async def _sink_task(sid: str, sink: Sink, edge: Edge, stats: Stats) -> None:
    st = stats.node(sid)
    lat = stats.latency_of(sid)
    # a sink that does not override awrite is written without a coroutine per packet
    sync_write = sink.write if type(sink).awrite is Sink.awrite else None
    while True:
        try:
            items = await edge.receive_all()
        except trio.EndOfChannel:
            break
        t0 = time.perf_counter_ns()
        for pkt, _ in items:
            st.packets_in += 1
            st.took(pkt)
            try:
                if sync_write is not None:
                    sync_write(pkt)
                else:
                    await sink.awrite(pkt)
            except Exception as e:
                raise NodeError(sid, e) from e
        st.busy_ns += time.perf_counter_ns() - t0
        done = trio.current_time()  # once per burst: latency errs on the high side
        run_arrival, run = items[0][1], 0
        for _, arrival in items:  # packets of one slice share their arrival time
            if arrival != run_arrival:
                lat.add(done - run_arrival, run)
                run_arrival, run = arrival, 0
            run += 1
        lat.add(done - run_arrival, run)
    st.drops += edge.drops


def _writes_inline(sink: Sink, policy: EdgePolicy) -> bool:
    """True when ``sink`` can be written by the task that made its packets:
    its write is a plain call (no ``awrite`` of its own) and its policy
    ``block`` (lossless, so an edge would change nothing but when the write
    happens; ``keep_latest`` and ``drop`` need the edge to drop)."""
    return policy == "block" and type(sink).awrite is Sink.awrite


class _InlineSink:
    """A sink written as soon as a packet reaches it, in the task that
    pushed the packet (see :func:`_writes_inline`). The same writes in the
    same order as through an edge into the sink's own task, without the
    edge, the task switch and the wait until the pushing task yields: each
    packet is written and freed while its arrays are still in the cache (a
    packet held for a burst pushes the operator's state and its next output
    out of it), and its latency is the engine's alone.

    The graph calls it as the packet reaches the sink
    (:meth:`Graph.write_through`); the latency counts from ``out.arrival``,
    which the pushing task sets before each push. Packets written one after
    another with the same arrival (the pieces of one packet cut event by
    event) are recorded as one run at the last one's latency, as the sink
    task records a burst (one histogram update per run, not per event;
    paced pieces each have their own arrival): :meth:`flush` records the
    run under way."""

    __slots__ = ("sid", "write", "st", "lat", "now", "out", "run_arrival", "run", "run_done")

    def __init__(self, sid: str, sink: Sink, stats: Stats, now: Callable[[], float], out: _Outbox) -> None:
        self.sid = sid
        self.write = sink.write
        self.st = stats.node(sid)
        self.lat = stats.latency_of(sid)
        self.now = now  # trio's clock
        self.out = out
        self.run_arrival = 0.0
        self.run = 0
        self.run_done = 0.0

    def flush(self) -> None:
        """Record the latency of the run of packets under way."""
        if self.run:
            self.lat.add(self.run_done - self.run_arrival, self.run)
            self.run = 0

    def __call__(self, pkt: Packet) -> None:
        # st.took(pkt) and wrote(1) inlined: per packet written, each call is one
        # more Python frame and code object to fetch after a kernel swept the
        # caches (inline sink 6.1 -> 4.3 µs a packet of frames, event frame, cold)
        st = self.st
        st.packets_in += 1
        if (kind := pkt.kind) is _EVENTS:
            st.events_in += pkt.t.shape[0]
        else:
            _add(st.samples_in, kind, pkt.t.shape[0])
        t0 = perf_counter_ns()
        try:
            self.write(pkt)
        except Exception as e:
            raise NodeError(self.sid, e) from e
        st.busy_ns += perf_counter_ns() - t0
        arrival = self.out.arrival
        if arrival != self.run_arrival or not self.run:
            if self.run:  # flush(), inlined
                self.lat.add(self.run_done - self.run_arrival, self.run)
                self.run = 0
            self.run_arrival = arrival
        self.run += 1
        self.run_done = self.now()

    def wrote(self, n: int) -> None:
        """``n`` packets were just written (by :meth:`__call__`, or by a
        :class:`Chain` calling :attr:`write` itself): they join the run
        under way, or start one, ending now."""
        arrival = self.out.arrival
        if arrival != self.run_arrival or not self.run:
            if self.run:  # flush(), inlined (a frame per push of the fused path)
                self.lat.add(self.run_done - self.run_arrival, self.run)
                self.run = 0
            self.run_arrival = arrival
        self.run += n
        self.run_done = self.now()


class _Outbox:
    """What the tasks' pushes delivered to sinks (and offload edges), held
    until the pushing task next yields and then handed to each edge in one
    go (one task switch per burst, not per packet). Sinks written inline
    (``inline``: sink id to :class:`_InlineSink`) are written at once instead.

    One outbox serves every task of a run. Each edge has its own FIFO lock,
    taken in the order the deliveries were taken out of the outbox, so every
    edge receives its items in the order the graph produced them, whichever
    task pushed them; a task blocked on one full edge holds no other edge's
    lock (no task waits on another in a cycle: the graph is a DAG).

    The edges in front of offloaded nodes on a feedback loop (``loops``:
    edge to loop number) are fed otherwise, since the loop's own tasks feed
    them: those tasks never wait on them (they may overfill), and any other
    task waits for room *before* it takes their items out of the outbox, so
    nobody holds items while waiting and the order stays that of the graph."""

    def __init__(self, edges: Mapping[str, Edge], loops: Mapping[str, int] | None = None) -> None:
        self.edges = edges
        self.pending: dict[str, list[Any]] = {}
        self._locks = {t: trio.StrictFIFOLock() for t in edges}
        self.loops = dict(loops or {})
        self.inline: dict[str, _InlineSink] = {}
        #: When the data of the push under way arrived (trio's clock, s): set
        #: by the pushing task before it pushes, read by the sinks written inline.
        self.arrival = 0.0

    def write_inline(self, graph: Graph, sinks: Mapping[str, Sink], stats: Stats, now: Callable[[], float]) -> None:
        """Write ``sinks`` inline (:class:`_InlineSink`): the graph calls them."""
        self.inline = {sid: _InlineSink(sid, sink, stats, now, self) for sid, sink in sinks.items()}
        graph.write_through(self.inline)

    def flush_latency(self) -> None:
        """Record the latency of the runs under way in the sinks written inline."""
        for sink in self.inline.values():
            sink.flush()

    def add(self, deliveries: list[Delivery], arrival: float) -> None:
        pending, inline = self.pending, self.inline
        for target, pkt in deliveries:
            if target in inline:  # only its end: an inline sink is closed by _main, after every task
                continue
            item = _CLOSE if pkt is END else (pkt, arrival)
            items = pending.get(target)
            if items is None:
                pending[target] = [item]
            else:
                items.append(item)

    async def flush(self, loop: int | None = None) -> None:
        """Hand what is pending to the edges; ``loop``: the feedback loop of
        the calling task's node, if any."""
        if self.loops:
            await self._flush_loops(loop)
            return
        await self._flush()

    async def _flush_loops(self, loop: int | None) -> None:
        pending, loops, edges = self.pending, self.loops, self.edges
        while pending:
            ready = next((t for t in pending if t in loops and (loops[t] == loop or edges[t].has_room(1))), None)
            if ready is not None:  # no wait between taking the items out and putting them in
                items = pending.pop(ready)
                edge = edges[ready]
                if items[-1] is _CLOSE:
                    edge.put_all(items[:-1])
                    edge.close()
                else:
                    edge.put_all(items)
                continue
            others = [t for t in pending if t not in loops]
            if not others:  # only full loop edges: wait for room, holding nothing
                await edges[next(iter(pending))].wait_room()
                continue
            target = next((t for t in others if edges[t].has_room(len(pending[t]))), others[0])
            await self._send(target, pending.pop(target))

    async def _flush(self) -> None:
        pending = self.pending
        while pending:
            # edges with room first: a full edge (a slow branch) does not hold back the others
            target = next((t for t, v in pending.items() if self.edges[t].has_room(len(v))), None)
            if target is None:
                target = next(iter(pending))
            await self._send(target, pending.pop(target))

    async def _send(self, target: str, items: list[Any]) -> None:
        lock = self._locks[target]
        try:
            lock.acquire_nowait()
        except trio.WouldBlock:
            await lock.acquire()
        try:
            edge = self.edges[target]
            if items[-1] is _CLOSE:
                await edge.send_all(items[:-1])
                edge.close()  # queued items are still drained by the receiver
            else:
                await edge.send_all(items)
        finally:
            lock.release()


#: End of an edge's input, queued behind its last items.
_CLOSE: Any = object()


async def _offload_task(nid: str, graph: Graph, edge: Edge, out: _Outbox, watch: _LoopWatch | None) -> None:
    """Run an offloaded operator: take what the graph delivered to its edge,
    call the operator in a thread of its own (:class:`NodeThread`; its
    kernels release the GIL), and
    push its outputs on from the trio thread. End of stream: ``finish()`` in
    the worker thread, then the end propagates below the node."""
    finish, forward, call = graph.call_finish, graph.forward, graph.call_marked
    loop = out.loops.get("offload:" + nid)

    def call_all(items: list[tuple[Any, float]]) -> list[tuple[list[Packet], int | None]]:
        return [call(nid, item) for item, _ in items]

    worker = NodeThread(f"tectum-offload-{nid}")
    try:
        while True:
            if watch is not None and not len(edge):
                await watch.idle(loop)
            try:
                items = await edge.receive_all()
            except trio.EndOfChannel:
                break
            if watch is not None:
                watch.busy += 1
            # everything queued goes to the worker in one hand-over (a thread
            # round trip costs tens of µs: not one per packet)
            results = await worker.call(call_all, items)
            for (_, arrival), (res, mark) in zip(items, results):
                out.arrival = arrival
                out.add(forward(nid, res, mark=mark), arrival)
            await out.flush(loop)
            if watch is not None:
                watch.busy -= 1
        res = await worker.call(finish, nid)
    finally:
        worker.close()
    out.arrival = trio.current_time()
    out.add(forward(nid, res, ended=True), out.arrival)
    await out.flush(loop)
    if watch is not None:
        await watch.ended(nid, loop)


class _LoopWatch:
    """Finds a feedback loop that stalls (its nodes wait on each other's
    output: the delay is too short for how late one of them emits): once
    every source has ended and no offloaded node has work left, a loop that
    has not ended never will, and it is told to run on without its
    feedback (:meth:`Graph.unstall`)."""

    def __init__(self, graph: Graph, edges: Mapping[str, Edge], outbox: _Outbox, sources: int) -> None:
        self.graph = graph
        self.edges = {t[8:]: e for t, e in edges.items() if t.startswith("offload:")}
        self.outbox = outbox
        self.sources = sources
        self.busy = 0

    async def source_ended(self) -> None:
        self.sources -= 1
        await self.idle()

    async def ended(self, nid: str, loop: int | None) -> None:
        del self.edges[nid]
        await self.idle(loop)

    async def idle(self, loop: int | None = None) -> None:
        # an offloaded node is still at work while its edge holds items or has closed (it is finishing)
        if self.sources or self.busy or self.outbox.pending or any(len(e) or e.closed for e in self.edges.values()):
            return
        self.outbox.arrival = trio.current_time()
        self.outbox.add(self.graph.unstall(), self.outbox.arrival)
        await self.outbox.flush(loop)  # loop: the calling task's own (it never waits on its own edge)


async def _source_task(node: Any, batch: BatchPolicy, graph: Graph, out: _Outbox,
                       watch: _LoopWatch | None = None, pace: _PaceClock | None = None, *,
                       checkpoint: Callable[[], Awaitable[None]] = trio.lowlevel.checkpoint,
                       now: Callable[[], float] | None = None) -> None:
    """Read source ``node``, check (or repair), pace or join and cut its
    packets, push them through ``graph`` and hand what they deliver to
    ``out``; ``pace``: what the run's paced sources share; ``checkpoint``
    lets the other tasks run, ``now`` reads trio's clock (both replaced when
    :func:`_run_inline` runs the task alone)."""
    sid = node.id
    st = graph.stats.node(sid)
    guard = Guard(sid)
    repair = Repair(window_us=node.spec.repair) if node.spec.repair is not None else None
    if repair is not None:
        st.repairs = repair.counts
    source: Source | None = None
    apackets: Any = None
    try:
        source = node.instantiate()
        pacer = _Pacer(batch, pace) if batch.pace is not None and not source.live else None
        late = LatencyRecorder()  # how late paced pieces go out after their oldest data could
        if pacer is not None:
            graph.stats.released_late[sid] = late
        # a live source's packets go in as they come, and so do those of a
        # source feeding an operator that acts on each packet's tick
        small = _SMALL if not source.live and graph.joinable(sid) else 0
        span = graph.join_span(sid)  # a run of joined packets ends by held_until (µs)
        held_until = 0
        clock = time.perf_counter
        trio_now = now or trio.lowlevel.current_clock().current_time  # trio.current_time() without its lookups
        # source -> operators -> sinks written inline: one call per operator (else the graph's push)
        push, add = fused_push(graph, sid) or graph.push, out.add
        chain = graph.chain_of(sid)
        max_events = batch.max_events
        last_yield = clock()
        arrival = trio_now()
        held: list[EventPacket] = []  # event packets waiting to go in as one
        held_n = 0
        held_big = False  # the run holds a packet of _SMALL events or more (slices end to end only)
        held_end = -1  # the run's slices lie end to end in held_base's arrays up to here (else -1)
        held_sensor: Any = None
        held_cols: Any = None
        held_base: Any = None
        held_owners: Any = None  # the owners of the run's x, y, p (its t's: held_base)
        held_own: Any = None  # the run's first packet's _own (its owners' shared tuple), if any
        held_t_end = 0  # the end of the run's last packet (µs)
        held_checked = False  # every packet of the run is checked
        # other tasks to let run: yield every _SLICE_S of work (run alone: never)
        sliced = checkpoint is not _no_wait
        # A plain source is read here, a packet per loop (no async generator
        # between: its time inside the source, decoding, counts as its busy
        # time); what an async source delivered is flushed before each wait.
        packets = None if source.is_async else iter(source.packets())
        apackets = source.apackets() if packets is None else None
        clock_ns = time.perf_counter_ns
        # a plain source's slices that continue the held run are taken in an
        # inner loop, one test each (see below); the first that does not is
        # handled here next (``ahead``)
        runs = packets is not None and repair is None and pacer is None
        ahead: Packet | None = None
        raw: Packet | None
        while True:
            if ahead is not None:
                raw, ahead = ahead, None
            elif packets is not None:
                t0 = clock_ns()
                raw = next(packets, None)
                st.busy_ns += clock_ns() - t0
            else:
                await out.flush()
                raw = await anext(apackets, None)
            if raw is None:
                break
            for pkt in repair(raw) if repair is not None else (raw,):
                pkt = guard(pkt)
                if pacer is not None:
                    # closed here, not left suspended to the garbage collector when the run is
                    # cancelled mid-packet (the finaliser would then run outside the run)
                    async with aclosing(pacer.release(pkt)) as paced:
                        async for piece, due, ready in paced:
                            st.packets_out += 1
                            st.gave(piece)
                            late.add(trio_now() - ready)
                            out.arrival = due
                            add(push(sid, piece), due)
                            await out.flush()  # paced: hand over at once, latency counts
                            # the pacer releases a piece whenever time has moved on, without
                            # sleeping while each microsecond brings one: let the other
                            # tasks (sinks, watchers) run after each piece, however long the packet
                            await trio.lowlevel.checkpoint()
                    continue
                # As fast as possible: yield to the other tasks (sinks) every
                # _SLICE_S of work, not per packet: a task switch costs more
                # than pushing one event through the operators. Small event
                # packets are joined (up to max_events) before they go in
                # (not for live sources, nor above an operator with on_tick):
                # operators give the same output however the stream is cut,
                # and a packet costs the engine and each operator a few µs
                # whatever its size. (Arrival is read once per packet and
                # slice: latency errs on the high side.)
                n = pkt.t.shape[0]
                if pkt.kind is _EVENTS:
                    st.events_out += n
                else:
                    st.gave(pkt)
                # Held and joined: packets under _SMALL events (a copy, unless they
                # are slices lying end to end), and slices of any size that continue
                # the held run end to end in the same arrays (a view: no copy).
                at = pkt._at if type(pkt) is EventPacket and not pkt.columns else -1
                if at == held_end >= 0 and pkt.t.base is held_base and held_n + n <= max_events and (
                        pkt.t_end <= held_until) and (
                        pkt.sensor is held_sensor or pkt.sensor == held_sensor) and (  # type: ignore[attr-defined]
                        pkt.x.base is held_owners[0] and pkt.y.base is held_owners[1]  # type: ignore[attr-defined]
                        and pkt.p.base is held_owners[2]):  # type: ignore[attr-defined]
                    held.append(pkt)  # type: ignore[arg-type]  # (at >= 0: an EventPacket without columns)
                    held_n += n
                    held_end = at + n  # extends the run
                    held_t_end = pkt.t_end
                    held_checked = held_checked and pkt._checked  # type: ignore[attr-defined]
                elif held and held_n + n <= max_events and n < small and not held_big and pkt.t_end <= held_until and (
                        type(pkt) is EventPacket and (pkt.sensor is held_sensor or pkt.sensor == held_sensor) and (
                            pkt.columns is held_cols or pkt.columns.keys() == held_cols.keys())):
                    if held_end >= 0:  # a run of views so far (not every slice kept): as one packet
                        held = [_join_run(held, held_end, held_owners, held_checked, held_t_end, held_own)]
                    held.append(pkt)
                    held_n += n
                    held_end = -1
                else:
                    if held:
                        st.packets_out += 1
                        out.arrival = arrival
                        # (deliveries only when a sink is not written inline: no call for nothing)
                        if got := push(sid, _join_run(held, held_end, held_owners, held_checked, held_t_end,
                                                      held_own)):
                            add(got, arrival)
                        held, held_n, held_end = [], 0, -1
                    if small and type(pkt) is EventPacket and n <= max_events and (n < small or at >= 0):
                        held, held_n, held_big = [pkt], n, n >= small  # starts a run
                        held_until = pkt.t_start + span
                        arrival = trio_now()
                        held_sensor, held_cols, held_base = pkt.sensor, pkt.columns, pkt.t.base
                        held_end = at + n if at >= 0 else -1
                        held_owners = (pkt.x.base, pkt.y.base, pkt.p.base)
                        held_own, held_t_end = pkt._own if at >= 0 else None, pkt.t_end
                        held_checked = pkt._checked
                    else:
                        arrival = trio_now()
                        if n <= max_events:  # goes in whole (the usual case: no cutting)
                            st.packets_out += 1
                            out.arrival = arrival
                            if got := push(sid, pkt):
                                add(got, arrival)
                        elif chain is not None and pkt.kind is _EVENTS:
                            # cut (event by event: a piece per timestamp) and pushed through the
                            # chain of operators _CHECK_EVERY + 1 pieces at a time; a packet cut
                            # in many pieces yields on the same schedule as any: what it delivered
                            # is written and freed while young, not held to the packet's end
                            pieces = pkt.batches(max_events)
                            while True:
                                out.arrival = arrival
                                k, got = chain.run(pieces, _CHECK_EVERY + 1)
                                st.packets_out += k
                                if got:  # (sinks written inline leave nothing to hand over)
                                    add(got, arrival)
                                if k <= _CHECK_EVERY:
                                    break
                                if sliced and clock() - last_yield > _SLICE_S:
                                    await out.flush()
                                    await checkpoint()
                                    last_yield = clock()
                                    arrival = trio_now()
                        else:
                            k = 0
                            for piece in pkt.batches(max_events):
                                st.packets_out += 1
                                out.arrival = arrival
                                got = push(sid, piece)
                                if got:
                                    add(got, arrival)
                                k += 1
                                if sliced and not k & _CHECK_EVERY and clock() - last_yield > _SLICE_S:
                                    await out.flush()
                                    await checkpoint()
                                    last_yield = clock()
                                    arrival = trio_now()
                if runs and held_end >= 0 and held_own is not None:
                    # (a run of views held: one that grew by this packet, or one it
                    # started, so the slice after the first of a run is taken here too,
                    # not by another pass of the loop above and the guard)
                    # The slices after it, while they continue the run: what the
                    # branch above and the guard test, in one expression (checked
                    # events slices of the same four arrays: the same _own tuple,
                    # one test instead of four owners; the next index, the same
                    # sensor, not before the last one's end, room left). They are
                    # not kept (a run of views needs its first packet and its end
                    # only). Their time, reading included, is the source's busy time.
                    # (Only the packet and its ints are read, not its arrays: after a
                    # kernel has swept the caches each line read costs; _stop instead
                    # of len(t): 375 -> 250 ns a slice, cold.)
                    t0 = clock_ns()
                    start, room, mark = held_end, held_end + max_events - held_n, guard.events_mark
                    own = held_own
                    while True:
                        for q in packets:  # type: ignore[union-attr]
                            if (type(q) is not EventPacket or q._at != held_end or q._own is not own
                                    or not q._checked or q.columns or q.sensor is not held_sensor
                                    or q.t_start < mark or (end := q._stop) > room
                                    or (mark_q := q.t_end) > held_until):
                                ahead = q
                                break
                            mark = mark_q
                            held_end = end
                        guard.events_mark = held_t_end = mark
                        ran = held_end - start
                        held_n += ran
                        st.events_out += ran
                        # The slice that ended the run, when all it failed is the run's span
                        # or room (the same test less those two: the next slice of the same
                        # arrays, checked, in order) and no other task waits: what the loop
                        # above does with it (the guard's trusted path, the run in, a run
                        # started by the slice), here, without a pass of that loop and a
                        # guard call per operator call. Its busy time stops for the push.
                        q = ahead
                        if (sliced or q is None or type(q) is not EventPacket or q._at != held_end
                                or q._own is not own or not q._checked or q.columns or q.sensor is not held_sensor
                                or q.t_start < mark or (n := q._stop - held_end) > max_events):
                            break
                        st.busy_ns += clock_ns() - t0
                        ahead = None
                        st.packets_out += 1
                        out.arrival = arrival
                        if got := push(sid, _join_run(held, held_end, held_owners, held_checked, held_t_end,
                                                      held_own)):
                            add(got, arrival)
                        t0 = clock_ns()
                        guard.events_mark = held_t_end = mark = q.t_end
                        st.events_out += n
                        held, held_n, held_big, held_until = [q], n, n >= small, q.t_start + span
                        arrival = trio_now()
                        held_cols, held_checked = q.columns, True
                        start = held_end = q._stop
                        room = held_end + max_events - n
                    st.busy_ns += clock_ns() - t0
                if sliced and clock() - last_yield > _SLICE_S:
                    if held:
                        st.packets_out += 1
                        out.arrival = arrival
                        add(push(sid, _join_run(held, held_end, held_owners, held_checked, held_t_end, held_own)),
                            arrival)
                        held, held_n, held_end = [], 0, -1
                    await out.flush()
                    await checkpoint()
                    last_yield = clock()
                    arrival = trio_now()
        if held:
            st.packets_out += 1
            out.arrival = arrival
            add(push(sid, _join_run(held, held_end, held_owners, held_checked, held_t_end, held_own)), arrival)
        if repair is not None:
            for pkt in repair.flush():
                out.arrival = trio_now()
                out.add(graph.push(sid, guard(pkt)), out.arrival)
        out.arrival = trio_now()
        out.add(graph.end(sid), out.arrival)
        await out.flush()
        if watch is not None:
            await watch.source_ended()
    except NodeError:
        raise
    except Exception as e:
        raise NodeError(sid, e) from e
    finally:
        try:
            if apackets is not None and hasattr(apackets, "aclose"):
                # an async source's generator, left at a packet when the run stopped (cancelled, an
                # error downstream): closed here, its own clean-up (a network source's flush) done
                # before the source closes, not left to the garbage collector after the run
                await apackets.aclose()
        finally:
            if source is not None:
                source.close()
                counts = getattr(source, "counts", None)
                if isinstance(counts, dict):
                    st.counters.update({k: v for k, v in counts.items() if isinstance(v, int)})


def _join_run(held: list[EventPacket], end: int, owners: Any, checked: bool, t_end: int, own: Any) -> EventPacket:
    """The packets a source task held, as one. With ``end >= 0`` the run is
    slices lying end to end in the same arrays (t's owner the first's, x's,
    y's and p's ``owners``), from ``held[0]`` to index ``end`` and time
    ``t_end`` (µs): the task tested each as it came and kept only some of
    them; one view of those arrays, without looking at each packet again
    (``own``: the first's :attr:`~EventPacket._own`), ``checked`` when every
    one is. Else every packet is in ``held``: :func:`join_consecutive` (a
    view when it finds one, or a copy)."""
    first = held[0]
    if end < 0:
        return join_consecutive(held)
    i = first._at
    if end == first._stop:  # the first alone
        return first
    ot: Any = first.t.base
    ox, oy, op = owners
    return _built(ot[i:end], ox[i:end], oy[i:end], op[i:end], first.sensor, first.t_start, t_end, _NO_COLUMNS,
                  checked, i, own)


_EVENTS = Kind.EVENTS

#: Longest stretch (s) a source task works before letting other tasks run
#: (sinks written inline need none; a scheduler pass costs 5-20 µs).
_SLICE_S = 1e-3

#: The clock is read every this many + 1 pieces of a packet (a power of 2 minus 1).
_CHECK_EVERY = 63

#: Event packets smaller than this (unpaced) are joined before they go in.
_SMALL = 8192


#: Pacing waits on trio's clock until this long (s) before a release time
#: (trio's wait rounds up to whole milliseconds), then in short sleeps that
#: let go of the GIL (:class:`_PaceClock`), then yields in a loop.
_SPIN_S = 1.2e-3

#: The last stretch (s) before a release that pacing spends yielding in a
#: loop instead of asleep: the OS wakes a sleeper 50-90 µs late (its timer
#: slack and the wake-up), unloaded.
_WAKE_S = 1.5e-4

#: The longest sleep (s) between two passes of trio's scheduler while pacing
#: waits (what other tasks wait for, a worker thread's result or a socket,
#: waits at most this long).
_NAP_S = 2.5e-4


class _PaceClock:
    """What the paced sources of one run share: the wall time their replay
    started (``origin``, trio's clock, s: set by the first to release, so
    that two sources of one recording release the same instant of it
    together, not apart by how much later one task started) and the release
    times the tasks are waiting for (``waiting``), so that while every task
    that could run is one of them, the wait is spent asleep
    (:meth:`wait_until`)."""

    def __init__(self) -> None:
        self.origin: float | None = None
        self.waiting: dict[object, float] = {}

    def start(self) -> float:
        """The run's replay origin (trio's clock, s), set now by the first caller."""
        if self.origin is None:
            self.origin = trio.current_time()
        return self.origin

    async def wait_until(self, deadline: float) -> None:
        """Sleep until ``deadline`` on trio's clock, precisely, holding the
        GIL as little as possible before the last stretch: a worker thread (an offloaded operator)
        that needs it gets it at once instead of after the switch interval
        (5 ms) and a forced switch that stalls this thread, and on a loaded
        machine a task that sleeps is given the CPU back sooner than one
        that spins. Until ``_SPIN_S`` before the deadline it waits on
        trio's clock; then, each time every other task waits (other pacers
        too) and no I/O or worker thread's result is ready, it sleeps in
        ``time.sleep`` (which lets go of the GIL) for at most ``_NAP_S``,
        up to ``_WAKE_S`` before the earliest deadline waited for or trio's
        next timer; the last ``_WAKE_S``, while no other task is queued to
        run, it waits in a loop that keeps the GIL (:func:`_hold`), up to
        the earliest deadline waited for, and else yields; on a clock of the
        user's own it yields in a loop all along. On a test clock (no wake-up jitter: it
        would never advance while we spin) it sleeps on trio's clock."""
        clock = trio.lowlevel.current_clock()
        now = clock.current_time
        if isinstance(clock, trio.testing.MockClock) or deadline - now() <= 0:
            await trio.sleep_until(deadline)
            return
        if deadline - now() > _SPIN_S:
            await trio.sleep_until(deadline - _SPIN_S)
        # (asleep on trio's own clock only: another clock's seconds need not be the thread's)
        naps = type(clock).__name__ == "SystemClock"
        waiting, me = self.waiting, object()
        waiting[me] = deadline
        try:
            while (left := deadline - now()) > 0:
                if left <= _WAKE_S or not naps:
                    # the last stretch: with no other task queued to run (this task
                    # comes out of a nap, or others queued by the previous pass have
                    # run), up to the earliest deadline waited for, keeping the GIL
                    # (a pass of trio's scheduler would hand it to a worker thread)
                    stats = trio.lowlevel.current_statistics()
                    if naps and not stats.tasks_runnable:
                        first = min(min(waiting.values()), now() + stats.seconds_to_next_deadline)
                        _hold(first, now)
                        if first >= deadline:
                            continue
                    await trio.lowlevel.checkpoint()
                    continue
                # until every other task waits (trio then has polled for I/O and found none)
                with trio.move_on_at(deadline - _WAKE_S):
                    await trio.testing.wait_all_tasks_blocked()
                nap = min(min(waiting.values()) - _WAKE_S - now(),
                          trio.lowlevel.current_statistics().seconds_to_next_deadline, _NAP_S)
                if nap > 0:
                    _sleep(nap)
        finally:
            del waiting[me]


#: A sleep of the thread that lets go of the GIL (pacing's waits; a name of
#: its own so that tests can watch it).
_sleep = time.sleep


def _hold(until: float, now: Callable[[], float]) -> None:
    """Wait until ``until`` (trio's clock, s) in a loop that keeps the GIL:
    the last stretch of a pacer's wait, while no other task is queued. A
    worker thread (an offloaded operator) that needs the GIL meanwhile, to
    start a call or hand back its result, gets it after the release instead
    of just before it: handing the GIL over and back costs the trio thread
    the worker's turn and its own wake-up, 60-90 µs (idle machine), which
    a release due then would wait for. The worker waits at most ``_WAKE_S``."""
    while now() < until:
        pass


class _Pacer:
    """Releases a recorded stream at (a multiple of) real time on trio's clock.

    With ``max_latency_us == 0`` each event goes out as soon as it is due, so
    under light load packets hold one timestamp and under load they grow by
    themselves; otherwise events go out in windows of ``max_latency_us``. A
    piece's arrival time is when it was due to go out: when its newest
    sample was due, or with windows when that sample's window closed (the
    wait for a window to fill is the latency asked for, not the engine's:
    a sparse stream's lone sample at a window's start is not a window late).
    Latency measured from there is what the engine adds. The paced sources
    of a run share their wall-clock origin (``pace``).
    """

    def __init__(self, batch: BatchPolicy, pace: _PaceClock | None = None) -> None:
        self.batch = batch
        self.speed = float(batch.pace or 1.0)
        self.pace = pace or _PaceClock()
        self.t0: int | None = None
        self.c0 = 0.0

    def clock(self, t_us: float) -> float:
        return self.c0 + (t_us - self.t0) / 1e6 / self.speed  # type: ignore[operator]

    def sensor_now(self) -> float:
        return self.t0 + (trio.current_time() - self.c0) * 1e6 * self.speed  # type: ignore[operator]

    def window_end(self, t_us: float) -> int:
        """The end (µs) of the window holding sensor time ``t_us``."""
        win = self.batch.max_latency_us
        return self.t0 + (math.floor((t_us - self.t0) / win) + 1) * win  # type: ignore[operator]

    async def release(self, pkt: Packet) -> AsyncGenerator[tuple[Packet, float, float], None]:
        """Pieces of ``pkt`` as they fall due: (piece, when it was due to go
        out (its newest sample due, or that sample's window closed), when
        its oldest data could go: its first window closed, or its first
        sample was due). A window is released once it has closed, the last
        one of a packet too (its data after the packet's end come with the
        next packet)."""
        if self.t0 is None:
            self.t0 = pkt.t_start
            self.c0 = self.pace.start()
        win = self.batch.max_latency_us
        cursor = pkt.t_start
        t = pkt.t
        while cursor < pkt.t_end:
            now = self.sensor_now()
            if win:
                upto = self.t0 + math.floor((now - self.t0) / win) * win
            else:
                upto = math.floor(now) + 1
            upto = min(upto, pkt.t_end)
            if upto > cursor:
                piece = pkt.slice_time(cursor, upto)
                cursor = upto
                # when its oldest data could go: its first window closed, or its first sample was due
                if win:
                    ready = self.clock(self.window_end(piece.t_start))
                else:
                    ready = self.clock(int(piece.t[0]) if len(piece) else upto - 1)
                for b in piece.batches(self.batch.max_events):
                    last = int(b.t[-1]) if len(b) else b.t_end - 1
                    yield b, self.clock(self.window_end(last) if win else last), ready
                continue
            if win:  # the window under way closes (a packet's last one too: it goes out whole)
                nxt = self.window_end(now)
            else:
                i = int(t.searchsorted(cursor))
                nxt = min(int(t[i]) if i < len(t) else pkt.t_end - 1, pkt.t_end)
            await self.pace.wait_until(self.clock(nxt))
