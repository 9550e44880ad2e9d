"""A blinking calibration board seen by a still, distorted camera (truth for ``tectum calibrate``).

The board is a grid of dots (``cols x rows``, OpenCV's symmetric or
asymmetric circle grid) on a plane; the dots are LEDs or screen dots that
blink at ``blink_hz`` (square wave with linear edges of ``rise_us``), the
board around them is a dim reflective surface, the rest of the scene
darker still. The board holds still at each pose for ``still_us`` and moves
to the next one in ``move_us`` (the "views" of a calibration).

Lens distortion: each pixel (``supersample`` x ``supersample`` samples per
pixel) is rendered along its *distorted* ray, the camera model's inverse
(:meth:`tectum.camera.Camera.undistort_normalized`) intersected with the
board plane, so the image holds exactly what a camera with ``camera.K`` and
``camera.D`` would see; the rest of the simulator has no lens.

Events come from the simulator's DVS pixel model (:func:`.dvs.dvs_step`,
per-pixel thresholds with spread ``sigma_c``), sampled at every corner of
the blink waveform (between corners the intensity is a linear ramp, whose
log the pixel model takes as linear: event times within an edge of
``rise_us`` are approximate, the edges' order is exact) and
``flicker_samples`` times per flicker period.
Non-idealities: shot noise ``noise_hz`` events per pixel per second (random
polarity), mains flicker ``flicker_hz`` of depth ``flicker_depth`` on part of
the background (a lamp), and Gaussian
timestamp jitter ``jitter_us``.

Event rate: each dot pixel fires about ``log(led / board_level) / c``
events per edge (3-4 with the defaults), twice per period.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from tectum import EventPacket
from tectum.camera import Camera, quat_slerp, quat_to_rot, rot_to_quat, so3_exp

from .dvs import dvs_step

__all__ = ["Board", "BoardTruth", "board_poses", "simulate_board", "coverage_kernel", "levels_kernel"]


@dataclass(frozen=True)
class Board:
    """A circle grid: ``cols`` dots per row, ``rows`` rows, ``spacing`` m
    between neighbouring dots of a row (symmetric) or, for an ``asymmetric``
    grid, half the distance between neighbours of a row (OpenCV's
    ``squareSize``: dot ``(i, j)`` at ``((2 j + i % 2) s, i s)``); dots of
    ``radius`` m. A ``checker`` board is a checkerboard of squares of
    ``spacing`` m whose white squares blink: ``cols x rows`` inner corners
    at ``(j s, i s)``, the square at the origin's lower right white."""

    cols: int = 7
    rows: int = 5
    spacing: float = 0.03
    radius: float = 0.0075
    asymmetric: bool = False
    checker: bool = False

    @property
    def kind(self) -> int:
        """0 symmetric dots, 1 asymmetric dots, 2 checkerboard (for the kernels)."""
        return 2 if self.checker else int(self.asymmetric)

    def object_points(self) -> np.ndarray:
        """Dot centres (or inner corners) (rows*cols, 3) m in the board
        frame, row by row, as OpenCV's circle grid orders them."""
        i, j = np.divmod(np.arange(self.rows * self.cols), self.cols)
        xs = (2 * j + i % 2) * self.spacing if self.asymmetric else j * self.spacing
        return np.column_stack([xs, i * self.spacing, np.zeros(len(i))]).astype(np.float64)

    def extent(self) -> tuple[float, float, float, float]:
        """The board's rectangle ``(x0, y0, x1, y1)`` m: the dots and one
        spacing of margin (a checkerboard: its squares and one more)."""
        pts = self.object_points()
        m = 2 * self.spacing if self.checker else self.spacing
        return (float(pts[:, 0].min() - m), float(pts[:, 1].min() - m),
                float(pts[:, 0].max() + m), float(pts[:, 1].max() + m))


@dataclass
class BoardTruth:
    """What the camera saw: its true ``camera``, the ``board``, the
    camera-from-board poses ``R`` (V, 3, 3) and ``t`` (V, 3) m of each still
    view, the views' spans ``spans`` (V, 2) µs, and the dot centres
    projected through the lens ``pixels`` (V, N, 2) px."""

    camera: Camera
    board: Board
    R: np.ndarray
    t: np.ndarray
    spans: np.ndarray
    pixels: np.ndarray = field(repr=False)
    blink_hz: float = 0.0


