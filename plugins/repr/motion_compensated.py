"""``repr.motion_compensated``: event images sharpened by the camera's
measured rotation (events + IMU gyro, or events + poses).

Under a rotation the events of one edge smear along the image motion over a
window. Knowing the rotation ``R(t)`` of the camera during the window, each
event's ray is rotated into the camera at the window's end and projected
there, so the events of one edge pile up on one line again: a sharp image
of where the scene is *now* (the latest instant a control loop cares
about). Translation is not compensated (it needs depth): the image is exact
for pure rotation or a distant scene.

Rotation sources (besides ``events``, the port ``imu`` or ``poses``; with
both connected, as from an ECD folder holding ``imu.txt`` and
``groundtruth.txt``, the gyro is used and the poses are ignored):

* ``imu``: the gyro ω (rad/s), rotated into the camera frame by
  ``imu_rotation`` (camera-from-IMU, a rotation vector in rad or a 3x3
  matrix row by row; identity when empty) and shifted by
  ``imu_time_offset_us`` (camera time = IMU time + offset). Between samples
  ω is held (zero-order hold), so an event needs only the samples at or
  before its time; events before the first sample are dropped (counted).
* ``poses``: world-from-camera orientations, slerped between samples; an
  event needs a pose at or after its time, so a window is emitted once a
  pose at or past its end has arrived (or at end of stream); events outside
  the poses' span are dropped (counted).

Output: per window ``[t0 + kW, t0 + (k+1)W)`` (``t0`` the first input's
start, as the other ``repr`` operators), a :class:`~tectum.FramePacket`
stamped ``end - 1`` µs with a float32 (H, W) image in the undistorted
pinhole camera with the calibration's ``K``: per pixel, the number of
events (``mode="count"``) or their polarity sum (``"polarity"``), each
event voted bilinearly at its sub-pixel position.

Cost: one 3x3 product and a bilinear vote per event (numba), plus a
rotation per gyro sample; memory: the events and samples of the windows not
yet emitted, plus one (H, W, 3) table of pixel rays.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal

import numpy as np
from numba import njit

from tectum import EventPacket, FramePacket, Kind, Operator, Packet, Port, concat
from tectum.camera import camera_from, gyro_rotations, quat_to_rot, rotation_matrix, so3_exp

__all__ = ["MotionCompensated", "warp_vote"]


@njit(cache=True, nogil=True)
def warp_vote(x, y, p, R, rays, fx, fy, cx, cy, signed, img):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Rotate each event's ray ``rays[y, x]`` by ``R[i]`` and vote it
    bilinearly into ``img`` (H, W) at its pinhole projection; returns the
    number of events that landed inside the image."""
    h, w = img.shape
    inside = 0
    for i in range(x.shape[0]):
        r = rays[y[i], x[i]]
        Ri = R[i]
        X = Ri[0, 0] * r[0] + Ri[0, 1] * r[1] + Ri[0, 2] * r[2]
        Y = Ri[1, 0] * r[0] + Ri[1, 1] * r[1] + Ri[1, 2] * r[2]
        Z = Ri[2, 0] * r[0] + Ri[2, 1] * r[1] + Ri[2, 2] * r[2]
        if not Z > 1e-9:
            continue
        u = fx * X / Z + cx
        v = fy * Y / Z + cy
        u0 = np.floor(u)
        v0 = np.floor(v)
        if u0 < -1 or v0 < -1 or u0 > w - 1 or v0 > h - 1:
            continue
        du, dv = u - u0, v - v0
        val = p[i] if signed else 1.0
        iu, iv = int(u0), int(v0)
        landed = False
        for dy, wy in ((0, 1.0 - dv), (1, dv)):
            for dx, wx in ((0, 1.0 - du), (1, du)):
                jj, ii = iv + dy, iu + dx
                if 0 <= jj < h and 0 <= ii < w:
                    img[jj, ii] += val * wy * wx
                    landed = True
        if landed:
            inside += 1
    return inside


