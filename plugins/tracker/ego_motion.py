"""``tracker.ego_motion``: the camera's motion per window of events, with a
model ladder that picks the simplest motion model the events need.

Per window (``window_events`` events sliding by ``step_events``, or
``window_us`` µs), every rung of the ladder is fitted by contrast
maximisation on the even-indexed events and scored on the odd-indexed ones
(:mod:`tectum.plugins.tracker._ladder`, which documents the warps, the
collapse-proof focus and the held-out likelihood):

====  ===============  ====  ==============================================
code  model            P     parameters (``params[0:P]``)
====  ===============  ====  ==============================================
0     ``translation``  2     vx, vy px/s (image velocity)
1     ``rotation``     3     wx, wy, wz rad/s (camera frame, OpenCV axes)
2     ``similarity``   4     vx, vy px/s, r rad/s, s 1/s (roll and scale rate of the image)
3     ``homography``   8     d00 d01 d02 d10 d11 d12 d20 d21 1/s (homography rate, normalised coordinates)
4     ``6dof``         6     wx, wy, wz rad/s, ux, uy, uz 1/s (velocity over the scene depth, v / Z)
====  ===============  ====  ==============================================

The choice is the rung with the fewest parameters whose mean held-out
log-likelihood falls short of the best by no more than ``max(k_se`` paired
standard errors, ``tol`` of the best's gain over no motion, ``tol_rel`` of
its gain over the translation rung``)``: statistical noise alone would let
every real recording pick the richest rung (real scenes are never exactly
any model, and with 10^4 held-out events tiny gains are "significant"),
so the two shares set how much better a richer rung must be to matter.
The defaults were set on simulated scenes (rotation, translation before a
plane, several depths, 6-DoF) and hold on the four ECD excerpts (see
``tectum bench tracker``). The window must hold some motion (a few px at
the image border between its first and last event): with less, the rungs
barely differ and the choice is unreliable; 30 000 events are 5-110 ms on
the ECD excerpts.

Output: a ``motion_model`` stream (:class:`MotionModelPacket`), one sample
per window stamped with its last event's time: ``model`` (the code
above), ``params`` (8, the chosen rung's, NaN-padded), ``scores`` (5: every
rung's mean held-out log-likelihood in nats per event, NaN where skipped)
and ``events``. ``--sink motion.csv`` writes columns ``t, model, p0..p7,
score_translation .. score_6dof, events``.

Calibration (``calib=`` or the recording's calib.txt): events are
undistorted and normalised by the intrinsics. Without it ``rotation`` and
``6dof`` (which need the focal length) are skipped, and counted, unless
``models`` names them (then a ValueError says how to give it); the image
rungs use the pixel grid normalised by a nominal focal ``max(w, h)`` about
the sensor's centre. Windows with fewer than ``min_events`` events give no
sample (counted), never NaN parameters.

Positions are dithered by up to half a pixel (a fixed pseudo-random
sequence per window): the bilinear IWE of events on integer pixels has a
kink maximum at zero motion that traps the optimiser.

Cost: five fits of a few dozen evaluations each (see ``_ladder``), about
10^4 events/s on one core; heavy, so it runs offloaded.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tectum import EventPacket, Field, Kind, Operator, Packet, SamplePacket, register_kind
from tectum.camera import Camera, camera_from

from ._ladder import MODELS, N_PARAMS, NEEDS_CALIBRATION, Frame, LadderResult, run_ladder

__all__ = ["EgoMotion", "MotionModelPacket", "MODEL_CODES", "moving_points"]

#: The ``model`` field's codes.
MODEL_CODES = {m: i for i, m in enumerate(MODELS)}
#: Parameter slots of the ``params`` field.
N_SLOTS = 8


@register_kind
class MotionModelPacket(SamplePacket):
    """Ego-motion from the model ladder, one sample per window ending at
    ``t``: the chosen ``model`` (0 translation, 1 rotation, 2 similarity,
    3 homography, 4 6dof), its ``params`` (NaN-padded to 8; units per model
    in :mod:`tectum.plugins.tracker.ego_motion`), the held-out ``scores``
    of every rung (nats per event, NaN where skipped) and the window's
    event count."""

    kind = Kind("motion_model")
    fields = {
        "model": Field("i8", (), "", doc="0 translation, 1 rotation, 2 similarity, 3 homography, 4 6dof"),
        "params": Field("f8", (N_SLOTS,), "per model", names=tuple(f"p{i}" for i in range(N_SLOTS)),
                        doc="the chosen model's parameters, NaN-padded"),
        "scores": Field("f8", (len(MODELS),), "nats/event", names=tuple(f"score_{m}" for m in MODELS),
                        doc="held-out log-likelihood per rung, NaN where skipped"),
        "events": Field("i8", (), "events", optional=True, doc="events in the window"),
    }


def _models(spec: str | Sequence[str]) -> tuple[str, ...]:
    names = [m.strip() for m in (spec.split(",") if isinstance(spec, str) else spec) if m.strip()]
    bad = [m for m in names if m not in MODELS]
    if bad:
        raise ValueError(f"models: unknown {bad} (choose from {', '.join(MODELS)})")
    return tuple(names)


class EgoMotion(Operator):
    """Ego-motion per window with a model ladder (see the module docstring).

    Parameters
    ----------
    calib:
        Calibration file (OpenCV YAML/JSON, ROS camera_info, UZH calib.txt)
        or inline ``fx;fy;cx;cy[;k1;k2;p1;p2;k3]`` (px); defaults to the
        calibration beside the source recording; empty: no calibration.
    window_events, step_events:
        Events per window and between window starts (0: = window_events).
    window_us:
        Fixed windows of this many µs instead (0: windows by event count).
    models:
        Comma-separated rungs to fit (empty: all the calibration allows).
    min_events:
        Fewer events in a window: no sample (counted).
    max_disp_px:
        Bound of each parameter, as px rms of displacement over the window.
    tol, tol_rel, k_se:
        The choice's margins (module docstring).
    """

    name = "tracker.ego_motion"
    consumes = (Kind.EVENTS,)
    produces = (MotionModelPacket.kind,)
    heavy = True

    def __init__(self, calib: str = "", window_events: int = 30_000, step_events: int = 0, window_us: int = 0,
                 models: str = "", min_events: int = 2000, max_disp_px: float = 30.0, tol: float = 0.01,
                 tol_rel: float = 0.1, k_se: float = 1.0) -> None:
        if window_events < 2 or step_events < 0 or window_us < 0 or min_events < 2:
            raise ValueError("need window_events >= 2, step_events >= 0, window_us >= 0, min_events >= 2")
        if max_disp_px <= 0 or tol < 0 or tol_rel < 0 or k_se < 0:
            raise ValueError("need max_disp_px > 0 and tol, tol_rel, k_se >= 0")
        asked = _models(models)
        self.camera: Camera | None = camera_from(calib) if calib else None
        if self.camera is None and NEEDS_CALIBRATION & set(asked):
            raise ValueError(f"models {sorted(NEEDS_CALIBRATION & set(asked))} need the camera calibration: give "
                             "calib= (a calibration file: UZH calib.txt, OpenCV YAML/JSON or a ROS camera_info "
                             "YAML; or inline 'fx;fy;cx;cy[;k1;k2;p1;p2;k3]' px), or read a recording with a "
                             "calib.txt beside it")
        wanted = asked or MODELS
        self.models = tuple(m for m in wanted if self.camera is not None or m not in NEEDS_CALIBRATION)
        self.skipped_rungs = len(wanted) - len(self.models)
        self.window_events, self.window_us = int(window_events), int(window_us)
        self.step = int(step_events) or int(window_events)
        self.min_events, self.max_disp = int(min_events), float(max_disp_px)
        self.tol, self.tol_rel, self.k_se = float(tol), float(tol_rel), float(k_se)
        self.counts = {"windows": 0, "too_few_events": 0, "rungs_skipped_no_calibration": 0,
                       "events_not_undistorted": 0}
        self._t = np.empty(0, np.int64)   # buffered events (the open windows')
        self._x = np.empty(0, np.float64)
        self._y = np.empty(0, np.float64)
        self._sensor: tuple[int, int] | None = None
        self._start = 0           # windows by count: index (in the buffer) of the next window's first event
        self._win_end: int | None = None  # windows by time: end of the open window, µs
        self._k = 0               # windows so far (seeds the dither)
        self._prev: dict[str, np.ndarray] = {}
        self._rays: tuple[tuple[int, int], np.ndarray] | None = None

    #: For the conformance check: a 64x48 sensor, small windows.
    conformance_params = {"calib": "40;40;31.5;23.5", "window_events": 1000, "step_events": 700,
                          "min_events": 300}

    @staticmethod
    def conformance_stream() -> EventPacket:
        """Points on a plane seen by a camera translating and turning (for the conformance check)."""
        return moving_points(duration_us=24_000, velocity=(2.0, -1.0, 1.0), omega=(1.0, 2.0, -1.0), n_points=24,
                             period_us=200, seed=2)

    def warmup(self) -> None:
        fr = Frame(np.linspace(-0.3, 0.3, 64), np.linspace(-0.2, 0.2, 64), np.linspace(-1e-3, 1e-3, 64), 40.0,
                   40.0, 16.0, 12.0, 32, 24, 4)
        run_ladder(fr, self.models, {}, max_disp_px=self.max_disp)

    # -- windows ------------------------------------------------------------------
    def process(self, packet: EventPacket) -> list[Packet]:
        if len(packet):
            self._sensor = packet.sensor
            self._t = np.concatenate([self._t, packet.t])
            self._x = np.concatenate([self._x, packet.x])
            self._y = np.concatenate([self._y, packet.y])
        if self.window_us:
            if self._win_end is None:
                self._win_end = packet.t_start + self.window_us
            return self._by_time(packet.t_end)
        return self._by_count(final=False)

    def finish(self) -> list[Packet]:
        if self.window_us:
            return self._by_time(None)
        return self._by_count(final=True)

    def _drop(self, n: int) -> None:
        self._t, self._x, self._y = self._t[n:], self._x[n:], self._y[n:]

    def _by_count(self, final: bool) -> list[Packet]:
        rows: list[tuple[int, LadderResult, int]] = []
        n = len(self._t)
        while n - self._start >= self.window_events:
            rows += self._run(self._start, self._start + self.window_events)
            self._start += self.step
        if final and self._start < n:
            # the rest, shorter than a window: the events no window has covered yet
            if n - self._start >= self.min_events:
                rows += self._run(self._start, n)
            else:
                self.counts["too_few_events"] += 1
            self._start = n
        cut = min(self._start, n)
        self._drop(cut)
        self._start -= cut
        return self._packet(rows)

    def _by_time(self, upto: int | None) -> list[Packet]:
        rows: list[tuple[int, LadderResult, int]] = []
        assert self._win_end is not None
        while len(self._t) and (upto is None or upto >= self._win_end):
            k = int(np.searchsorted(self._t, self._win_end))
            if k >= self.min_events:
                rows += self._run(0, k)
            elif k:
                self.counts["too_few_events"] += 1
            self._drop(k)
            self._win_end += self.window_us
        if upto is not None and not len(self._t) and upto >= self._win_end:  # skip empty windows
            self._win_end += ((upto - self._win_end) // self.window_us + 1) * self.window_us
        return self._packet(rows)

    def _run(self, i: int, j: int) -> list[tuple[int, LadderResult, int]]:
        """Fit the ladder on the buffered events i..j: [(time, result, events)], empty if skipped."""
        self.counts["windows"] += 1
        self.counts["rungs_skipped_no_calibration"] += self.skipped_rungs
        fr = self._frame(self._t[i:j], self._x[i:j], self._y[i:j])
        if len(fr.x) < self.min_events:
            self.counts["too_few_events"] += 1
            return []
        res = run_ladder(fr, self.models, self._prev, max_disp_px=self.max_disp, tol=self.tol,
                         tol_rel=self.tol_rel, k_se=self.k_se)
        self._prev = {m: f.theta for m, f in res.fits.items() if f is not None}
        return [(int(self._t[j - 1]), res, j - i)]

    def _frame(self, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> Frame:
        """A window's events as normalised, undistorted, dithered coordinates."""
        assert self._sensor is not None
        w, h = self._sensor
        rng = np.random.default_rng(self._k)
        self._k += 1
        u = x + rng.uniform(-0.5, 0.5, len(t))
        v = y + rng.uniform(-0.5, 0.5, len(t))
        t_ref = 0.5 * (float(t[0]) + float(t[-1]))
        dt = (t - t_ref) * 1e-6
        if self.camera is not None:
            cam = self.camera
            und = cam.undistort_points(np.stack([u, v], axis=1))
            ok = np.isfinite(und).all(axis=1)
            self.counts["events_not_undistorted"] += int((~ok).sum())
            fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
            x, y, dt = (und[ok, 0] - cx) / fx, (und[ok, 1] - cy) / fy, dt[ok]
        else:
            fx = fy = float(max(w, h))
            cx, cy = 0.5 * (w - 1), 0.5 * (h - 1)
            x, y = (u - cx) / fx, (v - cy) / fy
        margin = max(4, int(0.15 * max(w, h)))
        return Frame(np.ascontiguousarray(x), np.ascontiguousarray(y), np.ascontiguousarray(dt), fx, fy, cx, cy,
                     w, h, margin)

    def _packet(self, rows: list[tuple[int, LadderResult, int]]) -> list[Packet]:
        good = rows
        if not good:
            return []
        t = np.array([g[0] for g in good], np.int64)
        model = np.array([MODEL_CODES[g[1].model] for g in good], np.int64)
        params = np.full((len(good), N_SLOTS), np.nan)
        scores = np.full((len(good), len(MODELS)), np.nan)
        for i, (_t, r, _n) in enumerate(good):
            fit = r.fits[r.model]
            assert fit is not None
            params[i, :N_PARAMS[r.model]] = fit.theta
            scores[i] = [r.scores[m] for m in MODELS]
        events = np.array([g[2] for g in good], np.int64)
        return [MotionModelPacket(t, model=model, params=params, scores=scores, events=events,
                                  t_start=int(t[0]), t_end=int(t[-1]) + 1)]


