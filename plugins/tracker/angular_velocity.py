"""``tracker.angular_velocity``: the camera's angular velocity by contrast
maximisation with a rotational warp (Gallego & Scaramuzza, RA-L 2017,
"Accurate angular velocity estimation with an event camera").

Under a pure rotation (or a scene far away) the events of one window, warped
back to the window's middle by the right angular velocity ω, pile up on the
edges that caused them: the image of warped events (IWE) is sharpest. Per
window the operator maximises the IWE's focus over ω with its analytic
gradient and BFGS, warm-started from the previous window's ω. The focus is
the variance of the B-spline-voted IWE (pixels of ``iwe_px`` px) over the
sensor less, on each side, the window's image motion (see
:func:`estimate_rotation` and :mod:`tectum.plugins._cmax`): a fixed
region whose pixels all see a whole window of events. The sum of squares
over the whole IWE used before leant towards warps that keep the events
inside a smaller area (underestimated rates: ``tectum bench tracker`` had
up to 25 % of the peak error on the smallest axis at 100 °/s). A window
with no valid previous estimate starts from ω = 0 and climbs coarse to fine
(IWE pixels ``2 iwe_px``, then ``iwe_px``).

Event coordinates are undistorted with the calibration (``calib=`` or the
``calib.txt`` beside the recording) and warped on normalised coordinates
(first-order rotation, see :mod:`tectum.plugins._cmax`).

Windows: ``window_events`` events sliding by ``step_events`` (the result
rate follows the event rate: at 1 Mev/s, the default 60,000 events sliding
by 10,000 give a result every 10 ms from 60 ms of events), or with
``window_us`` > 0, windows of ``window_us`` µs sliding by ``step_us`` from
the stream's start, emitted when the watermark passes their end. Either way
the windows depend on the events and times only, never on how packets cut
the stream. A window must hold enough motion to focus, and the precision
grows with the motion it spans, not with its event count: a window longer
than ``max_events`` is thinned evenly (every k-th event) to at most that
many. Measured on the bench's 240x180 rotation scenes: 30,000 events
(about 10 px of motion) gave 7-10 % of the peak error at 100 °/s, 60,000
thinned to 30,000 give 1-2 %, at the same cost.

Output (:class:`~tectum.AngularVelocityPacket`): per window ``t`` (its last
event's time; with ``window_us``, its end - 1), ``wx, wy, wz`` rad/s in the
camera frame (OpenCV axes: x right, y down, z forward), ``confidence`` =
``1 - F(0)/F(ω)`` (how much sharper the warped image is than the unwarped
one: near 0 when the events show no motion the warp explains, as with a
static camera; ω is then whatever the flat focus peaks at, up to about
1 rad/s on time-shuffled events: trust ω by its confidence), ``events`` in
the window. A window with fewer
than ``min_events`` events landing in the image gives no sample and is
counted (``skipped_few_events``); an optimiser result that is not finite is
dropped and counted (``skipped_not_finite``): no NaN goes downstream.

Cost: per window a few (typically 4-6) focus-and-gradient evaluations,
each two passes over the (thinned) window's events (warp and vote, gather)
and a clear of the votes' bounding box; memory: the events of one window.
"""

from __future__ import annotations

import numpy as np

from tectum import AngularVelocityPacket, EventPacket, Kind, Operator, Packet
from tectum.camera import Camera
from tectum.plugins._cmax import maximise_rotation, rotation_focus_grad

__all__ = ["AngularVelocity", "estimate_rotation"]

#: IWE margin around the sensor, px (events warped just outside still vote)
MARGIN_PX = 8


def _need_camera(calib: str) -> Camera:
    if not calib:
        raise ValueError(
            "tracker.angular_velocity needs the camera intrinsics: give calib= (a calibration file: UZH "
            "calib.txt, OpenCV YAML/JSON or a ROS camera_info YAML; or inline 'fx;fy;cx;cy[;k1;k2;p1;p2;k3]' px), "
            "or put a calib.txt beside the recording the pipeline reads")
    from tectum.camera import camera_from

    return camera_from(calib)


