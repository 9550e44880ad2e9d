"""The fused push: the commonest pipeline's hot path in one call per operator.

A source feeding a straight line of in-process one-input operators whose
last one's only output is a sink written inline (:class:`Graph.write_through`)
is the shape of most pipelines (``tectum run rec --op X --sink out``). For
it, :meth:`Graph.push` costs each packet a dozen Python calls (``push``,
``_run``, ``_pass_on``, a writer call and two count helpers per output...),
each a frame and a code object to fetch, after a kernel that swept the
caches, at 0.25-0.5 µs each. :func:`fused_push` builds, once per run, one
closure per operator that does the same work with its node's stats,
process method and sink bound as local variables: the same calls of the
operator and the sink in the same order, the same counts, the same
:class:`NodeError` naming the same node. What it does not cover (a packet
of another kind than events, which may pass by or be replaced) goes to the
graph's own path for that node (``Graph._run``).
"""

from __future__ import annotations

from collections.abc import Callable
from time import perf_counter_ns
from typing import Any

from ._graph import Delivery, Graph, _Node
from ._operator import as_packets
from ._packet import Kind, Packet
from ._stats import _KEYS, _add
from .errors import NodeError

__all__ = ["fused_push", "fused_hops"]

_EVENTS = Kind.EVENTS
#: A fused step: (the pushing node's id, a packet) into one operator, as
#: :meth:`Graph.push`: what it delivers (always nothing in this shape: every
#: route is an operator or a sink written inline, nothing waits on feedback).
Step = Callable[[str, Packet], list[Delivery]]


def fused_hops(graph: Graph, node_id: str) -> tuple[_Node, ...]:
    """The operators the fused push runs below ``node_id`` (empty when the
    graph below it is not the fused shape): each in-process, taking events,
    without ticks, output marks or taps, the only child of the one before;
    the last one's only route a sink written inline that takes every kind."""
    hops: list[_Node] = []
    rec = graph._recs[node_id].chain  # the only route (an operator, no tap), or None
    while rec is not None and rec.takes_events and not (rec.ticks or rec.advances or rec.tapped):
        hops.append(rec)
        rec = rec.chain
    if rec is not None or not hops or hops[-1].writer is None:
        return ()
    return tuple(hops)


def fused_push(graph: Graph, node_id: str) -> Step | None:
    """:meth:`Graph.push` for packets pushed at ``node_id``, fused (see the
    module docstring), or None when the graph below it is not that shape
    (:func:`fused_hops`). Call it after :meth:`Graph.write_through`: it binds
    the sinks written inline."""
    hops = fused_hops(graph, node_id)
    if not hops:
        return None
    step: Step | None = None
    for rec in reversed(hops):
        step = _step(graph, rec, step)
    return step


def _step(graph: Graph, rec: _Node, nxt: Step | None) -> Step:
    """Operator ``rec`` as a fused step: its events in, its outputs counted
    and handed to ``nxt`` (the next operator's step), or when ``nxt`` is None
    written to ``rec``'s sink. What ``Graph._run``, ``_pass_on`` and the
    inline sink's call do, in one frame."""
    st, nid, plain = rec.st, rec.id, graph._run
    process = rec.op.process  # type: ignore[union-attr]
    out_samples, keys, clock = st.samples_out, _KEYS, perf_counter_ns
    writer: Any = rec.writer if nxt is None else None
    if writer is not None:
        sid, sink, write, wrote = writer.sid, writer.st, writer.write, writer.wrote
        in_samples = sink.samples_in

    def step(_sid: str, pkt: Packet) -> list[Delivery]:
        out: list[Delivery] = []
        if pkt.kind is not _EVENTS:  # another kind: consumed, passing by or replaced
            plain(rec, pkt, out)
            return out
        st.packets_in += 1
        st.events_in += pkt.t.shape[0]
        t0 = clock()
        try:
            res = process(pkt)
        except NodeError:
            raise
        except Exception as e:
            raise NodeError(nid, e) from e
        t1 = clock()
        st.busy_ns += t1 - t0
        if type(res) is not list:
            res = as_packets(res)
        st.packets_out += len(res)
        if nxt is not None:
            for q in res:
                if (kind := q.kind) is _EVENTS:
                    st.events_out += q.t.shape[0]
                else:
                    _add(out_samples, kind, q.t.shape[0])
                if got := nxt(nid, q):
                    out += got
            return out
        # Each output counted out of the operator and into the sink, then
        # written; the run's latency recorded once (wrote: the same record
        # as a call per packet, all sharing the push's arrival).
        k = 0
        try:
            for q in res:
                n = q.t.shape[0]
                if (kind := q.kind) is _EVENTS:
                    st.events_out += n
                    sink.events_in += n
                elif (key := keys.get(kind)) is not None:
                    out_samples[key] = out_samples.get(key, 0) + n
                    in_samples[key] = in_samples.get(key, 0) + n
                else:  # a kind not seen yet
                    _add(out_samples, kind, n)
                    _add(in_samples, kind, n)
                sink.packets_in += 1
                write(q)
                k += 1
        except Exception as e:
            sink.busy_ns += clock() - t1
            if k:
                wrote(k)
            raise NodeError(sid, e) from e
        if k:
            sink.busy_ns += clock() - t1
            wrote(k)
        return out
    return step