def moving_points(duration_us: int = 40_000, sensor: tuple[int, int] = (64, 48), f: float = 40.0,
                  velocity: tuple[float, float, float] = (0.0, 0.0, 0.0),
                  omega: tuple[float, float, float] = (0.0, 0.0, 0.0), depth: float = 1.0, n_points: int = 60,
                  period_us: int = 50, seed: int = 0) -> EventPacket:
    """Events of ``n_points`` points on the plane ``Z = depth`` (m) seen by a
    pinhole camera (focal ``f`` px, centred) moving with ``velocity`` (m/s)
    and turning at ``omega`` (rad/s), both constant in the camera frame; each
    point gives one event (rounded to the pixel) every ``period_us`` µs
    while in view. For tests: translation (omega 0), rotation (velocity 0)."""
    from tectum.camera import so3_exp

    rng = np.random.default_rng(seed)
    w, h = sensor
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    P0 = np.stack([(rng.uniform(-0.1, 1.1, n_points) * w - cx) / f * depth,
                   (rng.uniform(-0.1, 1.1, n_points) * h - cy) / f * depth, np.full(n_points, depth)], axis=1)
    ts = np.arange(0, duration_us, period_us, dtype=np.int64)
    v, om = np.asarray(velocity, np.float64), np.asarray(omega, np.float64)
    out_t, out_x, out_y = [], [], []
    for t in ts:
        s = t * 1e-6
        R = np.asarray(so3_exp(om * s))           # world-from-camera orientation at t (camera at 0 = world)
        c = v * s if not om.any() else _centre(v, om, s)
        Pc = (P0 - c) @ R                          # camera coordinates: R^T (P - c)
        ok = Pc[:, 2] > 1e-3
        u = f * Pc[:, 0] / np.where(ok, Pc[:, 2], 1.0) + cx
        vv = f * Pc[:, 1] / np.where(ok, Pc[:, 2], 1.0) + cy
        ok &= (u > -0.5) & (vv > -0.5) & (u < w - 0.5) & (vv < h - 0.5)
        # stagger the points within the period so that time stamps are spread
        sel = np.flatnonzero(ok)
        out_t.append(t + (sel * period_us) // n_points)
        out_x.append(np.round(u[sel]))
        out_y.append(np.round(vv[sel]))
    t_all = np.concatenate(out_t)
    order = np.argsort(t_all, kind="stable")
    x_all, y_all = np.concatenate(out_x)[order], np.concatenate(out_y)[order]
    pol = np.where(np.arange(len(t_all)) % 2 == 0, 1, -1).astype(np.int8)
    return EventPacket.from_arrays(t_all[order], x_all, y_all, pol, sensor=sensor, t_start=0, t_end=duration_us)


def _centre(v: np.ndarray, om: np.ndarray, s: float, steps: int = 16) -> np.ndarray:
    """Camera centre at ``s`` seconds for a velocity ``v`` constant in the
    turning camera frame: the integral of R(t) v (midpoint rule)."""
    from tectum.camera import so3_exp

    c = np.zeros(3)
    dt = s / steps
    for i in range(steps):
        c += np.asarray(so3_exp(om * (i + 0.5) * dt)) @ v * dt
    return c

