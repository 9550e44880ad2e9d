"""Family ``repr``: event representations as frames (event frame,
signed accumulation, count image, time surface, surface of active events,
voxel grid, polarity colour rendering).

Each is an operator producing :class:`tectum.FramePacket` on time windows
(``window_us``) or event counts (``count``), and a plain function of an
:class:`tectum.EventPacket` (:mod:`.functional`) over numba kernels
(:mod:`.kernels`) that other families reuse."""

from __future__ import annotations

from tectum.hookspecs import hookimpl

from .functional import (
    accumulate,
    color,
    count_image,
    event_frame,
    parse_color,
    polarity_map,
    render_polarity,
    sae,
    time_surface,
    voxel_grid,
)
from .motion_compensated import MotionCompensated
from .operators import Accumulate, Color, CountImage, EventFrame, Sae, TimeSurface, VoxelGrid

__all__ = [
    "EventFrame", "Accumulate", "CountImage", "TimeSurface", "Sae", "VoxelGrid", "Color", "MotionCompensated",
    "OPERATORS",
    "event_frame", "accumulate", "count_image", "time_surface", "sae", "voxel_grid", "color",
    "polarity_map", "render_polarity", "parse_color",
]

OPERATORS = (EventFrame, Accumulate, CountImage, TimeSurface, Sae, VoxelGrid, Color, MotionCompensated)


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    for cls in OPERATORS:
        registry.add_operator(cls)
