"""Family ``lifetime``: per-event lifetime (µs): how long an event's edge takes
to move one pixel, and lifetime-augmented event frames."""

from __future__ import annotations

from tectum.hookspecs import hookimpl

from .plane_fit import PlaneFitLifetime

__all__ = ["PlaneFitLifetime"]


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_operator(PlaneFitLifetime)
