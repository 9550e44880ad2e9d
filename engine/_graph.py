"""The synchronous core that runs a plan's operators as plain calls.

The trio scheduler, the thread runner and the direct :class:`Stepper` all
drive this one code path: a packet pushed at a node runs through every
operator below it, and what reaches a sink (or a tap) is returned, so that
the caller decides how to deliver it. Nodes with several inputs merge them
by timestamp, releasing samples once every input's watermark has passed.
"""

from __future__ import annotations

from time import perf_counter_ns
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ._operator import Operator, as_packets
from ._packet import EventPacket, Kind, Packet, ResultPacket, SamplePacket
from ._pipeline import Plan
from ._stats import Stats
from .errors import NodeError, PacketError, TectumError

__all__ = ["Graph", "END", "Merger"]


class _End:
    def __repr__(self) -> str:
        return "END"


#: Marker delivered to a sink when all of its input has ended.
END: Any = _End()
Delivery = tuple[str, Any]  # (sink or tap id, packet or END)
_OP, _SINK, _MERGE = 0, 1, 2


class Merger:
    """Merge k timestamp-ordered streams into one, per kind.

    ``carries[i]`` is the set of kinds input ``i`` can deliver. Samples of a
    kind are released once every input carrying that kind has a watermark
    (``t_end``) past them; equal timestamps keep input order.
    """

    def __init__(self, carries: Sequence[frozenset[Kind]]) -> None:
        self.carries = list(carries)
        self.pending: list[dict[Kind, list[Packet]]] = [dict() for _ in carries]
        self.marks: list[dict[Kind, float]] = [dict() for _ in carries]
        self.ended = [False] * len(carries)
        self.released: dict[Kind, int] = {}

    def push(self, i: int, pkt: Packet) -> list[Packet]:
        k = pkt.kind
        self.pending[i].setdefault(k, []).append(pkt)
        self.marks[i][k] = pkt.t_end
        return self._release(k)

    def end(self, i: int) -> list[Packet]:
        self.ended[i] = True
        out: list[Packet] = []
        for k in sorted({k for c in self.carries for k in c}, key=str):
            out += self._release(k)
        return out

    def _watermark(self, k: Kind) -> float:
        w = float("inf")
        for i, c in enumerate(self.carries):
            if k in c and not self.ended[i]:
                w = min(w, self.marks[i].get(k, -np.inf))
        if w == float("inf"):  # all ended: flush up to the last mark seen
            seen = [m[k] for m in self.marks if k in m]
            w = max(seen) if seen else -np.inf
        return w

    def _release(self, k: Kind) -> list[Packet]:
        w = self._watermark(k)
        if w == -np.inf:
            return []
        w = int(w)
        parts: list[Packet] = []
        for pend in self.pending:
            keep: list[Packet] = []
            for q in pend.get(k, ()):
                if q.t_end <= w:
                    parts.append(q)
                elif q.t_start < w:
                    a, b = q.split_at(w)
                    parts.append(a)
                    keep.append(b)
                else:
                    keep.append(q)
            if k in pend:
                pend[k] = keep
        start = self.released.get(k)
        if start is None:
            if not parts:
                return []
            start = min(q.t_start for q in parts)
        if w <= start:
            return []
        self.released[k] = w
        return [_merge_parts(parts, start, w)] if parts else []


def _merge_parts(parts: list[Packet], t0: int, t1: int) -> Packet:
    """Merge packets of one kind from several inputs into one packet covering
    ``[t0, t1)``, sorted by time; equal timestamps keep input order."""
    first = parts[0]
    if isinstance(first, EventPacket):
        sensors = {q.sensor for q in parts}  # type: ignore[attr-defined]
        if len(sensors) > 1:
            raise PacketError(f"cannot merge event streams of different sensor sizes {sorted(sensors)}")
        names = {frozenset(q.columns) for q in parts}  # type: ignore[attr-defined]
        if len(names) > 1:
            raise PacketError(f"cannot merge event streams with different extra columns {[sorted(c) for c in names]}")
        fields = ("t", "x", "y", "p", *first.columns)
        cat = {k: np.concatenate([q[k] for q in parts]) for k in fields}  # type: ignore[index]
        order = np.argsort(cat["t"], kind="stable")
        cat = {k: v[order] for k, v in cat.items()}
        return EventPacket(cat.pop("t"), cat.pop("x"), cat.pop("y"), cat.pop("p"),
                           sensor=first.sensor, t_start=t0, t_end=t1, columns=cat)
    assert isinstance(first, SamplePacket)
    t = np.concatenate([q.t for q in parts])
    order = np.argsort(t, kind="stable")
    data = {k: np.concatenate([q.data[k] for q in parts])[order] for k in first.data}  # type: ignore[attr-defined]
    if isinstance(first, ResultPacket):
        return ResultPacket(t[order], data["items"], t_start=t0, t_end=t1)
    return type(first)(t[order], t_start=t0, t_end=t1, **data)