class _Images:
    """Zeroed IWE buffers per pixel size (``scales``, px, coarse to fine),
    and the projection of each."""

    def __init__(self, camera: Camera, sensor: tuple[int, int], scales: tuple[float, ...]) -> None:
        w, h = sensor
        self.scales = scales
        self.f = float(camera.fx)
        self.by_scale: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        for s in scales:
            inv = 1.0 / s
            img = np.zeros((int(np.ceil((h + 2 * MARGIN_PX) * inv)) + 2, int(np.ceil((w + 2 * MARGIN_PX) * inv)) + 2))
            cam = np.array([camera.fx * inv, camera.fy * inv, (camera.cx + MARGIN_PX) * inv,
                            (camera.cy + MARGIN_PX) * inv])
            self.by_scale[s] = (img, cam)
        self.sensor = sensor

    def rect(self, s: float, border: float) -> np.ndarray:
        """The focus region at IWE pixel size ``s``: the sensor less ``border``
        px on each side (at most a quarter of its height), as inclusive IWE
        pixel indices ``(c0, c1, r0, r1)``."""
        w, h = self.sensor
        b = min(border, 0.25 * min(w, h))
        return np.array([np.ceil((b + MARGIN_PX) / s), np.floor((w - 1 - b + MARGIN_PX) / s),
                         np.ceil((b + MARGIN_PX) / s), np.floor((h - 1 - b + MARGIN_PX) / s)])


def estimate_rotation(xn: np.ndarray, yn: np.ndarray, dt: np.ndarray, images: _Images, w0: np.ndarray | None,
                      H: np.ndarray, max_iter: int, tol_px: float) -> tuple[np.ndarray, float, float, int, int]:
    """ω (rad/s) maximising the focus of events at normalised coordinates
    ``(xn, yn)`` seen ``dt`` s from the reference time; from ``w0`` at the
    finest IWE pixel size, or from zero coarse to fine when ``w0`` is None.
    ``H`` is the BFGS inverse-Hessian estimate (kept from window to window,
    see :func:`~tectum.plugins._cmax.maximise_rotation`). The focus region
    is the sensor less, on each side, the image motion of the window's end
    events at the centre under the starting ω (``|ω| span f`` px): scene
    points inside it stay in view for the whole window, so every pixel of
    it gathers a whole window of events (see the module). Returns ``(ω,
    focus at ω, focus at 0, events that voted, focus evaluations)``."""
    n = xn.shape[0]
    u, v = np.empty(n), np.empty(n)
    span = max(float(np.abs(dt).max()) if n else 0.0, 1e-6)
    scales = images.scales if w0 is None else images.scales[-1:]
    w = np.zeros(3) if w0 is None else w0.copy()
    tol = tol_px / (images.f * span)  # rad/s moving an event at the window's end by tol_px px
    f, m, evals = 0.0, 0, 0
    for s in scales:
        img, cam = images.by_scale[s]
        if len(scales) > 1:
            H[0, 0] = 0.0  # curvature differs per pixel size: start afresh
        rect = images.rect(s, float(np.linalg.norm(w)) * span * images.f)
        w, f, m, e = maximise_rotation(xn, yn, dt, w, H, cam, img, u, v, max_iter, tol, rect)
        evals += e
    f0, _ = rotation_focus_grad(xn, yn, dt, np.zeros(3), cam, img, u, v, np.empty(3), rect)
    return w, float(f), float(f0), int(m), evals + 1