def board_poses(camera: Camera, board: Board, n: int, *, distance: float = 0.0, tilt_deg: float = 30.0,
                margin_px: float = 4.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` camera-from-board poses ``(R (n, 3, 3), t (n, 3) m)`` with the
    whole board in view (every dot ``margin_px`` inside the image, through
    the lens): tilted up to ``tilt_deg`` about the board's x and y axes,
    turned up to 10° about its normal, spread over the image. ``distance``
    m (default: where the board fills about half the image width)."""
    w, h = camera._size()
    x0, y0, x1, y1 = board.extent()
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    if distance <= 0:
        distance = 1.6 * (x1 - x0) * camera.fx / w
    rng = np.random.default_rng(seed)
    obj = board.object_points()
    Rs: list[np.ndarray] = []
    ts: list[np.ndarray] = []
    for _ in range(2000 * n):
        if len(Rs) == n:
            break
        tilt = np.radians(tilt_deg) * rng.uniform(-1, 1, 2)
        R = so3_exp(np.array([tilt[0], tilt[1], np.radians(10.0) * rng.uniform(-1, 1)]))
        aim = camera.bearings(np.array([[rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h]]))[0]
        d = distance * rng.uniform(0.85, 1.15)
        t = aim / aim[2] * d - R @ centre
        px = camera.project(obj @ R.T + t)
        if np.all(np.isfinite(px)) and np.all((px > margin_px) & (px < np.array([w, h]) - 1 - margin_px)):
            Rs.append(R)
            ts.append(t)
    if len(Rs) < n:
        raise ValueError(f"board_poses: only {len(Rs)} of {n} poses keep the whole board in view; "
                         "lower tilt_deg or move the board away (distance)")
    return np.array(Rs), np.array(ts)


@njit(cache=True)
def coverage_kernel(rays, R, t, cols, rows, spacing, radius, kind, box, cov_board, cov_dot):  # type: ignore[no-untyped-def]
    """Fraction of each pixel's samples on the board and on a dot (or a
    white square).

    ``rays`` (H, W, S, 2) normalised undistorted coordinates of each
    pixel's samples (NaN: no ray); ``R``, ``t`` camera-from-board; grid
    ``cols``, ``rows``, ``spacing`` m, ``radius`` m, ``kind`` (see
    :attr:`Board.kind`); ``box`` the board rectangle (x0, y0, x1, y1) m.
    Writes ``cov_board`` and ``cov_dot`` (H, W)."""
    H, W, S = rays.shape[0], rays.shape[1], rays.shape[2]
    n0, n1, n2 = R[0, 2], R[1, 2], R[2, 2]
    dist = n0 * t[0] + n1 * t[1] + n2 * t[2]
    r2 = radius * radius
    for v in range(H):
        for u in range(W):
            cb = 0.0
            cd = 0.0
            for s in range(S):
                x = rays[v, u, s, 0]
                y = rays[v, u, s, 1]
                den = n0 * x + n1 * y + n2
                if not (den * dist > 0):  # NaN ray, parallel, or plane behind
                    continue
                k = dist / den
                px, py, pz = k * x - t[0], k * y - t[1], k - t[2]
                bx = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
                by = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
                if bx < box[0] or bx > box[2] or by < box[1] or by > box[3]:
                    continue
                cb += 1.0
                if kind == 2:
                    a = int(math.floor(bx / spacing)) + 1
                    b = int(math.floor(by / spacing)) + 1
                    if 0 <= a <= cols and 0 <= b <= rows and (a + b) % 2 == 0:
                        cd += 1.0
                    continue
                i = int(math.floor(by / spacing + 0.5))
                if i < 0 or i >= rows:
                    continue
                off = i % 2 if kind == 1 else 0
                step = 2.0 if kind == 1 else 1.0
                j = int(math.floor((bx / spacing - off) / step + 0.5))
                if j < 0 or j >= cols:
                    continue
                dx = bx - (j * step + off) * spacing
                dy = by - i * spacing
                if dx * dx + dy * dy <= r2:
                    cd += 1.0
            cov_board[v, u] = cb / S
            cov_dot[v, u] = cd / S


@njit(cache=True)
def levels_kernel(cov_board, cov_dot, lamp, dark, board, led, flicker, emit, eps, out):  # type: ignore[no-untyped-def]
    """Log intensity per pixel (flat): the background ``dark`` (times the
    flicker factor ``flicker`` where ``lamp`` is 1), the board ``board``
    (dots included), plus the dots' emission ``emit * led``."""
    for i in range(cov_board.shape[0]):
        cb, cd = cov_board[i], cov_dot[i]
        lin = (1.0 + (flicker - 1.0) * lamp[i]) * (1.0 - cb) * dark + cb * board + cd * emit * led
        out[i] = math.log(lin + eps)


_RAYS: dict[bytes, np.ndarray] = {}


def _sample_rays(camera: Camera, supersample: int) -> np.ndarray:
    """Normalised undistorted coordinates (H, W, S*S, 2) of each pixel's
    samples (the last camera's kept: benchmarks simulate one camera often)."""
    key = camera.params.tobytes() + np.array([*camera._size(), supersample]).tobytes()
    if key not in _RAYS:
        _RAYS.clear()
        _RAYS[key] = _render_rays(camera, supersample)
    return _RAYS[key]


def _render_rays(camera: Camera, supersample: int) -> np.ndarray:
    w, h = camera._size()
    s = supersample
    off = (np.arange(s) + 0.5) / s - 0.5
    ou, ov = np.meshgrid(off, off)
    vv, uu = np.mgrid[0:h, 0:w]
    px = np.stack([uu[:, :, None] + ou.ravel(), vv[:, :, None] + ov.ravel()], axis=-1).reshape(-1, 2)
    return np.ascontiguousarray(camera.undistort_points(px, P=np.eye(3)).reshape(h, w, s * s, 2))


def _wave(t: np.ndarray, period: float, on_us: float, rise_us: float) -> np.ndarray:
    """The LED's emission in [0, 1] at times ``t`` µs: on for ``on_us`` from
    each period's start, linear edges of ``rise_us``."""
    ph = np.mod(t, period)
    up = np.clip(ph / rise_us, 0, 1)
    down = np.clip((ph - on_us) / rise_us, 0, 1)
    return up - down


def simulate_board(camera: Camera, board: Board, R: np.ndarray, t: np.ndarray, *, blink_hz: float = 250.0,
                   duty: float = 0.5, rise_us: float = 20.0, still_us: int = 150_000, move_us: int = 60_000,
                   move_step_us: float = 5000.0, c: float = 0.25, sigma_c: float = 0.03, noise_hz: float = 0.0,
                   flicker_hz: float = 0.0, flicker_depth: float = 0.3, flicker_width: float = 0.25,
                   flicker_samples: int = 16, jitter_us: float = 0.0, dark: float = 0.03, board_level: float = 0.1,
                   led: float = 0.25,
                   supersample: int = 4, seed: int = 0) -> tuple[EventPacket, BoardTruth]:
    """Events of a still ``camera`` watching ``board`` blink at each pose
    ``R[k], t[k]`` (camera from board, m) for ``still_us`` µs, moving
    between poses in ``move_us`` µs (while it moves the dots keep blinking;
    the rendering is updated every ``move_step_us``). Returns the events
    (``t`` µs from 0) and the :class:`BoardTruth`.

    ``c`` the contrast threshold (log units) with per-pixel spread
    ``sigma_c``; ``noise_hz`` shot-noise events per pixel per second;
    ``flicker_hz`` mains flicker (50/100 Hz) of depth ``flicker_depth``
    (light times ``1 + depth sin 2πft``) on the background of the right
    ``flicker_width`` of the image (a lamp behind the board); ``jitter_us``
    the standard deviation of Gaussian timestamp jitter; intensities ``dark``,
    ``board_level``, ``led`` linear, full scale 1."""
    R, t = np.asarray(R, np.float64).reshape(-1, 3, 3), np.asarray(t, np.float64).reshape(-1, 3)
    if len(R) == 0 or len(R) != len(t):
        raise ValueError(f"simulate_board: need as many rotations as translations (>= 1), got {len(R)}, {len(t)}")
    if not (blink_hz > 0 and 0 < duty < 1 and rise_us > 0 and still_us > 0 and move_us >= 0):
        raise ValueError("simulate_board: blink_hz, rise_us, still_us must be > 0, duty in (0, 1), move_us >= 0")
    w, h = camera._size()
    rays = _sample_rays(camera, supersample)
    box = np.array(board.extent())
    period = 1e6 / blink_hz
    on_us = duty * period
    n = len(R)
    T = n * still_us + (n - 1) * move_us
    # sample times: every corner of the blink waveform, flicker samples, rendering updates, view edges
    k = np.arange(0, math.ceil(T / period) + 1) * period
    times = [k, k + rise_us, k + on_us, k + on_us + rise_us]
    if flicker_hz > 0:
        times.append(np.arange(0, T, 1e6 / (flicker_hz * flicker_samples)))
    starts = np.arange(n) * (still_us + move_us)
    for s in starts[:-1]:
        times.append(np.arange(s + still_us, s + still_us + move_us + move_step_us, move_step_us))
    ts = np.unique(np.clip(np.concatenate(times), 0, T))
    emit = _wave(ts, period, on_us, rise_us)
    ambient = 1.0 + flicker_depth * np.sin(2 * np.pi * flicker_hz * ts * 1e-6) if flicker_hz > 0 else np.ones(len(ts))
    lamp = (np.arange(w * h) % w >= (1.0 - flicker_width) * w).astype(np.float64)
    quats = rot_to_quat(R)
    cov_b, cov_d = np.empty((h, w)), np.empty((h, w))
    rng = np.random.default_rng(seed)
    c_on = np.maximum(c + sigma_c * rng.standard_normal(w * h), 0.01)
    c_off = np.maximum(c + sigma_c * rng.standard_normal(w * h), 0.01)
    L0 = np.empty(w * h)
    cached: dict[tuple[float, float], np.ndarray] = {}  # log levels of the pose, LED off / on, without flicker
    pose_key = None
    out_t, out_i, out_p = np.empty(1 << 16), np.empty(1 << 16, np.int64), np.empty(1 << 16, np.int8)
    parts_t, parts_i, parts_p = [], [], []
    l_ref = np.empty(0)
    t_release = np.zeros(w * h)
    for j, tj in enumerate(ts):
        v, ph = divmod(float(tj), still_us + move_us)
        v = int(min(v, n - 1))
        f = 0.0 if ph <= still_us or v == n - 1 else min((ph - still_us) / max(move_us, 1), 1.0)
        f = round(f * move_us / move_step_us) * move_step_us / max(move_us, 1) if f else 0.0
        key = (v, f)
        if key != pose_key:
            pose_key = key
            if f == 0.0:
                Rj, tvec = R[v], t[v]
            else:
                Rj = quat_to_rot(quat_slerp(quats[v], quats[v + 1], min(f, 1.0)))
                tvec = (1 - f) * t[v] + f * t[v + 1]
            coverage_kernel(rays, np.ascontiguousarray(Rj), np.ascontiguousarray(tvec), board.cols, board.rows,
                            board.spacing, board.radius, board.kind, box, cov_b, cov_d)
            fb, fd = cov_b.ravel(), cov_d.ravel()
            cached.clear()
        lk = (float(ambient[j]), float(emit[j]))
        L1 = cached.get(lk) if lk[1] in (0.0, 1.0) else None
        if L1 is None:
            L1 = np.empty(w * h)
            levels_kernel(fb, fd, lamp, dark, board_level, led, lk[0], lk[1], 1e-3, L1)
            if lk[1] in (0.0, 1.0) and flicker_hz <= 0:
                cached[lk] = L1
        if j == 0:
            l_ref = L1.copy()
        else:
            start = 0
            while start < w * h:
                m, start = dvs_step(L0, L1, float(ts[j - 1]), float(tj), l_ref, t_release, c_on, c_off, 0.0,
                                    start, out_t, out_i, out_p)
                parts_t.append(out_t[:m].copy())
                parts_i.append(out_i[:m].copy())
                parts_p.append(out_p[:m].copy())
                if start < w * h and m == 0:
                    out_t, out_i = np.empty(2 * len(out_t)), np.empty(2 * len(out_i), np.int64)
                    out_p = np.empty(2 * len(out_p), np.int8)
        L0 = L1
    et = np.concatenate(parts_t) if parts_t else np.empty(0)
    ei = np.concatenate(parts_i) if parts_i else np.empty(0, np.int64)
    ep = np.concatenate(parts_p) if parts_p else np.empty(0, np.int8)
    if jitter_us > 0:
        et = et + jitter_us * rng.standard_normal(len(et))
    if noise_hz > 0:
        nn = rng.poisson(noise_hz * T * 1e-6 * w * h)
        et = np.concatenate([et, rng.uniform(0, T, nn)])
        ei = np.concatenate([ei, rng.integers(0, w * h, nn)])
        ep = np.concatenate([ep, np.where(rng.random(nn) < 0.5, 1, -1).astype(np.int8)])
    ti = np.clip(np.rint(et), 0, T - 1).astype(np.int64)
    order = np.argsort(ti, kind="stable")
    ti, ei, ep = ti[order], ei[order], ep[order]
    events = EventPacket.from_arrays(ti, ei % w, ei // w, ep, sensor=(w, h), t_start=0, t_end=int(T))
    obj = board.object_points()
    pixels = np.stack([camera.project(obj @ Rk.T + tk) for Rk, tk in zip(R, t, strict=True)])
    spans = np.column_stack([starts, starts + still_us]).astype(np.int64)
    return events, BoardTruth(camera, board, R, t, spans, pixels, blink_hz)