class _Node:
    """A node's wiring for the hot path (one attribute load per field)."""

    __slots__ = ("id", "op", "consumes", "st", "routes", "tapped")

    def __init__(self, nid: str) -> None:
        self.id = nid


class Graph:
    """Operators of a plan, wired for synchronous execution.

    ``outputs`` are the ids whose deliveries are returned to the caller:
    every sink, plus any tapped node (returned under ``"tap:" + id``).
    """

    def __init__(self, plan: Plan, *, taps: Iterable[str] = (), stats: Stats | None = None) -> None:
        self.plan = plan
        self.stats = stats or Stats()
        self.ops: dict[str, Operator] = {}
        self.mergers: dict[str, Merger] = {}
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
            if node.role != "source":
                self.open_inputs[nid] = len(node.spec.inputs)
            if node.role == "operator" and len(node.spec.inputs) > 1:
                self.mergers[nid] = Merger([plan.nodes[i].provides for i in node.spec.inputs])
        self._wire()

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
        self._emit(self._recs[node_id], pkt, out)
        return out

    def end(self, node_id: str) -> list[Delivery]:
        """``node_id``'s stream has ended: flush and propagate end of stream."""
        out: list[Delivery] = []
        self._end(node_id, out)
        return out

    # -- internals ----------------------------------------------------------------
    # The hot path: plain calls over routes precomputed in _wire(); kinds are
    # tested against tuples (identity first), lengths read from t.shape.
    def _wire(self) -> None:
        recs = {nid: _Node(nid) for nid in self.plan.order}
        for nid, rec in recs.items():
            op = self.ops.get(nid)
            rec.op = op
            rec.consumes = tuple(op.consumes) if op is not None else ()
            rec.st = self.stats.nodes[nid]
            rec.tapped = nid in self.taps
            routes: list[tuple[int, Any, tuple[Kind, ...]]] = []
            for child in self.plan.nodes[nid].children:
                node = self.plan.nodes[child]
                if node.role == "sink":
                    routes.append((_SINK, child, tuple(node.cls.consumes)))
                elif child in self.mergers:
                    routes.append((_MERGE, recs[child], ()))
                else:
                    routes.append((_OP, recs[child], ()))
            rec.routes = tuple(routes)
        self._recs = recs

    def _emit(self, rec: "_Node", pkt: Packet, out: list[Delivery]) -> None:
        if rec.tapped:
            out.append(("tap:" + rec.id, pkt))
        for how, child, kinds in rec.routes:
            if how == _OP:
                self._run(child, pkt, out)
            elif how == _SINK:
                if pkt.kind in kinds:
                    out.append((child, pkt))
            else:
                node = self.plan.nodes[child.id]
                try:
                    merged = self.mergers[child.id].push(node.spec.inputs.index(rec.id), pkt)
                except Exception as e:
                    raise NodeError(child.id, e) from e
                for q in merged:
                    self._run(child, q, out)

    def _run(self, rec: "_Node", pkt: Packet, out: list[Delivery]) -> None:
        if pkt.kind not in rec.consumes:
            self._emit(rec, pkt, out)  # passes by
            return
        st = rec.st
        st.packets_in += 1
        st.events_in += pkt.t.shape[0]
        t0 = perf_counter_ns()
        try:
            res = rec.op.process(pkt)
        except NodeError:
            raise
        except Exception as e:
            raise NodeError(rec.id, e) from e
        st.busy_ns += perf_counter_ns() - t0
        for q in res if type(res) is list else as_packets(res):
            st.packets_out += 1
            st.events_out += q.t.shape[0]
            self._emit(rec, q, out)

    def _forward(self, nid: str, res: Sequence[Packet], out: list[Delivery]) -> None:
        rec = self._recs[nid]
        for q in res:
            rec.st.packets_out += 1
            rec.st.events_out += q.t.shape[0]
            self._emit(rec, q, out)

    def _end(self, nid: str, out: list[Delivery]) -> None:
        if nid in self.taps:
            out.append(("tap:" + nid, END))
        for child in self.plan.nodes[nid].children:
            node = self.plan.nodes[child]
            self.open_inputs[child] -= 1
            if node.role == "sink":
                if self.open_inputs[child] == 0:
                    out.append((child, END))
                continue
            m = self.mergers.get(child)
            if m is not None:
                try:
                    flushed = m.end(node.spec.inputs.index(nid))
                except Exception as e:
                    raise NodeError(child, e) from e
                for q in flushed:
                    self._run(self._recs[child], q, out)
            if self.open_inputs[child] == 0:
                try:
                    res = as_packets(self.ops[child].finish())
                except NodeError:
                    raise
                except Exception as e:
                    raise NodeError(child, e) from e
                self._forward(child, res, out)
                self._end(child, out)
