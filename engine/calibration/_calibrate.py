"""``tectum.calibrate``: a camera calibration from a recording of a blinking grid.

Steps (each in its own module): find the blink period (:func:`dominant_period`
when not given), cut the recording into still views and find each view's
blinking dots (:mod:`._blink`), order them as OpenCV's circle grid
(:mod:`._grid`), calibrate and drop outlier views (:mod:`._solve`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from tectum import EventPacket, FramePacket, Kind, Packet, Sink
from tectum.camera import Camera, Model
from tectum.errors import TectumError

from ._blink import Blobs, blobs, dominant_period, still_spans, transition_map
from ._corners import chessboard_corners
from ._grid import Grid, order_grid
from ._solve import Solution, StereoSolution, solve_mono, solve_stereo

__all__ = ["calibrate", "calibrate_stereo", "detect_views", "read_recording", "Calibration",
           "StereoCalibration", "View", "CalibrationError", "Status"]

#: What became of a still view: ``used`` in the solve, ``outlier`` (dropped
#: by its RMS), ``partial`` (fewer dots than the grid: the board was partly
#: out of view or hidden), ``unordered`` (enough dots, but no whole grid
#: among them).
Status = Literal["used", "outlier", "partial", "unordered"]
#: ``dots`` (a blinking circle grid: LEDs or screen dots) or ``checker`` (a
#: screen blinking a checkerboard's white squares).
Pattern = Literal["dots", "checker"]


class CalibrationError(TectumError, ValueError):
    """The recording does not give a calibration (no blinking, too few views
    of the whole board); the message says what was found and what is missing."""


@dataclass(frozen=True)
class View:
    """One still view: its span ``[t_start, t_end)`` µs, every blinking dot
    found ``dots`` (M, 2) px, the ``points`` (N, 2) px in grid order (None
    unless the whole grid was found), what became of it (``status``) and
    its reprojection ``rms`` px (NaN unless ordered) and ``residuals`` (N, 2)
    px, detected minus reprojected points (None unless ordered; an outlier's
    against its own best pose). ``transitions`` is the view's (H, W) map of
    ON→OFF transitions (for pictures)."""

    t_start: int
    t_end: int
    dots: np.ndarray
    points: np.ndarray | None
    status: Status
    rms: float = float("nan")
    transitions: np.ndarray | None = field(default=None, repr=False)
    residuals: np.ndarray | None = field(default=None, repr=False)


@dataclass(frozen=True)
class Calibration:
    """The result of :func:`calibrate`: the ``camera`` (intrinsics,
    distortion, image size), the total reprojection ``rms`` px over the
    views used, every still view found (:class:`View`), the ``grid`` and the
    blink frequency ``blink_hz`` used."""

    camera: Camera
    rms: float
    views: tuple[View, ...]
    grid: Grid
    blink_hz: float

    @property
    def used(self) -> tuple[View, ...]:
        """The views the calibration was solved from."""
        return tuple(v for v in self.views if v.status == "used")

    def summary(self) -> str:
        """A few lines for people: views by status, intrinsics, RMS."""
        c = self.camera
        counts = {s: sum(v.status == s for v in self.views) for s in ("used", "outlier", "partial", "unordered")}
        lines = [f"views: {len(self.views)} still ({', '.join(f'{n} {s}' for s, n in counts.items() if n)}), "
                 f"blinking at {self.blink_hz:.1f} Hz",
                 f"fx {c.fx:.3f}  fy {c.fy:.3f}  cx {c.cx:.3f}  cy {c.cy:.3f} px ({c.model})",
                 "distortion " + " ".join(f"{d:.5f}" for d in c.D),
                 f"reprojection RMS {self.rms:.4f} px; per view: "
                 + " ".join(f"{v.rms:.3f}" + ("*" if v.status == "outlier" else "") for v in self.views
                            if v.points is not None)]
        return "\n".join(lines)


@dataclass(frozen=True)
class StereoCalibration:
    """Two mono calibrations and the extrinsics between them (``stereo``:
    ``R``, ``T`` with ``x_right = R x_left + T`` m, and the rectification)."""

    left: Calibration
    right: Calibration
    stereo: StereoSolution


class _Collect(Sink):
    """Keeps the events and frames of a recording."""

    name = "calibration_input"
    consumes = (Kind.ANY,)

    def __init__(self) -> None:
        self.events: list[EventPacket] = []
        self.frames: list[FramePacket] = []

    def write(self, packet: Packet) -> None:
        if isinstance(packet, EventPacket):
            self.events.append(packet)
        elif isinstance(packet, FramePacket):
            self.frames.append(packet)


def read_recording(path: str) -> tuple[EventPacket | None, FramePacket | None]:
    """The events and frames of a recording (any format tectum reads; a
    ``?k=v`` tail passes source options)."""
    from tectum import Pipeline, concat, run

    uri, _, query = path.partition("?")
    params: dict[str, Any] = dict(kv.split("=", 1) for kv in query.split("&") if "=" in kv)
    p = Pipeline()
    p.source(uri, id="recording", **params)
    sink = _Collect()
    p.sink(sink, "recording")
    run(p)
    ev = concat(sink.events) if sink.events else None
    fr = concat(sink.frames) if sink.frames else None
    return (ev if isinstance(ev, EventPacket) else None), (fr if isinstance(fr, FramePacket) else None)


def detect_views(events: EventPacket, grid: Grid, period_us: float, *, pattern: Pattern = "dots",
                 duty: float = 0.5, tol: float = 0.25, window_periods: int = 5, min_fraction: float = 0.5,
                 still_px: float = 0.5) -> list[View]:
    """The still views of a recording of a blinking grid, each with its dots
    and, when the whole grid is among them, the ordered points (status
    ``used`` for now, ``partial`` or ``unordered`` otherwise). With
    ``pattern="checker"`` (a screen blinking a checkerboard's white squares)
    the points are the inner corners of the view's map of ON events at
    transitions, ``grid`` counting inner corners."""
    views: list[View] = []
    for t0, t1 in still_spans(events, period_us, duty=duty, tol=tol, window_periods=window_periods,
                              min_fraction=min_fraction, still_px=still_px):
        tr, wt = transition_map(events.slice_time(t0, t1), period_us, duty, tol)
        b: Blobs = blobs(tr, wt, (t1 - t0) / period_us, min_fraction)
        if pattern == "checker":
            pts = chessboard_corners(np.where(tr >= min_fraction * (t1 - t0) / period_us, wt, 0),
                                     (grid.cols, grid.rows))
            status: Status = "used" if pts is not None else "partial"
        else:
            pts = order_grid(b.xy, grid) if len(b) >= grid.size else None
            status = "used" if pts is not None else ("partial" if len(b) < grid.size else "unordered")
        views.append(View(t0, t1, b.xy, pts, status, transitions=tr))
    return views


def _period(events: EventPacket, frequency_hz: float) -> float:
    if frequency_hz > 0:
        return 1e6 / frequency_hz
    period = dominant_period(events)
    if period <= 0:
        raise CalibrationError(f"no blinking found: no pixel fires ON events repeatedly ({len(events):,} events); "
                               "is the pattern blinking, and in view?")
    return period


def _views_or_fail(events: EventPacket, grid: Grid, period_us: float, min_views: int, **kw: Any) -> list[View]:
    """Detected views, or a CalibrationError saying what was found."""
    views = detect_views(events, grid, period_us, **kw)
    hz = 1e6 / period_us
    if not views:
        tr, _ = transition_map(events, period_us, kw.get("duty", 0.5), kw.get("tol", 0.25))
        blinking = int(np.count_nonzero(tr >= 3))
        if blinking >= 10:
            raise CalibrationError(
                f"0 still views at {hz:.1f} Hz: {blinking} pixels blink, but the pattern never held still for "
                f"{kw.get('window_periods', 5) * 4} periods with the same dots (the board or camera kept moving, or "
                "timestamps jitter by more than a tenth of the ON time)")
        raise CalibrationError(
            f"no blinking found at {hz:.1f} Hz: 0 still views ({int(np.count_nonzero(tr))} pixels with any ON→OFF "
            f"transition at that period in {len(events):,} events); check --frequency and that the pattern blinks")
    whole = [v for v in views if v.points is not None]
    if len(whole) < min_views:
        partial = [len(v.dots) for v in views if v.status == "partial"]
        unordered = sum(v.status == "unordered" for v in views)
        what = (f"{len(views)} still views found at {hz:.1f} Hz, {len(whole)} with the whole "
                f"{grid.cols}x{grid.rows} grid")
        if partial:
            what += f", {len(partial)} partial (dots seen: {', '.join(map(str, partial))} of {grid.size})"
        if unordered:
            what += f", {unordered} where the dots did not form the grid (check --grid and --asymmetric)"
        raise CalibrationError(f"{what}; need at least {min_views} views of the whole board")
    return views


def _solve(views: list[View], grid: Grid, size: tuple[int, int], model: Model, k3: bool,
           min_views: int) -> tuple[Solution, list[View]]:
    whole = [i for i, v in enumerate(views) if v.points is not None]
    pts = [v.points for v in views if v.points is not None]
    sol = solve_mono(grid.object_points().astype(np.float64), pts, size, model=model, k3=k3, min_views=min_views)
    out = list(views)
    for k, i in enumerate(whole):
        status: Status = "used" if k in sol.used else "outlier"
        v = views[i]
        out[i] = View(v.t_start, v.t_end, v.dots, v.points, status, float(sol.view_rms[k]), v.transitions,
                      sol.residuals[k])
    return sol, out


def calibrate(recording: EventPacket | str, grid: tuple[int, int] | str, spacing: float, *,
              pattern: Pattern = "dots", frequency_hz: float = 0.0, asymmetric: bool = False,
              model: Model = "radtan", k3: bool = False,
              duty: float = 0.5, tol: float = 0.25, window_periods: int = 5, min_fraction: float = 0.5,
              still_px: float = 0.5, min_views: int = 5) -> Calibration:
    """Calibrate a camera from a recording of a blinking circle grid seen in
    several still poses (see :mod:`tectum.calibration`).

    ``recording`` events or a file; ``grid`` ``(cols, rows)`` dots or
    ``"COLSxROWS"`` (``pattern="checker"``: inner corners); ``spacing`` m between dots (OpenCV's convention, see
    :class:`Grid`); ``frequency_hz`` the blink frequency (0: the most
    common ON-to-ON interval); ``duty`` the lit fraction of a period; ``tol``
    the tolerance on the ON→OFF time; ``model`` ``radtan`` (k1 k2 p1 p2, and
    k3 with ``k3``) or ``equidistant`` (fisheye). Raises
    :class:`CalibrationError` with counts when fewer than ``min_views``
    views of the whole grid are found."""
    events = _events(recording)
    g = _grid(grid, spacing, asymmetric)
    period = _period(events, frequency_hz)
    views = _views_or_fail(events, g, period, min_views, pattern=pattern, duty=duty, tol=tol,
                           window_periods=window_periods, min_fraction=min_fraction, still_px=still_px)
    sol, views = _solve(views, g, events.sensor, model, k3, min_views)
    return Calibration(sol.camera, sol.rms, tuple(views), g, 1e6 / period)


def calibrate_stereo(left: EventPacket | str, right: EventPacket | str, grid: tuple[int, int] | str,
                     spacing: float, **kw: Any) -> StereoCalibration:
    """Calibrate two cameras that saw the same blinking board at the same
    time (keywords as :func:`calibrate`), then their extrinsics from the
    views both saw whole (views overlapping in time are pairs)."""
    cl = calibrate(left, grid, spacing, **kw)
    cr = calibrate(right, grid, spacing, **kw)
    pairs = [(a, b) for a in cl.views for b in cr.views if a.points is not None and b.points is not None
             and min(a.t_end, b.t_end) - max(a.t_start, b.t_start) > 0.5 * min(a.t_end - a.t_start,
                                                                                 b.t_end - b.t_start)]
    if len(pairs) < 3:
        raise CalibrationError(f"stereo: {len(pairs)} views where both cameras saw the whole board at the same "
                               f"time (left {sum(v.points is not None for v in cl.views)}, right "
                               f"{sum(v.points is not None for v in cr.views)}); need at least 3")
    obj = cl.grid.object_points().astype(np.float64)
    st = solve_stereo(obj, [a.points for a, _ in pairs], [b.points for _, b in pairs],  # type: ignore[misc]
                      cl.camera, cr.camera)
    return StereoCalibration(cl, cr, st)


def _events(recording: EventPacket | str) -> EventPacket:
    if isinstance(recording, EventPacket):
        return recording
    ev, _ = read_recording(str(recording))
    if ev is None or len(ev) == 0:
        raise CalibrationError(f"{recording}: no events")
    return ev


def _grid(grid: tuple[int, int] | str | Sequence[int], spacing: float, asymmetric: bool) -> Grid:
    if isinstance(grid, str):
        try:
            c, r = (int(v) for v in grid.lower().split("x"))
        except ValueError:
            raise ValueError(f"grid {grid!r}: expected COLSxROWS, e.g. 7x5") from None
    else:
        c, r = (int(v) for v in grid)
    return Grid(c, r, float(spacing), asymmetric)