class MotionCompensated(Operator):
    """Event images warped by the camera rotation measured by an IMU or
    given as poses, sharper than plain event frames (see the module).

    Parameters
    ----------
    calib:
        Calibration file (OpenCV YAML/JSON, ROS camera_info, UZH calib.txt)
        or inline ``fx;fy;cx;cy[;k1;k2;p1;p2;k3]`` (px); defaults to the
        calibration beside the source recording.
    window_us:
        Window length in µs.
    mode:
        ``count`` (events per pixel) or ``polarity`` (their polarity sum).
    imu_rotation:
        Camera-from-IMU rotation: a rotation vector (3 numbers, rad) or a
        matrix (9, row by row); identity when empty.
    imu_time_offset_us:
        Camera time minus IMU time, µs.
    partial:
        Emit the unfinished last window at end of stream.
    """

    name = "repr.motion_compensated"
    inputs = {
        "events": Port(Kind.EVENTS, doc="the events to warp"),
        "imu": Port(Kind.IMU, required=False, doc="gyro (rad/s) giving the rotation"),
        "poses": Port(Kind.POSES, required=False, doc="world-from-camera orientations giving the rotation"),
    }
    produces = (Kind.FRAMES,)

    def __init__(self, calib: str = "", window_us: int = 10_000, mode: Literal["count", "polarity"] = "count",
                 imu_rotation: tuple[float, ...] = (), imu_time_offset_us: int = 0, partial: bool = True) -> None:
        if window_us < 1:
            raise ValueError("window_us must be >= 1")
        self.camera = camera_from(calib)
        self.window_us, self.signed, self.partial = int(window_us), mode == "polarity", bool(partial)
        self.R_ci = rotation_matrix(tuple(imu_rotation), "imu_rotation")
        self.imu_offset = int(imu_time_offset_us)
        self.counts = {"no_motion_data": 0, "outside_image": 0}
        self._rays: np.ndarray | None = None
        self._sensor: tuple[int, int] | None = None
        self._end: int | None = None          # end of the current window, µs
        self._events: list[EventPacket] = []  # events not yet in an emitted window
        self._knot_t = np.empty(0, np.int64)  # gyro (camera time, µs) or pose times
        self._knot_v = np.empty((0, 3))       # gyro ω in the camera frame (rad/s) or ...
        self._knot_q = np.empty((0, 4))       # ... pose orientations (x, y, z, w)
        self._use_imu: bool | None = None
        self._mark = 0                        # the events' watermark, µs

    #: For the conformance check: inline intrinsics of a 48x36 sensor.
    conformance_params = {"calib": "40;40;24;18", "window_us": 4000}

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """Events of a few points seen by a camera turning at a steady
        rate, with its gyro at 1 kHz (for the conformance check)."""
        return _rotating_points(duration_us=40_000, sensor=(48, 36), f=40.0)

    def warmup(self) -> None:
        t = np.arange(4, dtype=np.int64)
        R = gyro_rotations(t, np.zeros(1, np.int64), np.zeros((1, 3)), 3)
        z = np.zeros(4, np.uint16)
        warp_vote(z, z, np.ones(4, np.int8), R, np.ones((2, 2, 3)), 1.0, 1.0, 0.0, 0.0, True, np.zeros((2, 2)))

    @classmethod
    def check_ports(cls, connected: frozenset[str]) -> str | None:
        if "imu" not in connected and "poses" not in connected:
            return "connect the port 'imu' (gyro) or 'poses' (orientations) besides 'events'"
        return None

    # -- input ------------------------------------------------------------------
    def process_ports(self, ports: Mapping[str, Packet]) -> list[FramePacket]:
        ev = ports.get("events")
        first = next(iter(ports.values()))
        if self._end is None:
            self._end = first.t_start + self.window_us
        if ev is not None:
            self._mark = ev.t_end  # windows follow the events: none past their stream's end
            if len(ev):
                self._events.append(ev)  # type: ignore[arg-type]
        imu, poses = ports.get("imu"), ports.get("poses")
        if imu is not None or self._use_imu:
            poses = None  # the gyro wins: measured at the camera, no interpolation between samples
        if imu is not None:
            self._use_imu = True
            if len(imu):
                w = np.asarray(imu.gyro, np.float64) @ self.R_ci.T  # type: ignore[attr-defined]
                self._knot_t = np.concatenate([self._knot_t, imu.t + self.imu_offset])
                self._knot_v = np.concatenate([self._knot_v, w])
        if poses is not None:
            self._use_imu = False
            if len(poses):
                self._knot_t = np.concatenate([self._knot_t, poses.t])
                self._knot_q = np.concatenate([self._knot_q, poses.orientation])  # type: ignore[attr-defined]
        return self._emit(final=False)

    def finish(self) -> list[FramePacket]:
        return self._emit(final=True)

    # -- windows ------------------------------------------------------------------
    def _ready(self, end: int) -> bool:
        if end > self._mark:
            return False
        if self._use_imu is False:  # poses: one at or past the window's last µs
            return bool(self._knot_t.size) and int(self._knot_t[-1]) >= end - 1
        return True

    def _emit(self, final: bool) -> list[FramePacket]:
        out: list[FramePacket] = []
        while self._end is not None and (self._ready(self._end) or (final and self._events)):
            end = self._end
            if final and not self._ready(end) and not self.partial:
                break
            start = end - self.window_us
            evs = self._take(end)
            if evs is not None or not final:
                out.append(self._frame(start, end, evs))
            self._end = end + self.window_us
        return out

    def _take(self, end: int) -> EventPacket | None:
        if not self._events:
            return None
        whole = concat(self._events)
        assert isinstance(whole, EventPacket)
        now, later = whole.split_at(end)
        self._events = [later] if len(later) else []
        return now if len(now) else None

    def _frame(self, start: int, end: int, ev: EventPacket | None) -> FramePacket:
        sensor = ev.sensor if ev is not None else self._sensor
        if sensor is None:
            sensor = (int(self.camera.width or 1), int(self.camera.height or 1))
        if self._rays is None or self._sensor != sensor:
            self._sensor = sensor
            w, h = sensor
            u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
            rays = self.camera.bearings(np.stack([u.ravel(), v.ravel()], axis=1))
            self._rays = np.ascontiguousarray(rays.reshape(h, w, 3))
        img = np.zeros((sensor[1], sensor[0]), np.float32)
        if ev is not None:
            R, ok = self._rotations(ev.t, end - 1)
            self.counts["no_motion_data"] += int((~ok).sum())
            sel = np.flatnonzero(ok)
            acc = np.zeros(img.shape, np.float64)
            landed = warp_vote(ev.x[sel], ev.y[sel], ev.p[sel], R[sel], self._rays, self.camera.fx,
                               self.camera.fy, self.camera.cx, self.camera.cy, self.signed, acc)
            self.counts["outside_image"] += len(sel) - int(landed)
            img = acc.astype(np.float32)
        self._drop_knots(end - 1)
        return FramePacket(np.array([end - 1], np.int64), images=img[None], t_start=start, t_end=end)

    def _rotations(self, t: np.ndarray, t_ref: int) -> tuple[np.ndarray, np.ndarray]:
        """Per event, ``R_ref_from_t`` (N, 3, 3) and whether motion data cover it."""
        kt = self._knot_t
        n = t.shape[0]
        if self._use_imu is not False:
            ok = (t >= kt[0]) if kt.size else np.zeros(n, np.bool_)
            if not kt.size or t_ref < kt[0]:
                return np.zeros((n, 3, 3)), np.zeros(n, np.bool_)
            R = np.zeros((n, 3, 3))
            sel = np.flatnonzero(ok)
            if sel.size:
                R[sel] = gyro_rotations(np.ascontiguousarray(t[sel]), kt, self._knot_v, int(t_ref))
            return R, ok
        from tectum.camera import interpolate_poses

        zeros = np.zeros((kt.size, 3))
        _, q, ok = interpolate_poses(np.append(t, t_ref), kt, zeros, self._knot_q)
        if not ok[-1]:
            return np.zeros((n, 3, 3)), np.zeros(n, np.bool_)
        R_wt = np.zeros((n, 3, 3))
        sel = np.flatnonzero(ok[:-1])
        if sel.size:
            R_wt[sel] = quat_to_rot(q[sel])
        R_wref = np.asarray(quat_to_rot(q[-1]))
        return np.einsum("ji,njk->nik", R_wref, R_wt), ok[:-1]

    def _drop_knots(self, t_ref: int) -> None:
        """Forget samples no later window needs (keep the last at or before ``t_ref``)."""
        kt = self._knot_t
        k = int(np.searchsorted(kt, t_ref, side="right")) - 1
        if k > 0:
            self._knot_t = kt[k:]
            if self._use_imu is False:
                self._knot_q = self._knot_q[k:]
            else:
                self._knot_v = self._knot_v[k:]


