"""Checkerboard calibration on frames: DAVIS APS frames, or ``map.high_pass``
reconstructions of a moving board from events alone (the e2calib idea:
reconstruct images, then calibrate with frame tools).

Frames are taken at least ``min_gap_us`` apart (at most ``max_frames``)
and searched by :func:`.chessboard_corners`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tectum import EventPacket, FramePacket

from ._calibrate import Calibration, CalibrationError, Status, View, _solve, read_recording
from ._corners import chessboard_corners
from ._grid import Grid

__all__ = ["calibrate_frames", "reconstruct"]


def reconstruct(events: EventPacket, window_us: int = 20_000, alpha: float = 15.0) -> FramePacket:
    """Log-intensity images of ``events`` by ``map.high_pass`` every
    ``window_us`` µs, as frames."""
    from tectum import MapPacket, get_registry

    cls: Any = get_registry().operator("map.high_pass")
    op = cls(alpha=alpha, window_us=window_us)
    out = [*op.process_ports({"events": events}), *op.finish()]
    maps = [p for p in out if isinstance(p, MapPacket)]
    if not maps:
        return FramePacket(np.zeros(0, np.int64), images=np.zeros((0, events.sensor[1], events.sensor[0])))
    t = np.concatenate([m.t for m in maps])
    images = np.concatenate([m.image for m in maps])
    return FramePacket(t, images=images)


def calibrate_frames(recording: FramePacket | EventPacket | str, inner: tuple[int, int] | str, square: float, *,
                     reconstruct_us: int = 0, min_gap_us: int = 100_000, max_frames: int = 60,
                     model: str = "radtan", k3: bool = False, min_views: int = 5) -> Calibration:
    """Calibrate from frames of a checkerboard with ``inner`` (cols, rows)
    inner corners (or ``"COLSxROWS"``) and squares of ``square`` m: the
    recording's frames, or with ``reconstruct_us`` > 0 (or a recording
    without frames) ``map.high_pass`` images of its events every that many
    µs (20 ms by default)."""
    frames = _frames(recording, reconstruct_us)
    from ._calibrate import _grid

    g = _grid(inner, square, False)
    obj_grid = Grid(g.cols, g.rows, g.spacing)
    picked, last = [], None
    for i, t in enumerate(frames.t):
        if last is None or t - last >= min_gap_us:
            picked.append(i)
            last = t
    if len(picked) > max_frames:
        picked = [picked[int(k)] for k in np.linspace(0, len(picked) - 1, max_frames)]
    views: list[View] = []
    for i in picked:
        pts = chessboard_corners(frames.images[i], (g.cols, g.rows))
        status: Status = "used" if pts is not None else "partial"
        views.append(View(int(frames.t[i]), int(frames.t[i]) + 1, np.zeros((0, 2)) if pts is None else pts, pts,
                          status))
    whole = sum(v.points is not None for v in views)
    if whole < min_views:
        raise CalibrationError(f"{len(frames)} frames, {len(views)} looked at ({min_gap_us} µs apart), {whole} with "
                               f"the whole {g.cols}x{g.rows} checkerboard (inner corners); need at least {min_views}")
    h, w = frames.images.shape[1:3]
    sol, views = _solve(views, obj_grid, (w, h), "equidistant" if model in ("equidistant", "fisheye") else "radtan",
                        k3, min_views)
    return Calibration(sol.camera, sol.rms, tuple(views), obj_grid, 0.0)


def _frames(recording: FramePacket | EventPacket | str, reconstruct_us: int) -> FramePacket:
    if isinstance(recording, FramePacket):
        return recording
    if isinstance(recording, EventPacket):
        return reconstruct(recording, reconstruct_us or 20_000)
    ev, fr = read_recording(recording)
    if fr is not None and len(fr) and not reconstruct_us:
        return fr
    if ev is None or len(ev) == 0:
        raise CalibrationError(f"{recording}: no frames and no events to reconstruct images from")
    return reconstruct(ev, reconstruct_us or 20_000)