class AngularVelocity(Operator):
    """Angular velocity (rad/s, camera frame) by contrast maximisation with a
    rotational warp (see the module).

    Parameters
    ----------
    calib:
        Calibration file (UZH calib.txt, OpenCV YAML/JSON, ROS camera_info)
        or inline ``fx;fy;cx;cy[;k1;k2;p1;p2;k3]`` (px); defaults to the
        calibration beside the source recording. Required.
    window_events:
        Events per window.
    step_events:
        Events between window starts (0: a sixth of a window).
    window_us:
        > 0: windows of this many µs instead of event counts.
    step_us:
        µs between window starts with ``window_us`` (0: half a window).
    max_events:
        Events of a window the focus uses: a longer window is thinned evenly
        (every k-th event) to at most this many.
    min_events:
        Fewer (used) events landing in the image: no estimate (a counted skip).
    iwe_px:
        IWE pixel size, px (a cold start climbs from twice this).
    max_iter:
        BFGS iterations per window (per pixel size on a cold start).
    tol_px:
        Stop when a step moves the window's end events by less than this (px).
    """

    name = "tracker.angular_velocity"
    consumes = (Kind.EVENTS,)
    produces = (Kind.ANGULAR_VELOCITY,)
    heavy = True

    #: For the conformance check: inline intrinsics of a 48x36 sensor, small windows.
    conformance_params = {"calib": "40;40;24;18", "window_events": 600, "step_events": 400, "min_events": 100}

    @staticmethod
    def conformance_stream() -> Packet:
        """Events of a few points seen by a camera turning at a steady rate."""
        from tectum.plugins.repr.motion_compensated import _rotating_points

        return _rotating_points(duration_us=40_000, sensor=(48, 36), f=40.0)["events"]

    def __init__(self, calib: str = "", window_events: int = 60_000, step_events: int = 0, window_us: int = 0,
                 step_us: int = 0, max_events: int = 30_000, min_events: int = 500, iwe_px: float = 2.0,
                 max_iter: int = 20, tol_px: float = 0.2) -> None:
        if window_events < 1 or step_events < 0 or window_us < 0 or step_us < 0 or min_events < 1:
            raise ValueError("need window_events >= 1, step_events >= 0, window_us >= 0, step_us >= 0, "
                             "min_events >= 1")
        if max_events < min_events or not iwe_px >= 1 or max_iter < 1 or not tol_px > 0:
            raise ValueError("need max_events >= min_events, iwe_px >= 1, max_iter >= 1 and tol_px > 0")
        self.camera = _need_camera(calib)
        self.window_events = int(window_events)
        self.step_events = int(step_events) or max(1, self.window_events // 6)
        self.max_events, self.iwe_px = int(max_events), float(iwe_px)
        self.window_us = int(window_us)
        self.step_us = int(step_us) or max(1, self.window_us // 2)
        self.min_events, self.max_iter, self.tol_px = int(min_events), int(max_iter), float(tol_px)
        self.counts = {"windows": 0, "skipped_few_events": 0, "skipped_not_finite": 0, "evaluations": 0}
        self._t = np.empty(0, np.int64)
        self._x = np.empty(0, np.uint16)
        self._y = np.empty(0, np.uint16)
        self._next = 0              # event mode: buffer index of the next window's first event
        self._covered = 0           # event mode: buffer index up to which windows have run
        self._win: int | None = None  # time mode: start of the next window, µs
        self._covered_us: int | None = None  # time mode: end of the last window run, µs
        self._mark: int | None = None  # start of the next output packet's interval, µs
        self._end = 0  # t_end of the last input packet, µs
        self._w: np.ndarray | None = None  # the last valid estimate (warm start)
        self._H = np.zeros((3, 3))  # BFGS inverse Hessian carried between windows
        self._sensor: tuple[int, int] | None = None
        self._table = np.empty((0, 0, 2))
        self._images: _Images | None = None

    def warmup(self) -> None:
        twin = AngularVelocity(calib="40;40;24;18", window_events=600, step_events=600, min_events=10)
        stream = self.conformance_stream()
        assert isinstance(stream, EventPacket)
        twin.process(stream)

    # -- geometry -------------------------------------------------------------------------
    def _setup(self, sensor: tuple[int, int]) -> None:
        w, h = sensor
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        rays = self.camera.bearings(np.stack([u.ravel(), v.ravel()], axis=1))
        with np.errstate(invalid="ignore", divide="ignore"):
            table = rays[:, :2] / rays[:, 2:3]
        table[~np.isfinite(table).all(axis=1)] = 1e6  # no inverse: far outside, never votes
        self._table = np.ascontiguousarray(table.reshape(h, w, 2))
        self._images = _Images(self.camera, sensor, (2 * self.iwe_px, self.iwe_px))
        self._sensor = sensor

    # -- one window -------------------------------------------------------------------------
    def _window(self, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float, int] | None:
        """ω and confidence of one window's events, or None (a counted skip)."""
        self.counts["windows"] += 1
        if len(t) < self.min_events:
            self.counts["skipped_few_events"] += 1
            self._w = None
            return None
        assert self._images is not None
        n = len(t)
        if n > self.max_events:  # thinned evenly: the window's time span (its motion) counts, not its events
            k = -(-n // self.max_events)
            t, x, y = t[::k], x[::k], y[::k]
        xy = self._table[y, x]
        t_ref = 0.5 * (int(t[0]) + int(t[-1]))
        dt = (t - t_ref) * 1e-6
        w, f, f0, m, evals = estimate_rotation(np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1]), dt,
                                               self._images, self._w, self._H, self.max_iter, self.tol_px)
        self.counts["evaluations"] += evals
        if m < self.min_events:
            self.counts["skipped_few_events"] += 1
            self._w = None
            return None
        if not (np.isfinite(w).all() and np.isfinite(f) and f > 0):
            self.counts["skipped_not_finite"] += 1
            self._w = None
            return None
        self._w = w
        return w, float(min(1.0, max(0.0, 1.0 - f0 / f))), n

    # -- windows ----------------------------------------------------------------------------
    def process(self, packet: EventPacket) -> list[Packet]:
        if self._mark is None:
            self._mark = packet.t_start
            self._win = packet.t_start
        if self._sensor != packet.sensor:
            self._setup(packet.sensor)
        self._end = packet.t_end
        if len(packet):
            self._t = np.concatenate([self._t, packet.t])
            self._x = np.concatenate([self._x, packet.x])
            self._y = np.concatenate([self._y, packet.y])
        rows = self._by_time(packet.t_end) if self.window_us else self._by_count()
        return self._emit(rows, packet.t_end)

    def _by_count(self) -> list[tuple[int, np.ndarray, float, int]]:
        rows = []
        while len(self._t) - self._next >= self.window_events:
            a, b = self._next, self._next + self.window_events
            r = self._window(self._t[a:b], self._x[a:b], self._y[a:b])
            if r is not None:
                rows.append((int(self._t[b - 1]), *r))
            self._next += self.step_events
            self._covered = b
        k = min(self._next, len(self._t))
        self._drop(k)
        self._next -= k
        self._covered = max(0, self._covered - k)
        return rows

    def _by_time(self, watermark: int) -> list[tuple[int, np.ndarray, float, int]]:
        rows = []
        assert self._win is not None
        while self._win + self.window_us <= watermark:
            end = self._win + self.window_us
            a, b = np.searchsorted(self._t, [self._win, end])
            r = self._window(self._t[a:b], self._x[a:b], self._y[a:b])
            if r is not None:
                rows.append((end - 1, *r))
            self._win += self.step_us
            self._covered_us = end
        self._drop(int(np.searchsorted(self._t, self._win)))
        return rows

    def finish(self) -> list[Packet]:
        """End of stream: the events no window has covered yet (a stream
        shorter than a window, or the tail after the last one) make one last,
        shorter window, reported at the stream's end (``t_end`` of the last
        input packet, µs); with fewer than
        ``min_events`` events it is a counted skip like any other window."""
        if self._mark is None or not len(self._t):
            return []
        last = int(self._t[-1])
        if self.window_us:
            if self._covered_us is not None and self._covered_us > last:
                return []
            assert self._win is not None
            a = int(np.searchsorted(self._t, self._win))
        else:
            if self._covered >= len(self._t):
                return []
            a = self._next
        r = self._window(self._t[a:], self._x[a:], self._y[a:])
        self._drop(len(self._t))
        at = self._end  # the stream's end: after every earlier output, however the input was split
        return self._emit([(at, *r)] if r is not None else [], at + 1)

    def _drop(self, k: int) -> None:
        """Forget the first ``k`` buffered events."""
        if k:
            self._t, self._x, self._y = self._t[k:], self._x[k:], self._y[k:]

    def _emit(self, rows: list[tuple[int, np.ndarray, float, int]], watermark: int) -> list[Packet]:
        if not rows:
            return []
        assert self._mark is not None
        w = np.array([r[1] for r in rows])
        out = AngularVelocityPacket(np.array([r[0] for r in rows], np.int64), wx=w[:, 0], wy=w[:, 1], wz=w[:, 2],
                                    confidence=np.array([r[2] for r in rows]),
                                    events=np.array([r[3] for r in rows], np.int64),
                                    t_start=self._mark, t_end=watermark)
        self._mark = watermark
        return [out]
