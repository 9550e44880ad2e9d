"""Instrumentation: per-node counts and time, drops, end-to-end latency."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._packet import Kind

__all__ = ["NodeStats", "LatencyRecorder", "Stats", "amounts"]


@dataclass(slots=True)
class NodeStats:
    """Counters of one node. ``events_in``/``events_out`` count events only;
    the samples of every other stream are counted by kind in
    ``samples_in``/``samples_out`` (``{"imu": 2363, "frames": 59}``: IMU
    samples, frames...). ``packets_*`` count packets of every kind.
    ``busy_ns`` is the time spent inside the node's own code (operator
    calls, sink writes), in ns. ``not_written`` (sinks) counts, by kind,
    what reached the sink and was not stored (a kind its format does not
    hold); ``replaced`` (operators) counts, by kind, what came from upstream
    and was not passed on because the operator makes that stream itself;
    ``counters`` are the node's own (a file source's skipped events)."""

    packets_in: int = 0
    events_in: int = 0
    packets_out: int = 0
    events_out: int = 0
    busy_ns: int = 0
    drops: int = 0
    repairs: dict[str, int] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)
    samples_in: dict[str, int] = field(default_factory=dict)
    samples_out: dict[str, int] = field(default_factory=dict)
    not_written: dict[str, int] = field(default_factory=dict)
    replaced: dict[str, int] = field(default_factory=dict)

    def took(self, pkt: Any) -> None:
        """Count the rows of a packet that came in (events, or samples of its kind)."""
        if pkt.kind is _EVENTS:
            self.events_in += pkt.t.shape[0]
        else:
            _add(self.samples_in, pkt.kind, pkt.t.shape[0])

    def gave(self, pkt: Any) -> None:
        """Count the rows of a packet that went out (events, or samples of its kind)."""
        if pkt.kind is _EVENTS:
            self.events_out += pkt.t.shape[0]
        else:
            _add(self.samples_out, pkt.kind, pkt.t.shape[0])

    def replaced_by_own(self, pkt: Any) -> None:
        """Count the rows of a packet from upstream this operator did not
        pass on: it makes the stream of that kind itself."""
        _add(self.replaced, pkt.kind, pkt.t.shape[0])

    def refuse(self, kind: str, n: int) -> None:
        """Count ``n`` events or samples of ``kind`` that reached this sink
        and were not written."""
        if n:
            _add(self.not_written, kind, n)

    def as_dict(self) -> dict[str, Any]:
        from dataclasses import asdict

        return asdict(self)


_EVENTS = Kind.EVENTS


def _add(counts: dict[str, int], kind: str, n: int) -> None:
    key = _KEYS.get(kind)
    if key is None:  # a kind not seen yet: its plain str, kept (str(Kind) is a Python-level call)
        key = _KEYS[kind] = str.__str__(kind)
    counts[key] = counts.get(key, 0) + n


#: Each kind's plain ``str`` (the counts' keys): a packet of samples costs a
#: dict lookup, not a call of ``Kind.__str__``.
_KEYS: dict[str, str] = {}


def amounts(counts: dict[str, int]) -> str:
    """``{"imu": 2363, "frames": 59}`` -> ``"2,363 imu samples, 59 frames"``."""
    return ", ".join(f"{n:,} {_noun(k, n)}" for k, n in counts.items() if n)


def _noun(kind: str, n: int) -> str:
    """How a count of ``kind`` reads: frames, events and maps count
    themselves, other kinds count samples."""
    if kind in ("events", "frames", "maps", "points", "tracks", "clusters", "triggers", "poses"):
        return kind if n != 1 else kind[:-1]
    return f"{kind} sample" + ("s" if n != 1 else "")


class LatencyRecorder:
    """Latency samples as a log-scale histogram: constant memory however long
    the run, constant time per sample (weighted samples too), percentiles to
    within about 1 %. Samples are in seconds; results in µs."""

    _PER_DECADE = 200  # bins per factor of ten: 1.2 % wide

    def __init__(self) -> None:
        self._bins: dict[int, int] = {}
        self._n = 0
        self._max = 0.0
        self._scale = self._PER_DECADE / math.log(10.0)

    def add(self, seconds: float, count: int = 1) -> None:
        us = seconds * 1e6
        b = int(math.log(us) * self._scale) if us > 1.0 else 0
        self._bins[b] = self._bins.get(b, 0) + count
        self._n += count
        if us > self._max:
            self._max = us

    @property
    def count(self) -> int:
        return self._n

    def percentiles(self, qs: tuple[float, ...] = (50, 90, 99, 99.9)) -> dict[str, float]:
        """Percentiles in µs (each bin's upper edge, capped at the maximum),
        keyed ``p50`` etc., plus ``max``; empty when nothing was seen."""
        if not self._n:
            return {}
        keys = sorted(self._bins)
        cum = np.cumsum([self._bins[k] for k in keys])
        out = {}
        for q in qs:
            i = int(np.searchsorted(cum, q / 100.0 * self._n, side="left"))
            edge = math.exp((keys[min(i, len(keys) - 1)] + 1) / self._scale)
            out[f"p{q:g}"] = min(edge, self._max)
        out["max"] = self._max
        return out


class Stats:
    """Everything a run measured: nodes by id, latency by sink id and, for
    paced sources, how late each piece was released after its oldest data
    could go (its first window closed, or its first sample was due:
    ``released_late``, by source id): time before the engine got to the
    data, while other tasks or, under load, other processes ran."""

    def __init__(self) -> None:
        self.nodes: dict[str, NodeStats] = {}
        self.latency: dict[str, LatencyRecorder] = {}
        self.released_late: dict[str, LatencyRecorder] = {}
        self.wall_s: float = 0.0

    def node(self, node_id: str) -> NodeStats:
        s = self.nodes.get(node_id)
        if s is None:
            s = self.nodes[node_id] = NodeStats()
        return s

    def latency_of(self, sink_id: str) -> LatencyRecorder:
        r = self.latency.get(sink_id)
        if r is None:
            r = self.latency[sink_id] = LatencyRecorder()
        return r

    def as_dict(self) -> dict[str, Any]:
        return {
            "wall_s": self.wall_s,
            "nodes": {k: v.as_dict() for k, v in self.nodes.items()},
            "latency_us": {k: v.percentiles() for k, v in self.latency.items()},
            "released_late_us": {k: v.percentiles() for k, v in self.released_late.items()},
        }

    def report(self) -> str:
        """A human-readable table: packets in, events in and out, busy time
        and drops per node; under a node, its samples of other streams by
        kind, what a sink did not write, repairs and the node's own counters
        (a file source's skipped events)."""
        w = max([24, *(len(n) + 2 for n in self.nodes)])
        lines = [f"{'node':<{w}}{'pk in':>9}{'ev in':>12}{'ev out':>12}{'ms busy':>10}{'drops':>8}"]
        for nid, s in self.nodes.items():
            lines.append(
                f"{nid:<{w}}{s.packets_in:>9}{s.events_in:>12}{s.events_out:>12}"
                f"{s.busy_ns / 1e6:>10.1f}{s.drops:>8}"
            )
            for label, counts in (("samples in", s.samples_in), ("samples out", s.samples_out),
                                  ("not written", s.not_written),
                                  ("not passed on (replaced by its own)", s.replaced)):
                if any(counts.values()):
                    lines.append(f"  {label}: {amounts(counts)}")
            for k, v in s.repairs.items():
                lines.append(f"  repaired: {k} = {v}")
            for k, v in s.counters.items():
                lines.append(f"  {k} = {v}")
        for sid, rec in self.latency.items():
            p = rec.percentiles()
            if p:
                lines.append(
                    f"latency to {sid}: p50 {p['p50']:.0f} µs, p99 {p['p99']:.0f} µs, "
                    f"max {p['max']:.0f} µs ({rec.count} packets)"
                )
        for sid, rec in self.released_late.items():
            p = rec.percentiles()
            if p:
                lines.append(f"paced source {sid} released its data late by: p50 {p['p50']:.0f} µs, "
                             f"p99 {p['p99']:.0f} µs, max {p['max']:.0f} µs")
        lines.append(f"wall time {self.wall_s:.3f} s")
        return "\n".join(lines)
