"""How much earlier a time shard must start: the pipeline's warm-up.

Each operator states its memory (:meth:`tectum.Operator.memory_us`): what it
emits once its input has passed time ``a`` depends only on its input from
``a - memory`` on. Along a chain the memories add up (the second operator's
input from ``a - m2`` on is exact only if the first started ``m1`` before
that), so the warm-up is the largest sum along any path from a source, plus
1 µs per stateful operator (inclusive comparisons at the edge). Operators
that cut windows on a grid counted from their first packet
(:meth:`tectum.Operator.window_grid_us`) also need the shard's reading to
start on that grid: the least common multiple of the grids.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass

from tectum._operator import Operator
from tectum._pipeline import Plan
from tectum.errors import PipelineError

__all__ = ["NotShardable", "Warmup", "warmup_of"]


class NotShardable(PipelineError):
    """The pipeline cannot be split in time: the message says which node and why."""


@dataclass(frozen=True)
class Warmup:
    """A pipeline's warm-up: ``span_us`` of input read before each shard's
    range (µs) and ``grid_us``, the period the reading start keeps to,
    counted from the stream's start (1: any µs)."""

    span_us: int
    grid_us: int = 1


def warmup_of(plan: Plan) -> Warmup:
    """The warm-up of a validated pipeline; raises :class:`NotShardable`
    naming the first operator that states no finite memory, with its reason."""
    if plan.loops:
        loop = plan.loops[0]
        raise NotShardable(f"the feedback loop {' -> '.join(loop)} cannot be split in time: what it computes "
                           "depends on everything before")
    reach: dict[str, int] = {}
    grid = 1
    for nid in plan.order:
        node = plan.nodes[nid]
        delay = {up: node.delays[q] for q, up in node.ports.items() if q in node.delays}
        before = max((reach[i] + delay.get(i, 0) for i in node.inputs), default=0)
        if node.role != "operator":
            reach[nid] = before
            continue
        op = node.instantiate()
        memory = op.memory_us()
        if memory is None:
            raise NotShardable(f"node {nid!r} ({node.spec.name}) cannot be split in time: {_reason(op)}")
        g = op.window_grid_us()
        if g > 0:
            if len(plan.of_role("source")) > 1:
                raise NotShardable(f"node {nid!r} ({node.spec.name}) counts windows from its first packet, "
                                   "which is not defined for a shard of several sources merged")
            grid = math.lcm(grid, int(g))
        reach[nid] = before + (int(memory) + 1 if memory else 0)
    return Warmup(max(reach.values(), default=0), grid)


def _reason(op: Operator) -> str:
    """Why ``op`` states no memory: its own ``memory_us`` docstring, or the
    base class's rule when it does not override it."""
    own = type(op).memory_us is not Operator.memory_us
    doc = inspect.getdoc(type(op).memory_us) if own else None
    if doc:
        text = " ".join(doc.replace("``", "").split())
        return f"its memory has no bound ({text[:1].lower()}{text[1:].rstrip('.')})"
    return ("it states no finite memory (Operator.memory_us), so its output after a shard's start may depend "
            "on the whole stream before it")
