"""The synchronous core that runs a plan's operators as plain calls.

The trio scheduler, the thread runner and the direct :class:`Stepper` all
drive this one code path: a packet pushed at a node runs through every
operator below it, and what reaches a sink (or a tap, or the edge in front
of an offloaded operator) is returned, so that the caller decides how to
deliver it.

Joins. Streams meeting at a node are joined by watermark (:class:`PortJoin`):
data are released up to the smallest watermark of the streams still open,
in one batch per release that covers the same interval on every stream.
An operator with named ports gets each batch whole (one packet per port);
a one-input operator fed by several nodes gets the batch's packets merged
kind by kind, samples (poses, IMU, ...) before the events of the same
interval, so an operator never sees a kind run ahead of another.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping, Sequence
from itertools import islice
from time import perf_counter_ns
from typing import Any, Generic, Protocol, TypeVar

from ._operator import Operator, as_packets
from ._packet import EventPacket, Kind, Packet, accepts
from ._pipeline import Plan
from ._stats import NodeStats, Stats, _add
from ._stream import concat, empty_like, merge
from .errors import NodeError, TectumError

log = logging.getLogger("tectum")

__all__ = ["Graph", "Chain", "END", "PortJoin", "DelayedJoin", "Merger"]


class _End:
    def __repr__(self) -> str:
        return "END"


#: Marker delivered to a sink (or an offloaded node) when all of its input has ended.
END: Any = _End()
Delivery = tuple[str, Any]  # (sink id, "tap:" + id or "offload:" + id; packet, port batch or END)
Batch = dict[str, Packet]  # one packet per port
K = TypeVar("K", bound=Hashable)
_OP, _SINK, _MERGE, _PORT, _FEEDBACK, _WRITE = 0, 1, 2, 3, 4, 5
_EVENTS = Kind.EVENTS


class PortJoin(Generic[K]):
    """Join named streams (ports; any hashable keys) by watermark.

    Each port's watermark is the ``t_end`` of the last packet pushed on it.
    Data are released up to ``W``, the smallest watermark of the ports still
    open (once all have ended: the largest seen), as one batch per release:
    a packet per port, all covering ``[previous W, W)`` (empty where a port
    had nothing; a port that has never delivered a packet, or whose stream
    ended before ``previous W``, is absent; a release is cut where an ended
    stream stopped, so no packet reaches past its stream's end).
    Memory: what a port holds beyond the slowest open port's watermark.
    """

    def __init__(self, ports: Iterable[K]) -> None:
        self.ports = tuple(ports)
        self.pending: dict[K, list[Packet]] = {p: [] for p in self.ports}
        self.marks: dict[K, int | None] = {p: None for p in self.ports}
        self.proto: dict[K, Packet | None] = {p: None for p in self.ports}
        self.ended: dict[K, bool] = {p: False for p in self.ports}
        self.released: int | None = None
        self.advanced: set[K] = set()  # ports moved on by advance()

    def push(self, port: K, pkt: Packet) -> list[dict[K, Packet]]:
        if self.ended[port]:
            raise TectumError(f"port {port!r} received a packet after its end")
        mark = self.marks[port]
        if mark is not None and pkt.t_start < mark:
            if port not in self.advanced:
                raise TectumError(f"port {port!r}: packet [{pkt.t_start}, {pkt.t_end}) starts before the "
                                  f"stream's watermark {mark} µs")
            # moved on by advance(): a packet whose interval (not its samples) reaches back is cut there
            if pkt.t.shape[0] and pkt.t[0] < mark:
                raise TectumError(f"port {port!r}: a sample at {int(pkt.t[0])} µs came after the stream had "
                                  f"moved on to {mark} µs: its producer on the feedback loop emits later than its "
                                  "output_mark says")
            if pkt.t_end <= mark:
                return []
            pkt = _reinterval(pkt, mark, pkt.t_end)
        self.pending[port].append(pkt)
        self.marks[port] = pkt.t_end
        self.proto[port] = pkt
        return self._release()

    def end(self, port: K) -> list[dict[K, Packet]]:
        self.ended[port] = True
        return self._release()

    def advance(self, port: K, t: int) -> list[dict[K, Packet]]:
        """Nothing more will come on ``port`` before ``t`` (µs): its
        watermark moves there without a packet (a feedback loop's producer
        that emitted nothing, see :meth:`Operator.output_mark`)."""
        mark = self.marks[port]
        if self.ended[port] or (mark is not None and t <= mark):
            return []
        self.marks[port] = t
        self.advanced.add(port)
        return self._release()

    @property
    def done(self) -> bool:
        return all(self.ended.values())

    def _watermark(self) -> int | None:
        open_marks = [self.marks[p] for p in self.ports if not self.ended[p]]
        if open_marks:
            return None if any(m is None for m in open_marks) else min(open_marks)  # type: ignore[type-var]
        seen = [m for m in self.marks.values() if m is not None]
        return max(seen) if seen else None

    def _release(self) -> list[dict[K, Packet]]:
        w = self._watermark()
        if w is None:
            return []
        start = self.released
        if start is None:
            starts = [q.t_start for qs in self.pending.values() for q in qs]
            if not starts:
                return []
            start = min(starts)
        out: list[dict[K, Packet]] = []
        while w > start:
            # an ended stream is released up to its own end, then left out:
            # no batch stretches a finished stream beyond where it stopped
            ends = [m for p, m in self.marks.items() if self.ended[p] and m is not None and start < m < w]
            upto = min(ends, default=w)
            batch: dict[K, Packet] = {}
            for port in self.ports:
                proto = self.proto[port]
                mark = self.marks[port]
                if proto is None or (self.ended[port] and mark is not None and mark <= start):
                    continue
                batch[port] = self._take(port, start, upto, proto)
            out.append(batch)
            start = self.released = upto
        return out

    def _take(self, port: K, t0: int, t1: int, proto: Packet) -> Packet:
        """The port's data in ``[t0, t1)`` as one packet with that interval."""
        pending = self.pending[port]
        if pending:  # the common case: a sparse stream with nothing before t1
            q = pending[0]
            if q.t_end > t1 and (q.t.shape[0] == 0 or q.t[0] >= t1):
                return empty_like(proto, t0, t1)  # all held samples lie at or after t1: held as they are
        pieces: list[Packet] = []
        keep: list[Packet] = []
        for q in pending:
            if q.t_end <= t1:
                pieces.append(q)
            elif q.t_start < t1:
                a, b = q.split_at(t1)
                pieces.append(a)
                keep.append(b)
            else:
                keep.append(q)
        self.pending[port] = keep
        if len(pieces) == 1:
            q = pieces[0]
            if q.t_start == t0 and q.t_end == t1:
                return q
            return _reinterval(q, t0, t1)
        pieces = [q for q in pieces if len(q)]
        if not pieces:
            return empty_like(proto, t0, t1)
        return _reinterval(pieces[0] if len(pieces) == 1 else concat(pieces), t0, t1)


class DelayedJoin(PortJoin[str]):
    """A :class:`PortJoin` with delayed ports (``delays``: port to µs).

    A packet pushed on a delayed port is shifted by its delay (samples and
    interval). A delayed port's stream starts ``delay`` after the node's
    other ports': once each of those has a watermark, the delayed port's is
    set to their earliest start plus its delay, and anything it holds before
    that is dropped (counted in :attr:`dropped`). ``feedback`` ports close a
    loop (their producer needs this node's output): they do not keep the
    node open; once every other port has ended at ``E``, the node takes the
    feedback ports up to ``E`` and is :attr:`complete` (what comes later on
    them is dropped)."""

    def __init__(self, ports: Iterable[str], delays: Mapping[str, int], feedback: Iterable[str]) -> None:
        super().__init__(ports)
        self.delays = dict(delays)
        self.feedback = frozenset(feedback)
        self.counted = tuple(p for p in self.ports if p not in self.feedback)
        self.primed = False
        self.starts: dict[str, int] = {}  # delayed port -> where its stream starts, once primed
        self.closed = False
        self.dropped = 0

    def push(self, port: str, pkt: Packet) -> list[dict[str, Packet]]:
        if self.closed:
            self.dropped += pkt.t.shape[0]
            return []
        d = self.delays.get(port)
        if not d:
            return super().push(port, pkt)
        pkt = _shifted(pkt, d)
        first = self.starts.get(port)
        if first is not None and pkt.t_start < first:  # before the port's start: dropped
            if pkt.t_end <= first:
                self.dropped += pkt.t.shape[0]
                return []
            a, pkt = pkt.split_at(first)
            self.dropped += a.t.shape[0]
        return super().push(port, pkt)

    def advance(self, port: str, t: int) -> list[dict[str, Packet]]:
        return [] if self.closed else super().advance(port, t + self.delays.get(port, 0))

    def end(self, port: str) -> list[dict[str, Packet]]:
        return [] if self.closed else super().end(port)

    def end_mark(self) -> int | None:
        """Once every port but the feedback ones has ended: where the last of them stopped."""
        return max((m for p in self.counted if (m := self.marks[p]) is not None), default=None)

    @property
    def complete(self) -> bool:
        """Every port but the feedback ones has ended and all is released up to where they stopped."""
        if not all(self.ended[p] for p in self.counted):
            return False
        e = self.end_mark()
        return e is None or (self.released is not None and self.released >= e)

    def close(self) -> None:
        """The node has taken all it will: drop what is held, refuse what comes."""
        self.closed = True
        for p in self.ports:
            self.dropped += sum(q.t.shape[0] for q in self.pending[p])
            self.pending[p] = []

    def _watermark(self) -> int | None:
        if all(self.ended[p] for p in self.counted):
            e = self.end_mark()
            fb = [self.marks[p] for p in self.feedback if not self.ended[p]]
            if e is None or any(m is None for m in fb):
                return None
            return min([e, *(m for m in fb if m is not None)])
        return super()._watermark()

    def _release(self) -> list[dict[str, Packet]]:
        if not self.primed:
            self._prime()
        return super()._release()

    def _prime(self) -> None:
        plain = [p for p in self.ports if p not in self.delays]
        if any(not self.ended[p] and self.marks[p] is None for p in plain):
            return
        starts = [q.t_start for p in plain for q in self.pending[p]]
        if not starts:
            return
        start = min(starts)
        for p, d in self.delays.items():
            m = self.starts[p] = start + d
            keep: list[Packet] = []
            for q in self.pending[p]:
                if q.t_end <= m:
                    self.dropped += q.t.shape[0]
                elif q.t_start < m:
                    a, b = q.split_at(m)
                    self.dropped += a.t.shape[0]
                    keep.append(b)
                else:
                    keep.append(q)
            self.pending[p] = keep
            mark = self.marks[p]
            if mark is None or mark < m:
                self.marks[p] = m
        self.primed = True

    def waiting(self) -> str:
        """Which feedback port holds the node back, and where it is (for a stall's message)."""
        e = self.end_mark()
        late = [(p, self.marks[p]) for p in sorted(self.feedback) if not self.ended[p]]
        held = ", ".join(f"port {p!r} at {m} µs" for p, m in late)
        return f"has its other inputs up to {e} µs, {held or 'no feedback port'}"


def _shifted(pkt: Packet, d: int) -> Packet:
    """``pkt`` ``d`` µs later: samples and interval."""
    if isinstance(pkt, EventPacket):
        return EventPacket._trusted(pkt.t + d, pkt.x, pkt.y, pkt.p, pkt.sensor, pkt.t_start + d, pkt.t_end + d,
                                    pkt.columns)
    return pkt._trusted(pkt.t + d, pkt.data, pkt.t_start + d, pkt.t_end + d)  # type: ignore[attr-defined]


def _reinterval(pkt: Packet, t0: int, t1: int) -> Packet:
    """``pkt``'s samples with the interval ``[t0, t1)``, which holds them (no check)."""
    if isinstance(pkt, EventPacket):
        return EventPacket._trusted(pkt.t, pkt.x, pkt.y, pkt.p, pkt.sensor, t0, t1, pkt.columns)
    return pkt._trusted(pkt.t, pkt.data, t0, t1)  # type: ignore[attr-defined]


class Merger:
    """Merge k timestamp-ordered streams into one (a one-input operator fed
    by several nodes). ``carries[i]`` is the set of kinds input ``i`` can
    deliver; ``consumes`` the kinds the operator takes. The consumed kinds
    are joined together (one watermark across inputs and kinds, samples
    released before the events of the same interval); each other kind,
    which only passes by, is joined on its own. Equal timestamps keep
    input order."""

    def __init__(self, carries: Sequence[frozenset[Kind]], consumes: Iterable[Kind]) -> None:
        consumed = frozenset(consumes)
        groups: dict[Kind | None, list[tuple[int, Kind]]] = {}  # lanes (input, kind) joined together
        for i, kinds in enumerate(carries):
            for k in sorted(kinds):
                groups.setdefault(None if accepts(consumed, k) else k, []).append((i, k))
        self.lanes: dict[tuple[int, Kind], PortJoin[tuple[int, Kind]]] = {}
        for lanes in groups.values():
            join = PortJoin(lanes)
            for lane in lanes:
                self.lanes[lane] = join

    def push(self, i: int, pkt: Packet) -> list[Packet]:
        join = self.lanes.get((i, pkt.kind))
        if join is None:
            raise TectumError(f"input {i} delivered {pkt.kind}, which it does not declare")
        return self._merged(join.push((i, pkt.kind), pkt))

    def end(self, i: int) -> list[Packet]:
        out: list[Packet] = []
        for lane, join in self.lanes.items():
            if lane[0] == i:
                out += self._merged(join.end(lane))
        return out

    @staticmethod
    def _merged(batches: list[dict[tuple[int, Kind], Packet]]) -> list[Packet]:
        out: list[Packet] = []
        for batch in batches:
            by_kind: dict[Kind, list[Packet]] = {}
            for pkt in batch.values():
                by_kind.setdefault(pkt.kind, []).append(pkt)
            for kind in sorted(by_kind, key=lambda k: (k == Kind.EVENTS, k)):
                parts = by_kind[kind]
                first = parts[0]
                out.append(first if len(parts) == 1 else merge(parts, first.t_start, first.t_end))
        return out


class _Node:
    """A node's wiring for the hot path (one attribute load per field)."""

    __slots__ = ("id", "op", "consumes", "replaces", "takes_events", "st", "routes", "chain", "writer", "tapped",
                 "join", "ports", "offload", "ticks", "advances", "settles", "feedback_from", "feedback_ports", "done")

    def __init__(self, nid: str, st: NodeStats) -> None:
        self.id = nid
        self.st = st  # the run's stats of the node (Stats.node)
        self.op: Operator | None = None
        self.consumes: tuple[Kind, ...] = ()
        self.replaces: tuple[Kind, ...] = ()  # kinds from upstream not passed on: the operator makes its own
        self.takes_events = False  # an operator run here (not offloaded) that consumes events
        self.routes: tuple[tuple[int, Any, Any], ...] = ()
        self.chain: _Node | None = None  # the only route, when it is a one-input operator and no tap
        self.writer: Any = None  # the only route, when it is a sink written through (every kind) and no tap
        self.tapped = False
        self.join: PortJoin[str] | Merger | None = None
        self.ports: Mapping[str, str] = {}
        self.offload = False
        self.ticks = False
        # feedback loops: the ports of this node's loop children it feeds (moved on by output_mark),
        # whether it has feedback ports (it completes through its join), their producers, done or not
        self.advances: tuple[tuple[_Node, str], ...] = ()
        self.settles = False
        self.feedback_from: frozenset[str] = frozenset()
        self.feedback_ports: frozenset[str] = frozenset()
        self.done = False


class Writer(Protocol):
    """A sink written through by the graph (:meth:`Graph.write_through`)."""

    sid: str
    st: NodeStats
    #: the sink's own write (no counts, no clock)
    write: Callable[[Packet], None]

    def __call__(self, pkt: Packet) -> None:
        """Write ``pkt``, counting it and its latency."""

    def wrote(self, n: int) -> None:
        """``n`` packets were just written by :attr:`write` directly (counted by
        the caller): record their latency."""


class Chain:
    """A straight line of one-input operators that take events (no ticks,
    not offloaded, each the only route of the one before): what a source's
    event packets go through, run by :meth:`run` as a loop instead of a
    call per node per packet.

    The same calls in the same order as :meth:`Graph.push` packet after
    packet; the counts are added up over a run of packets and stored at its
    end, the busy time is read with one clock read per step (each node's
    time runs from the end of the step before: its share of the loop's own
    bookkeeping included). An operator that returns anything but one events
    packet hands what it returned to the plain path (:meth:`Graph._pass_on`)."""

    def __init__(self, graph: Graph, hops: tuple[_Node, ...]) -> None:
        self.graph = graph
        self.hops = hops
        self.procs = tuple(rec.op.process for rec in hops)  # type: ignore[union-attr]
        last = hops[-1]
        self.next = last.chain  # an operator the loop leaves to the plain path
        writer: Writer | None = last.writer if self.next is None else None
        self.writer = writer
        self.write = writer.write if writer is not None else None

    def run(self, pieces: Iterator[Packet], limit: int) -> tuple[int, list[Delivery]]:
        """Push up to ``limit`` event packets of ``pieces`` through the
        chain, as :meth:`Graph.push` would one by one: (how many were
        taken, what they delivered)."""
        graph, procs, write = self.graph, self.procs, self.write
        n = len(procs)
        out: list[Delivery] = []
        ev = [0] * (n + 1)  # events into each step (n: out of the last operator)
        busy = [0] * (n + 1)  # ns in each step (n: the sink's write)
        broke = [0] * n  # packets a step handed to the plain path
        clock = perf_counter_ns
        k = 0
        i = -1
        # The pieces are made first (their making is no node's time, as on
        # the plain path), so that one clock read per step is all the loop
        # needs: a step's time runs from the read that ended the step before
        # (for the first, the previous piece's last step, or the plain path's end).
        block = list(islice(pieces, limit))
        try:
            t0 = clock()
            for piece in block:
                k += 1
                ev[0] += len(piece.t)  # (the array's len: 3x cheaper than .shape[0], 6x than len(piece))
                q = piece
                i = 0
                for proc in procs:
                    res = proc(q)
                    if type(res) is list and len(res) == 1 and (q := res[0]).kind is _EVENTS:
                        t1 = clock()
                        busy[i] += t1 - t0
                        t0 = t1
                        i += 1
                        ev[i] += len(q.t)
                    else:
                        busy[i] += clock() - t0
                        broke[i] += 1
                        graph._pass_on(self.hops[i], res, out)
                        t0 = clock()
                        break
                else:
                    if write is not None:
                        write(q)
                        t1 = clock()
                        busy[n] += t1 - t0
                        t0 = t1
                    else:
                        if self.next is not None:
                            graph._run(self.next, q, out)
                        else:
                            graph._emit(self.hops[-1], q, out)
                        t0 = clock()
                i = -1
        except NodeError:
            raise
        except Exception as e:
            if i < 0:
                raise
            raise NodeError(self.hops[i].id if i < n else self.writer.sid, e) from e  # type: ignore[union-attr]
        finally:
            self._count(k, ev, busy, broke)
        if graph._deferred:
            graph._drain(out)
        return k, out

    def _count(self, k: int, ev: list[int], busy: list[int], broke: list[int]) -> None:
        """Store a run's counts: ``k`` packets went in; step ``i`` took
        ``ev[i]`` events, ran ``busy[i]`` ns and handed ``broke[i]`` packets'
        outputs to the plain path (which counted them)."""
        entered = k
        for i, rec in enumerate(self.hops):
            st = rec.st
            st.packets_in += entered
            st.events_in += ev[i]
            st.busy_ns += busy[i]
            entered -= broke[i]
            st.packets_out += entered
            st.events_out += ev[i + 1]
        if self.writer is not None and entered:
            st = self.writer.st
            st.packets_in += entered
            st.events_in += ev[-1]
            st.busy_ns += busy[-1]
            self.writer.wrote(entered)


class Graph:
    """Operators of a plan, wired for synchronous execution.

    Deliveries returned to the caller go to every sink, to any tapped node
    (under ``"tap:" + id``) and, with ``offload`` (the scheduler), to the
    edge in front of each offloaded operator (``"offload:" + id``): the
    caller runs :meth:`call` for those in a worker thread and hands the
    result back to :meth:`forward`. Without ``offload`` (:class:`Stepper`)
    every operator runs inline. Each operator's :meth:`~Operator.warmup`
    runs when the graph is built.
    """

    def __init__(self, plan: Plan, *, taps: Iterable[str] = (), stats: Stats | None = None,
                 offload: bool = True) -> None:
        self.plan = plan
        self.stats = stats or Stats()
        self.ops: dict[str, Operator] = {}
        self.open_inputs: dict[str, int] = {}
        self.taps = set(taps)
        for t in self.taps:
            if t not in plan.nodes:
                raise TectumError(f"cannot tap unknown node {t!r}")
        for nid in plan.order:
            node = plan.nodes[nid]
            self.stats.node(nid)
            if node.role == "operator":
                self.ops[nid] = node.instantiate()
            if node.role != "source":  # a feedback port's producer does not keep the node open
                fb = {node.ports[q] for q in node.feedback}
                self.open_inputs[nid] = len([i for i in node.inputs if i not in fb])
        self.offloaded = frozenset(n for n in self.ops if offload and self.plan.nodes[n].offload)
        self._ended: set[str] = set()
        # what crosses a feedback edge waits here until the current push is done, so that no
        # operator is called again while its own outputs are still on their way (FIFO: in order)
        self._deferred: deque[tuple[_Node, str, Any]] = deque()
        self._wire()
        for op in self.ops.values():
            op.warmup()

    def collect_counters(self) -> None:
        """Copy operators' own counters into the stats: an int ``dropped``
        attribute (a rate limiter's drops) and a ``counts`` dict."""
        for nid, op in self.ops.items():
            d = getattr(op, "dropped", None)
            if isinstance(d, int):
                self.stats.nodes[nid].drops = d
            counts = getattr(op, "counts", None)
            if isinstance(counts, dict):
                self.stats.nodes[nid].counters.update({k: v for k, v in counts.items() if isinstance(v, int)})

    # -- driving ----------------------------------------------------------------
    def push(self, node_id: str, pkt: Packet) -> list[Delivery]:
        """Emit ``pkt`` as the output of ``node_id`` (a source, usually)."""
        out: list[Delivery] = []
        rec = self._recs[node_id]
        if rec.chain is not None:
            self._run(rec.chain, pkt, out)
        elif rec.writer is not None:
            rec.writer(pkt)
        else:
            self._emit(rec, pkt, out)
        if self._deferred:
            self._drain(out)
        return out

    def chain_of(self, node_id: str) -> Chain | None:
        """The straight line of operators below ``node_id`` as a
        :class:`Chain` (for a source's event packets), or None when its
        first step is not a plain one-input operator taking events."""
        hops: list[_Node] = []
        rec = self._recs[node_id].chain
        while rec is not None and rec.takes_events and not rec.ticks and not rec.advances:
            hops.append(rec)
            rec = rec.chain
        return Chain(self, tuple(hops)) if hops else None

    def write_through(self, writers: Mapping[str, Any]) -> None:
        """Write what reaches the sinks of ``writers`` (sink id to a callable
        taking a packet) at once, by calling the writer, instead of
        returning it as a delivery (the scheduler's sinks written inline:
        no list, tuple or hand-over per packet). Their ends are still
        delivered."""
        for rec in self._recs.values():
            rec.routes = tuple((_WRITE, writers[c], x) if how == _SINK and c in writers else (how, c, x)
                               for how, c, x in rec.routes)
            if len(rec.routes) == 1 and rec.routes[0][0] == _WRITE and rec.routes[0][2] is None and not rec.tapped:
                rec.writer = rec.routes[0][1]

    def end(self, node_id: str) -> list[Delivery]:
        """``node_id``'s stream has ended: flush and propagate end of stream."""
        out: list[Delivery] = []
        self._end(node_id, out)
        if self._deferred:
            self._drain(out)
        return out

    def call(self, node_id: str, item: Packet | Batch) -> list[Packet]:
        """Run operator ``node_id`` on one delivered item (a packet, or a
        port batch); thread-safe with respect to every other node."""
        return self._call(self._recs[node_id], item)

    def call_finish(self, node_id: str) -> list[Packet]:
        """End of stream for operator ``node_id``: its ``finish()`` output."""
        return self._finish(self._recs[node_id])

    def call_marked(self, node_id: str, item: Packet | Batch) -> tuple[list[Packet], int | None]:
        """:meth:`call`, and for a node on a feedback loop its output mark
        after the call (:meth:`Operator.output_mark`; None elsewhere), for
        :meth:`forward`."""
        rec = self._recs[node_id]
        res = self._call(rec, item)
        return res, (self._output_mark(rec, item) if rec.advances else None)

    def forward(self, node_id: str, outputs: Sequence[Packet], *, ended: bool = False,
                mark: int | None = None) -> list[Delivery]:
        """Hand an offloaded operator's outputs on (and, with ``ended``, its
        end of stream; with ``mark``, its output mark from :meth:`call_marked`)."""
        out: list[Delivery] = []
        rec = self._recs[node_id]
        self._forward(rec, outputs, out)
        if mark is not None:
            self._advance(rec, mark, out)
        if ended:
            self._end(node_id, out)
        if self._deferred:
            self._drain(out)
        return out

    def unstall(self) -> list[Delivery]:
        """Once every source has ended and no work is left: end the feedback
        ports of each loop that has not finished (its nodes wait on each
        other: one of them emits later than the loop's delay allows, e.g. a
        tracker that lost track feeding a mapper that waits for poses). The
        nodes then run on to the end without what the loop would have
        brought back; each such node counts ``feedback_stalled_at`` (µs, where
        its feedback stopped) and a warning says so. Where a loop stalls is
        a property of the data, not of timing: the result stays
        deterministic."""
        out: list[Delivery] = []
        for loop in self.plan.loops:
            for nid in loop:
                rec = self._recs[nid]
                if nid in self._ended or not rec.settles or rec.done:
                    continue
                join: Any = rec.join
                log.warning("the feedback loop %s stalled: node %r %s; it runs on without its feedback (a node on "
                            "the loop emits later than the delay allows, see Operator.output_mark; raise delay_us)",
                            " -> ".join(loop), nid, join.waiting())
                rec.st.counters["feedback_stalled_at"] = min(
                    (m for q in rec.feedback_ports if (m := join.marks[q]) is not None), default=0)
                self._deferred.extend((rec, q, END) for q in sorted(rec.feedback_ports))
        if self._deferred:
            self._drain(out)
        return out

    # -- internals ----------------------------------------------------------------
    # The hot path: plain calls over routes precomputed in _wire(); kinds are
    # tested against tuples (identity first), lengths read from t.shape.
    def _wire(self) -> None:
        plan = self.plan
        nodes = self.stats.nodes
        recs = {nid: _Node(nid, nodes[nid]) for nid in plan.order}
        for nid, rec in recs.items():
            node = plan.nodes[nid]
            op = self.ops.get(nid)
            rec.op = op
            rec.consumes = tuple(op.consumes) if op is not None else ()
            rec.replaces = tuple(node.replaces)
            rec.tapped = nid in self.taps
            rec.offload = nid in self.offloaded
            rec.ticks = op is not None and type(op).on_tick is not Operator.on_tick
            rec.takes_events = _EVENTS in rec.consumes and not rec.offload
            if op is not None and node.ports:
                rec.ports = node.ports
                rec.join = DelayedJoin(node.ports, node.delays, node.feedback) if node.delays else PortJoin(node.ports)
                rec.settles = bool(node.feedback)
                rec.feedback_from = frozenset(node.ports[q] for q in node.feedback)
                rec.feedback_ports = node.feedback
            elif op is not None and len(node.inputs) > 1:
                rec.join = Merger([plan.nodes[i].provides for i in node.inputs], op.consumes)
        for nid, rec in recs.items():
            routes: list[tuple[int, Any, Any]] = []
            for child in plan.nodes[nid].children:
                node = plan.nodes[child]
                crec = recs[child]
                if node.role == "sink":
                    takes = tuple(node.cls.consumes)  # type: ignore[attr-defined]
                    routes.append((_SINK, child, None if Kind.ANY in takes else takes))  # None: every kind
                elif crec.ports:
                    for port, up in crec.ports.items():
                        if up == nid:
                            how = _FEEDBACK if port in node.feedback else _PORT
                            routes.append((how, crec, (port, crec.op.inputs[port].kind)))  # type: ignore[union-attr,index]
                elif isinstance(crec.join, Merger):
                    routes.append((_MERGE, crec, node.inputs.index(nid)))
                else:
                    routes.append((_OP, crec, None))
            rec.routes = tuple(routes)
            if len(routes) == 1 and routes[0][0] == _OP and not rec.tapped:
                rec.chain = routes[0][1]
        for loop in plan.loops:  # inside a loop, each node moves its children's ports on by its output mark
            for nid in loop:
                recs[nid].advances = tuple((recs[c], q) for c in plan.nodes[nid].children if c in loop
                                           for q, up in recs[c].ports.items() if up == nid)
        self._recs = recs

    def _below(self, node_id: str) -> Iterator[_Node]:
        """``node_id``'s record and those of every node below it, each once."""
        todo, seen = [node_id], set()
        while todo:
            nid = todo.pop()
            if nid in seen:
                continue
            seen.add(nid)
            yield self._recs[nid]
            todo += self.plan.nodes[nid].children

    def joinable(self, node_id: str) -> bool:
        """True when packets pushed at ``node_id`` may be joined before they
        go in: no operator below it acts on ticks (``on_tick`` runs after
        each input packet, so its calls would change)."""
        return not any(rec.ticks for rec in self._below(node_id))

    def join_span(self, node_id: str) -> int:
        """The longest span (µs) of packets pushed at ``node_id`` that may be
        joined into one: the least :meth:`~tectum.Operator.join_us` of the
        operators below it (2**62 when none states one)."""
        spans = [us for rec in self._below(node_id) if rec.op is not None and (us := rec.op.join_us()) is not None]
        return min((max(int(us), 1) for us in spans), default=1 << 62)

    def _emit(self, rec: _Node, pkt: Packet, out: list[Delivery]) -> None:
        if rec.tapped:
            out.append(("tap:" + rec.id, pkt))
        for how, child, extra in rec.routes:
            if how == _OP:
                self._run(child, pkt, out)
            elif how == _WRITE:
                if extra is None or pkt.kind in extra:
                    child(pkt)
                else:
                    self.stats.nodes[child.sid].refuse(pkt.kind, pkt.t.shape[0])
            elif how == _SINK:
                if extra is None or pkt.kind in extra:
                    out.append((child, pkt))
                else:  # a kind the sink does not take: counted as not written
                    self.stats.nodes[child].refuse(pkt.kind, pkt.t.shape[0])
            elif how == _MERGE:
                try:
                    merged = child.join.push(extra, pkt)
                except Exception as e:
                    raise NodeError(child.id, e) from e
                for q in merged:
                    self._run(child, q, out)
            elif how == _FEEDBACK:
                if pkt.kind == extra[1]:
                    self._deferred.append((child, extra[0], pkt))
            elif pkt.kind == extra[1]:  # a port
                self._feed(child, child.join.push, extra[0], pkt, out)

    def _run(self, rec: _Node, pkt: Packet, out: list[Delivery]) -> None:
        # The hot path of one-input operators (event by event: once per
        # event per operator), so _call's work, the event counts and a
        # chain's next step are inlined here.
        st = rec.st
        if pkt.kind is _EVENTS and rec.takes_events:  # the usual case, in one test
            st.packets_in += 1
            st.events_in += pkt.t.shape[0]
        elif pkt.kind not in rec.consumes:
            if pkt.kind in rec.replaces:
                st.replaced_by_own(pkt)
            else:
                self._emit(rec, pkt, out)  # passes by
            return
        elif rec.offload:
            out.append(("offload:" + rec.id, pkt))
            return
        else:
            st.packets_in += 1
            st.took(pkt)
        t0 = perf_counter_ns()
        try:
            res = rec.op.process(pkt)  # type: ignore[union-attr]
            if rec.ticks:
                res = list(as_packets(res)) + list(as_packets(rec.op.on_tick(pkt.t_end)))  # type: ignore[union-attr]
        except NodeError:
            raise
        except Exception as e:
            raise NodeError(rec.id, e) from e
        st.busy_ns += perf_counter_ns() - t0
        self._pass_on(rec, res, out)

    def _pass_on(self, rec: _Node, res: Any, out: list[Delivery]) -> None:
        """Count what operator ``rec`` returned (``res``) and hand it on."""
        st = rec.st
        if type(res) is not list:
            res = as_packets(res)
        st.packets_out += len(res)
        nxt, writer = rec.chain, rec.writer
        for q in res:
            if (kind := q.kind) is _EVENTS:
                st.events_out += q.t.shape[0]
            else:  # st.gave(q), inlined (a frame per window: per packet)
                _add(st.samples_out, kind, q.t.shape[0])
            if nxt is not None:
                self._run(nxt, q, out)
            elif writer is not None:
                writer(q)
            else:
                self._emit(rec, q, out)

    def _dispatch(self, rec: _Node, item: Packet | Batch, out: list[Delivery]) -> None:
        if rec.offload:
            out.append(("offload:" + rec.id, item))
            return
        self._forward(rec, self._call(rec, item), out)
        if rec.advances:
            self._advance(rec, self._output_mark(rec, item), out)

    def _output_mark(self, rec: _Node, item: Packet | Batch) -> int:
        mark = next(iter(item.values())).t_end if isinstance(item, dict) else item.t_end
        try:
            return int(rec.op.output_mark(mark))  # type: ignore[union-attr]
        except Exception as e:
            raise NodeError(rec.id, e) from e

    def _advance(self, rec: _Node, mark: int, out: list[Delivery]) -> None:
        """``rec`` will emit nothing more before ``mark``: its loop children's ports move there."""
        for child, port in rec.advances:
            if child.done:
                continue
            if child.settles and port in child.feedback_ports:
                self._deferred.append((child, port, mark))
                continue
            self._feed(child, child.join.advance, port, mark, out)  # type: ignore[union-attr]

    def _feed(self, child: _Node, into: Any, port: str, x: Any, out: list[Delivery]) -> None:
        """``into(port, x)`` on ``child``'s join (push, advance or end), then
        run ``child`` on what it releases."""
        try:
            batches = into(port, x) if x is not END else into(port)
        except Exception as e:
            raise NodeError(child.id, e) from e
        for b in batches:
            self._dispatch(child, b, out)
        if child.settles:
            self._settle(child, out)

    def _drain(self, out: list[Delivery]) -> None:
        """Deliver what waits on feedback edges: packets, output marks, ends."""
        q = self._deferred
        while q:
            child, port, x = q.popleft()
            if child.done:
                continue
            join: Any = child.join
            self._feed(child, join.end if x is END else join.advance if isinstance(x, int) else join.push, port, x,
                       out)

    def _settle(self, rec: _Node, out: list[Delivery]) -> None:
        """A node with feedback ports ends once its other inputs have ended
        and its join has released up to where they stopped."""
        join = rec.join
        if rec.done or self.open_inputs[rec.id] or not join.complete:  # type: ignore[union-attr]
            return
        rec.done = True
        join.close()  # type: ignore[union-attr]
        rec.st.counters["feedback_dropped"] = join.dropped  # type: ignore[union-attr]
        if rec.offload:
            out.append(("offload:" + rec.id, END))  # the offload task finishes it
            return
        self._forward(rec, self._finish(rec), out)
        self._end(rec.id, out)

    def _call(self, rec: _Node, item: Packet | Batch) -> list[Packet]:
        st = rec.st
        op: Any = rec.op
        st.packets_in += 1
        t0 = perf_counter_ns()
        try:
            if isinstance(item, dict):
                for q in item.values():
                    st.took(q)
                res = op.process_ports(item)
                mark = next(iter(item.values())).t_end
            else:
                st.took(item)
                res = op.process(item)
                mark = item.t_end
            res = res if type(res) is list else list(as_packets(res))
            if rec.ticks:
                res = res + list(as_packets(op.on_tick(mark)))
        except NodeError:
            raise
        except Exception as e:
            raise NodeError(rec.id, e) from e
        st.busy_ns += perf_counter_ns() - t0
        return res

    def _finish(self, rec: _Node) -> list[Packet]:
        try:
            return list(as_packets(rec.op.finish()))  # type: ignore[union-attr]
        except NodeError:
            raise
        except Exception as e:
            raise NodeError(rec.id, e) from e

    def _forward(self, rec: _Node, res: Sequence[Packet], out: list[Delivery]) -> None:
        st = rec.st
        for q in res:
            st.packets_out += 1
            st.gave(q)
            self._emit(rec, q, out)

    def _end(self, nid: str, out: list[Delivery]) -> None:
        self._ended.add(nid)
        if nid in self.taps:
            out.append(("tap:" + nid, END))
        for child in self.plan.nodes[nid].children:
            node = self.plan.nodes[child]
            crec = self._recs[child]
            if nid in crec.feedback_from:  # after what is still on its way
                self._deferred.extend((crec, q, END) for q in node.feedback if node.ports[q] == nid)
                continue
            self.open_inputs[child] -= 1
            if node.role == "sink":
                if self.open_inputs[child] == 0:
                    out.append((child, END))
                continue
            if crec.done:
                continue
            try:
                if isinstance(crec.join, Merger):
                    for q in crec.join.end(node.inputs.index(nid)):
                        self._run(crec, q, out)
                elif isinstance(crec.join, PortJoin):
                    for port, up in crec.ports.items():
                        if up == nid:
                            for b in crec.join.end(port):
                                self._dispatch(crec, b, out)
            except NodeError:
                raise
            except Exception as e:
                raise NodeError(child, e) from e
            if crec.settles:
                self._settle(crec, out)
            elif self.open_inputs[child] == 0:
                if crec.offload:
                    out.append(("offload:" + child, END))  # the offload task finishes it
                    continue
                self._forward(crec, self._finish(crec), out)
                self._end(child, out)