def _rotating_points(duration_us: int, sensor: tuple[int, int], f: float, omega: tuple[float, float, float] = (
        0.0, 2.0, 0.5), n_points: int = 12, rate_hz: float = 1000.0, seed: int = 0) -> dict[str, Packet]:
    """Events of ``n_points`` distant points seen by a pinhole camera (focal
    ``f`` px, centred) turning at the constant rate ``omega`` (rad/s, camera
    frame), one event per point every 100 µs, and the gyro at ``rate_hz``."""
    from tectum import ImuPacket

    rng = np.random.default_rng(seed)
    w, h = sensor
    cx, cy = w / 2.0, h / 2.0
    rays0 = np.stack([(rng.uniform(0.2, 0.8, n_points) * w - cx) / f,
                      (rng.uniform(0.2, 0.8, n_points) * h - cy) / f, np.ones(n_points)], axis=1)
    ts = np.arange(0, duration_us, 100, dtype=np.int64)
    t_all, x_all, y_all = [], [], []
    for t in ts:
        R = np.asarray(so3_exp(np.asarray(omega) * t * 1e-6))  # camera at t from camera at 0: p_t = R^T p_0
        r = rays0 @ R  # rows: R^T r0
        u = f * r[:, 0] / r[:, 2] + cx
        v = f * r[:, 1] / r[:, 2] + cy
        ok = (r[:, 2] > 0) & (u >= 0) & (v >= 0) & (u < w - 0.5) & (v < h - 0.5)
        t_all.append(np.full(int(ok.sum()), t))
        x_all.append(np.round(u[ok]))
        y_all.append(np.round(v[ok]))
    t_ev = np.concatenate(t_all)
    ev = EventPacket.from_arrays(t_ev, np.concatenate(x_all), np.concatenate(y_all), np.ones(len(t_ev), np.int8),
                                 sensor=sensor, t_start=0, t_end=duration_us)
    ti = np.arange(0, duration_us, int(1e6 / rate_hz), dtype=np.int64)
    imu = ImuPacket(ti, accel=np.zeros((len(ti), 3)), gyro=np.tile(omega, (len(ti), 1)), t_start=0,
                    t_end=duration_us)
    return {"events": ev, "imu": imu}
