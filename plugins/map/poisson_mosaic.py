"""``map.poisson_mosaic``: a panoramic log-intensity mosaic from events and
the camera's orientation (the mapping half of Kim, Handa, Benosman, Ieng,
Davison, "Simultaneous mosaicing and tracking with an event camera", BMVC
2014, with the orientation given).

Under pure rotation every event is a ray of a sphere at infinity. With the
orientation ``R(t)`` (world-from-camera, slerped between pose samples at the
event's time; world = the camera frame at the first pose), each event's
undistorted ray is rotated into the world and placed on an equirectangular
panorama (convention in :mod:`._panorama`: ``pano_width`` W px by W/2,
azimuth ``atan2(X, Z)`` over -π..π onto columns, elevation ``asin(Y/|d|)``
(y down) over -π/2..π/2 onto rows).

Gradient estimator. Kim et al. run a per-pixel EKF on the 2-D log-intensity
gradient ``g`` with the measurement ``1/Δt ≈ g·v / C`` (``v`` the pixel's
image velocity, ``Δt`` the time since the sensor pixel's previous event).
Here the same measurement is written without the velocity: between two
events of one sensor pixel, the log intensity it sees changed by one
contrast step while its ray moved by ``Δm`` on the panorama, so
``g · Δm = ±C``. This is exact for any motion between the events (no
constant-velocity assumption), linear in ``g`` (so the Kalman filter is
exact, not extended), and its noise is the threshold's own (``sigma_c``),
independent of speed. With a static scene (no process noise) the filter's
estimate after any number of updates equals the information form
``(Σ Δm Δmᵀ + λI)⁻¹ Σ Δm z`` with ``λ = (sigma_c / sigma_g)²``: the kernel
accumulates those sums per panorama pixel (5 additions per event, in any
order, so packet splits cannot change the result) and each emission solves
the 2x2 systems. Measurements whose displacement exceeds ``max_disp_px``
(the previous event at that pixel was another edge) are dropped and counted.

Integration: the per-pixel gradients, averaged onto the forward-difference
grid, are integrated by a Poisson solve (DCT along elevation, DFT along the
wrapping azimuth; :mod:`._poisson`); pixels with no measurement contribute a
zero gradient and are NaN in the output.

Output: every ``emit_us`` of event time (boundaries ``t0 + k·emit_us``, t0
the stream's start; the mosaic of the events before each boundary) and at
end of stream, a :class:`~tectum.MapPacket` with ``image`` (H, W) float32
log intensity (mean zero over the observed pixels; only differences are
known), ``confidence`` (measurements per pixel) and ``pose`` the identity
(the world frame); no ``K`` (not a pinhole view).

Bad input: the ``poses`` port must be connected (checked before running).
Events before the first pose or after the last one are not mapped but
counted (``before_poses``, ``after_poses``); pose times that do not
increase strictly and non-finite or non-unit quaternions raise ValueError
naming the sample.

Cost: per event one slerp, one 3x3 product, an atan2 and an asin and five
additions (numba); per emission a 2x2 solve per panorama pixel and the
Poisson solve (``tectum bench map`` states both). Memory: 6 float64 per
panorama pixel (25 MB at W = 1024) and 3 numbers per sensor pixel.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from tectum import EventPacket, Kind, MapPacket, Operator, Packet, Port, PosePacket, concat
from tectum.camera import QUAT_TOL, Camera, camera_from, quat_conj, quat_mul, rot_to_quat, so3_exp

from ._panorama import map_events, pano_shape, solve_gradients
from ._poisson import poisson_solve

__all__ = ["PoissonMosaic", "mosaic_image", "rotating_camera_stream"]

_IDENTITY = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


def mosaic_image(info: np.ndarray, ridge: float, min_measurements: int = 1) -> np.ndarray:
    """The log-intensity mosaic (H, W) float32 of accumulated measurements
    ``info`` (H, W, 6) (see :func:`._panorama.map_events`): per-pixel
    gradients, averaged onto forward differences where both neighbours
    were measured, integrated with a wrapping azimuth; NaN where fewer than
    ``min_measurements`` landed; mean zero over the rest."""
    gu, gv = solve_gradients(info, ridge, min_measurements)
    seen = info[..., 5] >= min_measurements
    gx = _pair_mean(gu, np.roll(gu, -1, axis=1), seen, np.roll(seen, -1, axis=1))
    gy = np.zeros_like(gv)
    gy[:-1] = _pair_mean(gv[:-1], gv[1:], seen[:-1], seen[1:])
    L = poisson_solve(gx, gy, wrap_x=True)
    out = np.full(L.shape, np.nan, np.float32)
    if seen.any():
        out[seen] = (L[seen] - L[seen].mean()).astype(np.float32)
    return out


def _pair_mean(a: np.ndarray, b: np.ndarray, sa: np.ndarray, sb: np.ndarray) -> np.ndarray:
    """The gradient between two pixels: their mean where both are known, else the known one."""
    return np.where(sa & sb, 0.5 * (a + b), np.where(sa, a, 0.0) + np.where(sb, b, 0.0))


class PoissonMosaic(Operator):
    """Panoramic log-intensity mosaic from events and orientations (Kim et al. BMVC 2014; see the module).

    Parameters
    ----------
    calib:
        Calibration file or inline ``fx;fy;cx;cy[;k1;k2;p1;p2;k3]`` (px);
        defaults to the calibration beside the source recording.
    pano_width:
        Panorama width in px (even); the height is half of it.
    emit_us:
        Emit the mosaic every ``emit_us`` µs of event time (and at the end).
    contrast:
        Contrast threshold C (log intensity) of ON events.
    contrast_off:
        Of OFF events; 0 means the same as ``contrast``.
    sigma_c:
        Noise of one contrast measurement, std in log units.
    sigma_g:
        Prior std of the gradient, log units per panorama px.
    max_disp_px:
        Longest panorama displacement (px) between a sensor pixel's two
        events that still counts as one contrast step.
    min_measurements:
        Measurements a panorama pixel needs to be shown (else NaN).
    """

    name = "map.poisson_mosaic"
    inputs = {
        "events": Port(Kind.EVENTS, doc="the events to map"),
        "poses": Port(Kind.POSES, doc="world-from-camera orientations (ground truth, IMU integration, a tracker)"),
    }
    produces = (Kind.MAPS,)

    def __init__(self, calib: str = "", pano_width: int = 1024, emit_us: int = 1_000_000, contrast: float = 0.2,
                 contrast_off: float = 0.0, sigma_c: float = 0.05, sigma_g: float = 1.0, max_disp_px: float = 3.0,
                 min_measurements: int = 1) -> None:
        self.H, self.W = pano_shape(int(pano_width))
        if emit_us < 1:
            raise ValueError(f"emit_us must be >= 1 µs, got {emit_us}")
        c_off = contrast_off or contrast
        if not (contrast > 0 and c_off > 0 and sigma_c > 0 and sigma_g > 0 and max_disp_px > 0):
            raise ValueError("contrast, contrast_off, sigma_c, sigma_g and max_disp_px must be > 0")
        if min_measurements < 1:
            raise ValueError(f"min_measurements must be >= 1, got {min_measurements}")
        self.camera: Camera = camera_from(calib)
        self.emit_us = int(emit_us)
        self.contrast = np.array([contrast, c_off], np.float64)
        self.ridge = (sigma_c / sigma_g) ** 2
        self.max_disp, self.min_meas = float(max_disp_px), int(min_measurements)
        self.counts = {"mapped": 0, "measurements": 0, "too_far": 0, "before_poses": 0, "after_poses": 0}
        self.info = np.zeros((self.H, self.W, 6))
        self._rays: np.ndarray | None = None
        self._pix_t = np.empty((0, 0), np.int64)
        self._pix_uv = np.empty((0, 0, 2))
        self._q0_inv: np.ndarray | None = None  # first-camera-from-world
        self._pose_t = np.empty(0, np.int64)
        self._pose_q = np.empty((0, 4))
        self._pending: list[EventPacket] = []  # events waiting for a pose at or after them
        self._next: int | None = None          # next emission boundary, µs
        self._mark: int | None = None          # the events' watermark, µs
        self._poses_seen = False
        self._changed = False                  # events mapped since the last emission

    #: For the conformance check: inline intrinsics of a 32x24 sensor, a small panorama.
    conformance_params = {"calib": "30;30;15.5;11.5", "pano_width": 64, "emit_us": 10_000}

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """Events and poses of a camera turning inside a grating (see :func:`rotating_camera_stream`)."""
        return rotating_camera_stream(duration_us=30_000, sensor=(32, 24), f=30.0)

    def warmup(self) -> None:
        t = np.arange(2, dtype=np.int64)
        z = np.zeros(2, np.uint16)
        q = np.tile([0.0, 0.0, 0.0, 1.0], (2, 1))
        map_events(t, z, z, np.ones(2, np.int8), t, q, np.ones((1, 1, 3)), self.contrast, 1.0,
                   np.full((1, 1), -1, np.int64), np.zeros((1, 1, 2)), np.zeros((2, 4, 6)))

    # -- input ------------------------------------------------------------------
    def process_ports(self, ports: Mapping[str, Packet]) -> list[MapPacket]:
        if self._next is None:
            self._next = next(iter(ports.values())).t_start + self.emit_us
        poses = ports.get("poses")
        if poses is not None:
            self._poses_seen = True
            assert isinstance(poses, PosePacket)
            self._add_poses(poses)
        ev = ports.get("events")
        if ev is not None:
            assert isinstance(ev, EventPacket)
            self._mark = ev.t_end
            if len(ev):
                self._pending.append(ev)
        ended = poses is None and self._poses_seen  # the pose stream has ended: no later pose will come
        return self._advance(final=ended)

    def finish(self) -> list[MapPacket]:
        out = self._advance(final=True)
        if self._changed and self._mark is not None and self._next is not None:
            out.append(self._packet(self._mark - 1, self._next - self.emit_us, self._mark))
        return out

    def _add_poses(self, poses: PosePacket) -> None:
        t = poses.t
        q = np.asarray(poses.orientation, np.float64)
        if not len(t):
            return
        bad = ~np.isfinite(q).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"poses: orientation at t={int(t[i])} µs (sample {i} of its packet) is not finite: "
                             f"{q[i].tolist()}")
        norm_err = np.abs(np.linalg.norm(q, axis=1) - 1.0)
        if norm_err.max() > QUAT_TOL:
            i = int(np.argmax(norm_err))
            raise ValueError(f"poses: orientation at t={int(t[i])} µs has norm {np.linalg.norm(q[i]):.6g}, not a "
                             f"unit quaternion (tolerance {QUAT_TOL})")
        prev = self._pose_t[-1:] if self._pose_t.size else t[:0]
        allt = np.concatenate([prev, t])
        step = np.diff(allt)
        if (step <= 0).any():
            k = int(np.argmax(step <= 0))
            raise ValueError(f"poses: times must increase strictly; a pose at t={int(allt[k + 1])} µs follows "
                             f"one at t={int(allt[k])} µs")
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        if self._q0_inv is None:
            self._q0_inv = np.asarray(quat_conj(q[0]))
        q = np.asarray(quat_mul(self._q0_inv, q)).reshape(-1, 4)
        self._pose_t = np.concatenate([self._pose_t, t])
        self._pose_q = np.concatenate([self._pose_q, q])

    # -- mapping and emission -------------------------------------------------------
    def _advance(self, final: bool) -> list[MapPacket]:
        """Map the pending events the poses cover, emitting at each boundary
        passed; with ``final`` the events no pose will cover are dropped."""
        out: list[MapPacket] = []
        ev = self._take()
        pt = self._pose_t
        if ev is not None:
            if pt.size:
                before, ev = ev.split_at(int(pt[0]))
                self.counts["before_poses"] += len(before)
                now, later = ev.split_at(int(pt[-1]) + 1)
            else:
                now, later = ev.split_at(ev.t_start)[0], ev
            if final:
                key = "after_poses" if pt.size else "before_poses"
                self.counts[key] += len(later)
            elif len(later):
                self._pending = [later]
            out += self._map_until_boundaries(now)
        # boundaries passed by every event, none still waiting
        done = self._mark if not self._pending else int(self._pending[0].t[0])
        while self._next is not None and done is not None and self._next <= done:
            if self.counts["mapped"]:
                out.append(self._packet(self._next - 1, self._next - self.emit_us, self._next))
            self._next += self.emit_us
        return out

    def _take(self) -> EventPacket | None:
        if not self._pending:
            return None
        whole = concat(self._pending)
        assert isinstance(whole, EventPacket)
        self._pending = []
        return whole if len(whole) else None

    def _map_until_boundaries(self, ev: EventPacket) -> list[MapPacket]:
        out: list[MapPacket] = []
        assert self._next is not None
        while len(ev):
            if int(ev.t[-1]) < self._next:
                self._map(ev)
                break
            now, ev = ev.split_at(self._next)
            self._map(now)
            if self.counts["mapped"]:
                out.append(self._packet(self._next - 1, self._next - self.emit_us, self._next))
            self._next += self.emit_us
        return out

    def _map(self, ev: EventPacket) -> None:
        if not len(ev):
            return
        self._ensure_sensor(ev.sensor)
        assert self._rays is not None
        n_meas, n_far = map_events(ev.t, ev.x, ev.y, ev.p, self._pose_t, self._pose_q, self._rays, self.contrast,
                                   self.max_disp, self._pix_t, self._pix_uv, self.info)
        self.counts["mapped"] += len(ev)
        self.counts["measurements"] += int(n_meas)
        self.counts["too_far"] += int(n_far)
        self._changed = True
        self._drop_poses(int(ev.t[-1]))

    def _ensure_sensor(self, sensor: tuple[int, int]) -> None:
        if self._rays is not None and self._pix_t.shape == (sensor[1], sensor[0]):
            return
        if self._rays is not None:
            raise ValueError(f"map.poisson_mosaic: the sensor changed from {self._pix_t.shape[::-1]} to {sensor}")
        w, h = sensor
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        rays = self.camera.bearings(np.stack([u.ravel(), v.ravel()], axis=1)).reshape(h, w, 3)
        if not np.isfinite(rays).all():
            raise ValueError("map.poisson_mosaic: the calibration's lens model has no inverse at some sensor pixels")
        self._rays = np.ascontiguousarray(rays)
        self._pix_t = np.full((h, w), -1, np.int64)
        self._pix_uv = np.zeros((h, w, 2))

    def _drop_poses(self, t: int) -> None:
        """Forget poses no later event needs (keep the last at or before ``t``)."""
        k = int(np.searchsorted(self._pose_t, t, side="right")) - 1
        if k > 0:
            self._pose_t, self._pose_q = self._pose_t[k:], self._pose_q[k:]

    def _packet(self, t: int, t_start: int, t_end: int) -> MapPacket:
        img = mosaic_image(self.info, self.ridge, self.min_meas)
        self._changed = False
        conf = self.info[..., 5].astype(np.float32)
        return MapPacket(np.array([t], np.int64), image=img[None], confidence=conf[None], pose=_IDENTITY[None],
                         t_start=t_start, t_end=t_end)


def rotating_camera_stream(duration_us: int, sensor: tuple[int, int], f: float,
                           omega: tuple[float, float, float] = (0.3, 4.0, 0.5),
                           log_intensity: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                           contrast: float = 0.2, pose_rate_hz: float = 1000.0, step_us: int = 20,
                           circle_rad: float = 0.0, circle_hz: float = 10.0) -> dict[str, Packet]:
    """Events and poses of a pinhole camera (focal ``f`` px, centred)
    turning at ``omega`` (rad/s; world = the camera at t = 0), its
    orientation ``exp(ω t + a (sin 2πft, 1 - cos 2πft, 0))`` with ``a`` =
    ``circle_rad`` and ``f`` = ``circle_hz`` (the optical axis circles, so
    every gradient direction is seen), inside a sphere whose log intensity is ``log_intensity(azimuth,
    elevation)`` (rad, the panorama's convention; default a grating
    ``sin(15 az) cos(15 el)``): each pixel samples it every ``step_us`` µs
    and fires ±1 per ``contrast`` crossed (an ideal DVS); poses at
    ``pose_rate_hz``."""
    w, h = sensor
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(u.ravel() - cx) / f, (v.ravel() - cy) / f, np.ones(w * h)], axis=1)
    pattern = log_intensity or (lambda az, el: np.sin(15.0 * az) * np.cos(15.0 * el))

    def rotvec(t_s: np.ndarray) -> np.ndarray:
        ph = 2 * np.pi * circle_hz * t_s
        return (np.outer(t_s, omega) + circle_rad * np.stack([np.sin(ph), 1 - np.cos(ph), 0 * ph], axis=-1))

    def log_i(t_us: float) -> np.ndarray:
        d = rays @ np.asarray(so3_exp(rotvec(np.array([t_us * 1e-6]))[0])).T
        return pattern(np.arctan2(d[:, 0], d[:, 2]), np.arcsin(d[:, 1] / np.linalg.norm(d, axis=1)))

    ref = log_i(0.0)
    ts, idx, ps = [], [], []
    for t in range(step_us, duration_us, step_us):
        n = np.trunc((log_i(float(t)) - ref) / contrast).astype(np.int64)
        fired = np.flatnonzero(n)
        reps = np.abs(n[fired])
        ts.append(np.full(int(reps.sum()), t, np.int64))
        idx.append(np.repeat(fired, reps))
        ps.append(np.repeat(np.sign(n[fired]), reps))
        ref += n * contrast
    i = np.concatenate(idx) if idx else np.empty(0, np.int64)
    t_ev = np.concatenate(ts) if ts else np.empty(0, np.int64)
    p_ev = np.concatenate(ps) if ps else np.empty(0, np.int64)
    ev = EventPacket.from_arrays(t_ev, i % w, i // w, p_ev, sensor=sensor, t_start=0, t_end=duration_us)
    tp = np.arange(0, duration_us + 1, int(1e6 / pose_rate_hz), dtype=np.int64)
    q = np.asarray(rot_to_quat(so3_exp(rotvec(tp * 1e-6))))
    poses = PosePacket(tp, position=np.zeros((len(tp), 3)), orientation=q, t_start=0, t_end=duration_us + 1)
    return {"events": ev, "poses": poses}
