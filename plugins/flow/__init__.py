"""Family ``flow``: per-event optical flow (px/s) with a validity per event."""

from __future__ import annotations

from tectum.hookspecs import hookimpl

from .contrast_max import ContrastMax
from .edge_speed import EdgeSpeed
from .lucas_kanade import LucasKanade
from .plane_fit import PlaneFit

__all__ = ["ContrastMax", "EdgeSpeed", "LucasKanade", "PlaneFit"]


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    for cls in (EdgeSpeed, PlaneFit, LucasKanade, ContrastMax):
        registry.add_operator(cls)
