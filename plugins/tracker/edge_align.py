"""``tracker.edge_align``: the camera's 6-DoF pose by aligning an image of
recent events to a semi-dense 3-D map, the tracker of EVO (Rebecq,
Horstschaefer, Gallego, Scaramuzza, "EVO: A Geometric Approach to
Event-Based 6-DOF Parallel Tracking and Mapping in Real Time", RA-L 2017).

Events fire on edges; a semi-dense map (``map.emvs``: depth on the
edges of a reference view) holds the same edges in 3-D. Seen from the
right pose, the map's points land on the edges of the event image. Per
step of ``step_events`` events:

1. the event image of the last ``window_events`` events (undistorted
   positions, one bilinear vote each), blurred by a Gaussian of σ
   ``sigma_px`` px and scaled so its brightest 0.5 % of pixels are 1
   (clipped there);
2. the map's points (3-D, world) are projected with the pose predicted at
   constant velocity (the steps' velocities smoothed by ``velocity_gain``);
3. the pose moves so the points land on bright pixels: Levenberg-Marquardt
   on SE(3) with analytic Jacobians (the image gradient is computed once per
   image, the points are reprojected per iteration) of ``Σ ρ(1 - E(u))``,
   ρ Huber at ``huber``, plus a prior at the prediction (σ ``prior_rad``,
   ``prior_m``, counted like one point), coarse to fine over ``levels`` blurs (σ doubling
   per coarser level: a wider basin first). EVO states its alignment as an
   inverse-compositional image alignment of the event image against the
   map's projection; this is the forward (Gauss-Newton on the points)
   form of the same objective, which needs no depth per template pixel.

The pose fits the window's middle event; the output is stamped at its last
event (µs), moved there by the estimated velocity.

Maps (port ``maps``, :class:`~tectum.MapPacket` rows with ``depth`` m NaN
unknown, ``K`` and ``pose`` world-from-camera) become their back-projected
points in the world (pixels with fewer than ``min_neighbours`` neighbours of
consistent depth within 3 px dropped: EMVS leaves scattered outliers; at
most ``max_points``, thinned evenly); a step uses
the latest map stamped at or before its last event (EVO aligns to the
latest map). A map whose size differs from the events' sensor, or whose
intrinsics differ from the calibration's by more than 1 %, is an error.

Bootstrap: the first map needs poses. With ``bootstrap_us`` > 0 the
given poses (port ``poses``, e.g. a stretch of ground truth or an IMU
integration) from their first one for ``bootstrap_us`` µs are the output,
as they are (the mapper builds the first map from them); after that the
tracker runs alone and ignores that port. With ``plane_depth`` > 0 m and
no bootstrap poses, the first window's event edges are taken as a
fronto-parallel plane at that depth in front of the first camera (the world
frame is that camera's, the scale is set by ``plane_depth``): a planar
scene's bootstrap.

Gyro (port ``imu``, with ``gyro_rad`` > 0; off by default, as a gyro's
axes must be stated): the rotation between steps comes from the
gyro rather than the constant-velocity model, and the alignment holds the
rotation near it with σ ``gyro_rad`` per step instead of ``prior_rad``:
the pose's weak direction, a sideways slide traded for a turn (see
``docs/evo.md``), is then pinned by a sensor that measures the turn. ω
(rad/s) is rotated into the camera frame by ``imu_rotation`` (camera-from-
IMU, a rotation vector in rad or a 3x3 matrix row by row; identity when
empty), shifted by ``imu_time_offset_us`` (camera time = IMU time +
offset), held between samples, less ``gyro_bias`` (rad/s, camera frame);
with ``gyro_bias`` empty and a bootstrap, the bias is the mean gap between
the gyro and the bootstrap poses' turn over the bootstrap (else zero). A
step whose span the samples do not reach (none at or before its start, or
the last more than :data:`GYRO_HOLD_US` before its end) falls back to the
constant-velocity prediction. Non-finite samples are dropped (counted in
``counts["imu_dropped"]``); a run with steps after the bootstrap and not
one sample is an error at its end.

Lost: a step is lost when fewer than ``min_points`` map points are in
view; when its aligned points land on edges (E ≥ 0.5) for less than
``min_overlap`` of them, or for less than ``overlap_drop`` times the
running overlap of the good steps on the same map (how much of a map lands
on edges depends on the scene and the view: a relative test); or when the
pose moved farther from the last good one than ``max_speed`` m/s and
``max_rate`` rad/s allow (plus 2 cm, 0.02 rad). A lost row holds the
prediction, flagged ``lost`` (never a confident guess): the last good pose
moved on at the last velocity for ``coast_us``, then held with zero
velocities; each is counted in ``counts``. While lost, each step tries to
relocalise from that prediction with one coarser level, and resumes when
the overlap is back to ``relocalise_overlap`` times the running overlap
and the jump is plausible. A map without good steps yet has no running
overlap: with ``known_overlap`` (the default) the one the map before it
had stands in (after the bootstrap: its points' overlap at the pose
predicted from the bootstrap's last), when at least ``min_overlap``;
otherwise, and without ``known_overlap``, twice ``min_overlap`` (20 %).
A map filled in by a plane prior (``map.emvs surface=plane``) lands only
15-18 % of its points on edges even where it is right, so the fixed bar
kept the tracker lost for good (``docs/evo.md``).

Output (:class:`~tectum.PosePacket`): ``position`` (m), ``orientation``
(x, y, z, w, world-from-camera), ``linear_velocity`` (m/s, world),
``angular_velocity`` (rad/s, camera frame) and ``lost``.

Cost per step: one vote per window event, then per level a Gaussian blur
and a gradient of the image (H x W) and at most ``max_iter`` passes over the
map's points in view. Memory: the window's events (24 bytes each), the
map's points (24 bytes each), four H x W float64 images.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.ndimage import gaussian_filter

from tectum import EventPacket, ImuPacket, Kind, MapPacket, Operator, Packet, Port, PosePacket
from tectum.camera import (
    Camera,
    camera_from,
    depth_points,
    gyro_turn,
    interpolate_poses,
    quat_to_rot,
    rot_to_quat,
    rotation_matrix,
    se3_exp,
    se3_log,
    so3_exp,
    so3_log,
)

from ._edge_align import align, consistent, gradients, normalise, vote_events

__all__ = ["EdgeAlign"]

#: Fraction of pixels at the top of the event image that saturate at 1.
TOP_FRACTION = 0.005
#: Map points nearer than this to a camera are not used, m.
MIN_DEPTH_M = 0.05
#: The last gyro sample is held this long past its time at most, µs.
GYRO_HOLD_US = 20_000
#: The bootstrap's gyro bias is measured over spans of this length, µs.
BIAS_SPAN_US = 20_000


class EdgeAlign(Operator):
    """6-DoF camera tracking against semi-dense maps by event-image
    alignment (EVO's tracker, see the module).

    Parameters
    ----------
    calib:
        Calibration file (UZH calib.txt, OpenCV YAML/JSON, ROS camera_info)
        or inline ``fx;fy;cx;cy[;k1;k2;p1;p2;k3]`` (px); defaults to the
        calibration beside the source recording. Required.
    bootstrap_us:
        Output the poses of port ``poses`` for this long from the first one,
        µs (0: none).
    plane_depth:
        Without bootstrap poses: the first window's edges as a plane this far
        in front of the first camera, m (0: off).
    window_events:
        Events per event image.
    step_events:
        Events between poses.
    sigma_px:
        Blur of the finest level, px.
    levels:
        Blur levels, coarse (σ doubling) to fine.
    max_iter:
        Levenberg-Marquardt iterations per level.
    huber:
        Huber threshold of the residual ``1 - E`` (in [0, 1]).
    max_points:
        A map with more known pixels is thinned evenly to this many points.
    min_points:
        Fewer map points in view: lost.
    min_overlap:
        Fewer aligned points on an edge (E ≥ 0.5) than this fraction: lost.
    overlap_drop:
        An overlap below this fraction of the running overlap: lost.
    relocalise_overlap:
        Fraction of the running overlap needed to resume after a loss.
    max_speed:
        Fastest plausible camera speed, m/s.
    max_rate:
        Fastest plausible turn, rad/s.
    min_neighbours:
        A map pixel is used when at least this many known pixels within 3 px
        have an inverse depth within ``neighbour_tol`` of its own (0: all).
    neighbour_tol:
        Relative inverse-depth tolerance of that test.
    prior_rad:
        σ of the rotation about the constant-velocity prediction, per step,
        rad (a prior counted like one map point).
    prior_m:
        σ of the position about the prediction, per step, m.
    velocity_gain:
        Each step moves the velocity estimate this fraction of the way to
        the step's own (1: the last step's motion; 0: no velocity).
    binary:
        Event image of pixels with events (1) rather than event counts.
    coast_us:
        While lost, the prediction goes on at the last velocity for this
        long after the last good step, µs; then it holds the last good pose.
    known_overlap:
        While lost on a map without good steps, ask ``relocalise_overlap``
        times the overlap of the map before (or at the bootstrap's end)
        rather than twice ``min_overlap`` (False: the latter, as before).
    gyro_rad:
        σ of the rotation about the gyro's (port ``imu``), per step, rad; 0:
        the gyro is not used.
    gyro_bias:
        The gyro's bias, rad/s (3 numbers, camera frame); empty: measured over
        the bootstrap (zero without one).
    imu_rotation:
        Camera-from-IMU rotation: 3 numbers (rotation vector, rad) or 9 (a
        matrix, row by row); empty: the identity.
    imu_time_offset_us:
        Camera time minus IMU time, µs.
    """

    name = "tracker.edge_align"
    inputs = {
        "events": Port(Kind.EVENTS, doc="the events to track with"),
        "maps": Port(Kind.MAPS, doc="semi-dense depth maps (map.emvs) to align to; the latest is used"),
        "poses": Port(Kind.POSES, required=False,
                      doc="bootstrap poses (world-from-camera), output as they are for bootstrap_us µs"),
        "imu": Port(Kind.IMU, required=False, doc="gyro (rad/s): the rotation between steps (σ gyro_rad)"),
    }
    produces = (Kind.POSES,)
    heavy = True

    def __init__(self, calib: str = "", bootstrap_us: int = 0, plane_depth: float = 0.0, window_events: int = 12000,
                 step_events: int = 3000, sigma_px: float = 1.0, levels: int = 2, max_iter: int = 10,
                 huber: float = 0.5, max_points: int = 6000, min_points: int = 60, min_overlap: float = 0.1,
                 overlap_drop: float = 0.3, relocalise_overlap: float = 0.8, max_speed: float = 10.0,
                 max_rate: float = 20.0, min_neighbours: int = 8, neighbour_tol: float = 0.03,
                 prior_rad: float = 0.01, prior_m: float = 0.01, velocity_gain: float = 0.3,
                 binary: bool = False, coast_us: int = 50_000,
                 known_overlap: bool = True, gyro_rad: float = 0.0, gyro_bias: Sequence[float] = (),
                 imu_rotation: Sequence[float] = (), imu_time_offset_us: int = 0) -> None:
        if bootstrap_us < 0 or not plane_depth >= 0:
            raise ValueError(f"tracker.edge_align: need bootstrap_us >= 0 and plane_depth >= 0 m, got {bootstrap_us}, "
                             f"{plane_depth}")
        if window_events < 10 or not 1 <= step_events <= window_events:
            raise ValueError(f"tracker.edge_align: need window_events >= 10 and 1 <= step_events <= window_events, "
                             f"got {window_events}, {step_events}")
        if not sigma_px > 0 or levels < 1 or max_iter < 1 or not huber > 0:
            raise ValueError("tracker.edge_align: need sigma_px > 0, levels >= 1, max_iter >= 1 and huber > 0")
        if min_points < 6 or max_points < min_points:
            raise ValueError(f"tracker.edge_align: need 6 <= min_points <= max_points, got {min_points}, {max_points}")
        if not (0 <= min_overlap <= 0.5 and 0 <= overlap_drop <= relocalise_overlap <= 1):
            raise ValueError(f"tracker.edge_align: need 0 <= min_overlap <= 0.5 and 0 <= overlap_drop <= "
                             f"relocalise_overlap <= 1, got {min_overlap}, {overlap_drop}, {relocalise_overlap}")
        if not (max_speed > 0 and max_rate > 0):
            raise ValueError(f"tracker.edge_align: need max_speed > 0 and max_rate > 0, got {max_speed}, {max_rate}")
        if not calib:
            raise ValueError("tracker.edge_align needs the camera intrinsics: give calib= (a calibration file or "
                             "inline 'fx;fy;cx;cy[;k1;k2;p1;p2;k3]' px), or put a calib.txt beside the recording")
        self.camera: Camera = camera_from(calib)
        self.cam = np.array([self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy])
        self.bootstrap_us, self.plane_depth = int(bootstrap_us), float(plane_depth)
        self.window_events, self.step_events = int(window_events), int(step_events)
        self.sigma_px, self.levels = float(sigma_px), int(levels)
        self.max_iter, self.huber = int(max_iter), float(huber)
        self.max_points, self.min_points = int(max_points), int(min_points)
        self.min_overlap, self.relocalise_overlap = float(min_overlap), float(relocalise_overlap)
        self.overlap_drop, self.max_speed, self.max_rate = float(overlap_drop), float(max_speed), float(max_rate)
        if not 0 <= min_neighbours <= 48 or not neighbour_tol > 0:
            raise ValueError(f"tracker.edge_align: need 0 <= min_neighbours <= 48 and neighbour_tol > 0, got "
                             f"{min_neighbours}, {neighbour_tol}")
        self.min_neighbours, self.neighbour_tol = int(min_neighbours), float(neighbour_tol)
        if not (prior_rad > 0 and prior_m > 0 and 0 <= velocity_gain <= 1):
            raise ValueError(f"tracker.edge_align: need prior_rad > 0, prior_m > 0 and 0 <= velocity_gain <= 1, got "
                             f"{prior_rad}, {prior_m}, {velocity_gain}")
        self._prior = np.array([prior_rad ** -2] * 3 + [prior_m ** -2] * 3)
        if not gyro_rad >= 0:
            raise ValueError(f"tracker.edge_align: need gyro_rad >= 0 rad (0: no gyro), got {gyro_rad}")
        self.gyro_rad = float(gyro_rad)
        self._gyro_prior = np.array([gyro_rad ** -2 if gyro_rad else 0.0] * 3 + [prior_m ** -2] * 3)
        bias = np.asarray(tuple(gyro_bias), np.float64)
        if bias.size not in (0, 3) or not np.isfinite(bias).all():
            raise ValueError(f"tracker.edge_align: gyro_bias takes 3 finite numbers (rad/s) or none, got "
                             f"{list(gyro_bias)}")
        self._bias_given = bias.size == 3
        self._bias = bias if self._bias_given else np.zeros(3)
        self.R_ci = rotation_matrix(tuple(imu_rotation), "tracker.edge_align: imu_rotation")
        self.imu_offset = int(imu_time_offset_us)
        # gyro samples (camera time µs, ω rad/s camera frame, bias not taken off)
        self._gt = np.empty(0, np.int64)
        self._gw = np.empty((0, 3))
        self.velocity_gain = float(velocity_gain)
        self.binary = bool(binary)
        if coast_us < 0:
            raise ValueError(f"tracker.edge_align: coast_us must be >= 0 µs, got {coast_us}")
        self.coast_us = int(coast_us)
        self.known_overlap = bool(known_overlap)
        self._ref_pending = False
        self._known_overlap: float | None = None
        self.counts = {"steps": 0, "tracked": 0, "bootstrap_poses": 0, "bootstrap_steps": 0, "maps": 0,
                       "lost_no_map": 0, "lost_few_points": 0, "lost_overlap": 0, "lost_jump": 0, "relocalised": 0,
                       "gyro_steps": 0, "imu_dropped": 0}
        #: (cost, points in view, overlap, iterations) of the last alignment (for diagnostics)
        self.last_info = np.zeros(4)
        self._sensor: tuple[int, int] | None = None
        self._table = np.empty((0, 0, 2))
        self._img = np.empty((0, 0))
        self._gx = np.empty((0, 0))
        self._gy = np.empty((0, 0))
        # buffered events: times (µs) and undistorted positions (px)
        self._t = np.empty(0, np.int64)
        self._xu = np.empty(0)
        self._yu = np.empty(0)
        self._next_end = self.window_events  # buffer index one past the next step's last event
        # maps waiting for their time, and the current one: (stamp µs, points (N, 3) world m)
        self._maps: list[tuple[int, np.ndarray]] = []
        self._points: np.ndarray | None = None
        self._shapes: list[tuple[int, tuple[int, ...]]] = []  # map sizes to check once the sensor is known
        # bootstrap poses
        self._boot_end: int | None = None  # µs: the first given pose + bootstrap_us
        self._bt = np.empty(0, np.int64)
        self._bp = np.empty((0, 3))
        self._bq = np.empty((0, 4))
        # the state: camera-from-world at the last good step's middle time, its twist (ω, v) per s
        self._R: np.ndarray | None = None
        self._tr = np.zeros(3)
        self._t_mid = 0
        self._xi = np.zeros(6)
        self._has_velocity = False
        self._lost = False
        self._overlap: float | None = None  # running overlap of the good steps on the current map
        self._mark: int | None = None  # start of the next output packet's interval, µs

    def warmup(self) -> None:
        twin = EdgeAlign(calib="40;40;23.5;17.5", bootstrap_us=5_000, window_events=200, step_events=100, min_points=6,
                         min_neighbours=0)
        twin.process_ports(self.conformance_stream())
        twin.finish()

    #: For the conformance check: a 48x36 sensor, small windows.
    conformance_params = {"calib": "40;40;23.5;17.5", "window_events": 200, "step_events": 100, "min_points": 6,
                          "bootstrap_us": 5_000, "min_neighbours": 0, "gyro_rad": 0.001}

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """Events of points seen by a camera sliding sideways and turning, its
        poses and gyro at 1 kHz and a map of the points at the start (for the
        conformance check)."""
        return _points_scene(duration_us=40_000, sensor=(48, 36), f=40.0, omega=(0.1, 0.3, -0.2))

    # -- input ----------------------------------------------------------------------------
    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        rows: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, bool]] = []
        first = next(iter(ports.values()))
        if self._mark is None:
            self._mark = first.t_start
        maps = ports.get("maps")
        if maps is not None and len(maps):
            self._add_maps(maps)  # type: ignore[arg-type]
        poses = ports.get("poses")
        if poses is not None and len(poses):
            rows += self._add_poses(poses)  # type: ignore[arg-type]
        imu = ports.get("imu")
        if imu is not None and len(imu) and self.gyro_rad:
            self._add_imu(imu)  # type: ignore[arg-type]
        ev = ports.get("events")
        if ev is not None and len(ev):
            self._add_events(ev)  # type: ignore[arg-type]
            rows += self._steps()
        return self._emit(rows, max(p.t_end for p in ports.values()))

    def finish(self) -> Sequence[Packet]:
        if self.bootstrap_us and self._boot_end is None and self.counts["bootstrap_steps"]:
            raise ValueError(f"tracker.edge_align: bootstrap_us={self.bootstrap_us} but no pose came on port 'poses' "
                             f"for the {self.counts['bootstrap_steps']} steps: connect the bootstrap's poses (a "
                             "source with poses, e.g. simulate:SCENE?poses=true)")
        steps = self.counts["steps"] - self.counts["bootstrap_steps"]  # the steps that would have used it
        if self.gyro_rad and steps and not self.counts["gyro_steps"] and not self._gt.size:
            raise ValueError(f"tracker.edge_align: gyro_rad={self.gyro_rad} but no gyro sample came on port 'imu' "
                             f"for the {steps} steps after the bootstrap: connect an IMU (a source with one, e.g. "
                             "a DAVIS recording, or simulate:SCENE?davis=true of a scene whose davis section has "
                             "imu_rate_hz), or leave gyro_rad at 0")
        return ()

    def _add_maps(self, maps: MapPacket) -> None:
        if "depth" not in maps.column_names or "K" not in maps.column_names or "pose" not in maps.column_names:
            raise ValueError(f"tracker.edge_align: maps on port 'maps' need depth, K and pose; got columns "
                             f"{list(maps.column_names)}")
        for i in range(len(maps)):
            t = int(maps.t[i])
            depth, K, pose = maps.depth[i], np.asarray(maps.K[i], np.float64), np.asarray(maps.pose[i], np.float64)
            if not (np.isfinite(K).all() and np.isfinite(pose).all()):
                raise ValueError(f"tracker.edge_align: the map at t={t} µs has a K or pose that is not finite")
            mine = np.array([self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy])
            theirs = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
            if np.any(np.abs(theirs - mine) > 0.01 * max(self.camera.fx, 1.0)):
                raise ValueError(f"tracker.edge_align: the map at t={t} µs has intrinsics fx, fy, cx, cy = "
                                 f"{theirs.round(3).tolist()} px, the calibration {mine.round(3).tolist()} px")
            self._check_size(depth.shape, t)
            if self._sensor is None:
                self._shapes.append((t, depth.shape))
            if self.min_neighbours:
                d = np.nan_to_num(np.asarray(depth, np.float64), nan=0.0)
                keep = np.zeros(d.shape, bool)
                consistent(d, 3, self.neighbour_tol, self.min_neighbours, keep)
                depth = np.where(keep, d, np.nan)
            pts = depth_points(depth, K, quat_to_rot(np.asarray(pose[3:7], np.float64)), pose[:3])[0]
            if len(pts) > self.max_points:
                pts = np.ascontiguousarray(pts[np.linspace(0, len(pts) - 1, self.max_points).astype(np.int64)])
            self._maps.append((t, pts))

    def _check_size(self, shape: tuple[int, ...], t: int) -> None:
        if self._sensor is not None and tuple(shape) != (self._sensor[1], self._sensor[0]):
            raise ValueError(f"tracker.edge_align: the map at t={t} µs is {shape[1]}x{shape[0]} px, the events "
                             f"{self._sensor[0]}x{self._sensor[1]} px")

    def _add_poses(self, poses: PosePacket) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray, bool]]:
        """Keep the bootstrap poses; return them as output rows."""
        if not self.bootstrap_us:
            return []
        if self._boot_end is None:
            self._boot_end = int(poses.t[0]) + self.bootstrap_us
        k = int(np.searchsorted(poses.t, self._boot_end, side="left"))
        if not k:
            return []
        pos, q = np.asarray(poses.position[:k], np.float64), np.asarray(poses.orientation[:k], np.float64)
        if not (np.isfinite(pos).all() and np.isfinite(q).all()):
            raise ValueError("tracker.edge_align: a bootstrap pose on port 'poses' is not finite")
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        self._bt = np.concatenate([self._bt, poses.t[:k]])
        self._bp = np.concatenate([self._bp, pos])
        self._bq = np.concatenate([self._bq, q])
        self.counts["bootstrap_poses"] += k
        zero = np.zeros(6)
        return [(int(poses.t[i]), pos[i], q[i], zero, False) for i in range(k)]

    def _add_imu(self, imu: ImuPacket) -> None:
        """Keep the gyro's samples (camera frame and time) from the last at or
        before the state's time on (before tracking: the bootstrap's span)."""
        w = np.asarray(imu.gyro, np.float64) @ self.R_ci.T
        ok = np.isfinite(w).all(axis=1)
        self.counts["imu_dropped"] += int(len(ok) - ok.sum())
        self._gt = np.concatenate([self._gt, imu.t[ok] + self.imu_offset])
        self._gw = np.concatenate([self._gw, w[ok]])
        if self._R is not None:
            keep_from = self._t_mid
        else:  # not tracking yet: the bootstrap's span (its bias), else the last gyro hold
            first = int(self._bt[0]) if self._bt.size else int(self._gt[-1]) - self.bootstrap_us
            keep_from = min(first, int(self._gt[-1]) - GYRO_HOLD_US)
        k = max(int(np.searchsorted(self._gt, keep_from, side="right")) - 1, 0)
        if k:
            self._gt, self._gw = self._gt[k:], self._gw[k:]

    def _gyro(self, t0: int, t1: int) -> np.ndarray | None:
        """Camera at ``t1`` from camera at ``t0`` (µs, ``t0 <= t1``) by the
        gyro less its bias; None when the samples do not reach over the span."""
        gt = self._gt
        if not gt.size or gt[0] > t0 or gt[-1] < t1 - GYRO_HOLD_US:
            return None
        return np.asarray(gyro_turn(gt, self._gw - self._bias, t0, t1)).T

    def _bootstrap_bias(self) -> None:
        """The gyro's bias: over :data:`BIAS_SPAN_US` spans of the bootstrap
        the gyro and the bootstrap poses both give the turn; the bias is the
        mean gap per second (first order: ``exp(-ω_gyro T) exp(ω T) ≈
        exp(-b T)``). Left as it is when the gyro does not cover them."""
        a = max(int(self._bt[0]), int(self._gt[0]) if self._gt.size else int(self._bt[-1]))
        edges = np.arange(a, int(self._bt[-1]) + 1, BIAS_SPAN_US)
        R_wc = np.asarray(quat_to_rot(interpolate_poses(edges, self._bt, self._bp, self._bq)[1])).reshape(-1, 3, 3)
        gaps = []
        raw, self._bias = self._bias, np.zeros(3)
        for i in range(len(edges) - 1):
            t0, t1 = int(edges[i]), int(edges[i + 1])
            G = self._gyro(t0, t1)
            if G is None:
                continue
            turn = R_wc[i + 1].T @ R_wc[i]  # camera at t1 from camera at t0, by the poses
            gaps.append(-np.asarray(so3_log(G @ turn.T)) / ((t1 - t0) * 1e-6))
        self._bias = np.mean(gaps, axis=0) if gaps else raw

    def _add_events(self, ev: EventPacket) -> None:
        if self._sensor is None:
            self._start(ev.sensor)
        elif ev.sensor != self._sensor:
            raise ValueError(f"tracker.edge_align: the sensor changed from {self._sensor} to {ev.sensor}")
        xy = self._table[ev.y, ev.x]
        self._t = np.concatenate([self._t, ev.t])
        self._xu = np.concatenate([self._xu, xy[:, 0]])
        self._yu = np.concatenate([self._yu, xy[:, 1]])

    def _start(self, sensor: tuple[int, int]) -> None:
        w, h = sensor
        size = self.camera.size
        if size is not None and tuple(size) != (w, h):
            raise ValueError(f"tracker.edge_align: the calibration is for {size[0]}x{size[1]} px, the events for "
                             f"{w}x{h}")
        self._sensor = (w, h)
        for t, shape in self._shapes:  # maps that came before the events
            self._check_size(shape, t)
        self._shapes = []
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        und = self.camera.undistort_points(np.stack([u.ravel(), v.ravel()], axis=1))
        und[~np.isfinite(und).all(axis=1)] = -1e6  # no inverse: never votes
        self._table = np.ascontiguousarray(und.reshape(h, w, 2))
        self._img, self._gx, self._gy = np.zeros((h, w)), np.zeros((h, w)), np.zeros((h, w))

    # -- steps ------------------------------------------------------------------------------
    def _steps(self) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray, bool]]:
        rows = []
        while len(self._t) >= self._next_end:
            b = self._next_end
            a = b - self.window_events
            row = self._step(a, b)
            if row is not None:
                rows.append(row)
            self._next_end += self.step_events
        k = self._next_end - self.window_events
        if k > 0:
            self._t, self._xu, self._yu = self._t[k:], self._xu[k:], self._yu[k:]
            self._next_end -= k
        return rows

    def _image(self, a: int, b: int, sigma: float) -> None:
        """The normalised, blurred event image of events ``[a, b)`` and its gradients."""
        img = self._img
        img[:] = 0.0
        vote_events(self._xu[a:b], self._yu[a:b], img)
        if self.binary:
            img[:] = img >= 0.5
        img[:] = gaussian_filter(img, sigma, mode="constant", truncate=3.0)
        flat = img.ravel()
        k = max(1, int(TOP_FRACTION * flat.size))
        top = float(np.partition(flat, flat.size - k)[flat.size - k])
        normalise(img, top if top > 0 else 1.0)
        gradients(img, self._gx, self._gy)

    def _step(self, a: int, b: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, bool] | None:
        self.counts["steps"] += 1
        t_last = int(self._t[b - 1])
        t_mid = int(self._t[(a + b - 1) // 2])
        while self._maps and self._maps[0][0] <= t_last:  # the latest map stamped by now
            self._points = self._maps.pop(0)[1]
            if self._overlap is not None and self.known_overlap:
                self._known_overlap = self._overlap  # the map before's, until this one has its own
            self._overlap = None
            self.counts["maps"] += 1
        if self._R is None and not self._begin(a, b, t_mid, t_last):
            return None
        assert self._R is not None
        if self._points is None:
            self.counts["lost_no_map"] += 1
            return self._lost_row(t_last)
        self._coast(t_mid)
        R, tr, gyro = self._predict(t_mid)  # lost: relocalise from the coasting prediction, one level coarser
        levels = self.levels + 1 if self._lost else self.levels
        info = np.zeros(4)
        if self._ref_pending:  # the map's overlap where the bootstrap says the camera is
            self._ref_pending = False
            self._image(a, b, self.sigma_px)
            align(self._points, R.copy(), tr.copy(), R, tr, self.cam, self._img, self._gx, self._gy, self.huber, 1.0,
                  MIN_DEPTH_M, 0, 1e-6, self._prior, info)
            if info[1] >= self.min_points:
                self._known_overlap = float(info[2])
        Rp, tp = R.copy(), tr.copy()
        prior = self._gyro_prior if gyro else self._prior
        self.counts["gyro_steps"] += gyro
        for lvl in range(levels - 1, -1, -1):
            self._image(a, b, self.sigma_px * 2.0 ** lvl)
            align(self._points, R, tr, Rp, tp, self.cam, self._img, self._gx, self._gy, self.huber, 1.0, MIN_DEPTH_M,
                  self.max_iter, 1e-6, prior, info)
        self.last_info = info
        if info[1] < self.min_points:
            self.counts["lost_few_points"] += 1
            return self._lost_row(t_last, lose=True)
        ov, ref = float(info[2]), self._overlap
        if self._lost:
            known = ref if ref is not None else self._known_overlap
            if ref is None and known is not None and known < self.min_overlap:
                known = None  # the map before, or this one at the bootstrap, was no better than lost: no bar from it
            bad = ov < (2 * self.min_overlap if known is None else
                        max(self.min_overlap, self.relocalise_overlap * known))
        else:
            bad = ov < self.min_overlap or (ref is not None and ov < self.overlap_drop * ref)
        if bad:
            self.counts["lost_overlap"] += 1
            return self._lost_row(t_last, lose=True)
        if not self._plausible(R, tr, (t_mid - self._t_mid) * 1e-6):
            self.counts["lost_jump"] += 1
            return self._lost_row(t_last, lose=True)
        self._overlap = ov if ref is None else ref + 0.1 * (ov - ref)
        if self._lost:
            self.counts["relocalised"] += 1
        self._set_state(R, tr, t_mid)
        self.counts["tracked"] += 1
        return self._row(t_last)

    def _begin(self, a: int, b: int, t_mid: int, t_last: int) -> bool:
        """Start tracking at this step when the bootstrap allows; False: not yet."""
        if self.bootstrap_us:
            if self._boot_end is None or t_last < self._boot_end or not self._bt.size:
                self.counts["bootstrap_steps"] += 1
                return False
            # the last bootstrap pose and the twist over the bootstrap's last 10 ms
            R1, t1 = self._bootstrap_pose(int(self._bt[-1]))
            t0 = max(int(self._bt[0]), int(self._bt[-1]) - 10_000)
            self._set_state(R1, t1, int(self._bt[-1]))
            self._ref_pending = self.known_overlap
            if not self._bias_given and self._gt.size:
                self._bootstrap_bias()
            if t0 < int(self._bt[-1]):
                R0, p0 = self._bootstrap_pose(t0)
                self._xi = _twist(R0, p0, R1, t1, (int(self._bt[-1]) - t0) * 1e-6)
                self._has_velocity = True
            return True
        if self.plane_depth > 0:
            self._image(a, b, self.sigma_px)
            v, u = np.nonzero(self._img >= 0.5)
            Z = self.plane_depth
            pts = np.stack([(u - self.cam[2]) / self.cam[0] * Z, (v - self.cam[3]) / self.cam[1] * Z,
                            np.full(len(u), Z)], axis=1)
            if len(pts) > self.max_points:
                pts = pts[np.linspace(0, len(pts) - 1, self.max_points).astype(np.int64)]
            self._points = np.ascontiguousarray(pts)
            self._set_state(np.eye(3), np.zeros(3), t_mid)
            return True
        self.counts["bootstrap_steps"] += 1
        return False

    def _plausible(self, R: np.ndarray, tr: np.ndarray, dt: float) -> bool:
        """Whether camera-from-world ``(R, tr)`` is within reach of the last
        good pose ``dt`` s later (``max_speed``, ``max_rate``; plus 2 cm, 0.02 rad)."""
        assert self._R is not None
        turn = float(np.linalg.norm(so3_log(R @ self._R.T)))
        move = float(np.linalg.norm(R.T @ tr - self._R.T @ self._tr))  # camera centres
        return turn <= self.max_rate * dt + 0.02 and move <= self.max_speed * dt + 0.02

    def _bootstrap_pose(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Camera-from-world at ``t`` µs from the bootstrap poses."""
        p, q, _ = interpolate_poses(np.array([t], np.int64), self._bt, self._bp, self._bq)
        R_wc = np.asarray(quat_to_rot(q[0]))
        return R_wc.T, -(R_wc.T @ p[0])

    def _predict(self, t: int) -> tuple[np.ndarray, np.ndarray, bool]:
        """Camera-from-world at ``t`` µs (not before the last good step's
        time): the position at constant velocity, the rotation by the gyro
        where it reaches (then True), else at constant velocity."""
        assert self._R is not None
        R, tr = self._R.copy(), self._tr.copy()
        if self._has_velocity:
            # world-from-camera moves by exp(ξ dt) on the right, so camera-from-world by exp(-ξ dt) on the left
            dR, dtr = se3_exp(-self._xi * ((t - self._t_mid) * 1e-6))
            R, tr = dR @ R, dR @ tr + dtr
        G = self._gyro(self._t_mid, t)
        if G is None:
            return R, tr, False
        centre = -(R.T @ tr)
        R = G @ self._R
        return R, -(R @ centre), True

    def _set_state(self, R: np.ndarray, tr: np.ndarray, t_mid: int) -> None:
        if self._R is not None and not self._lost and t_mid > self._t_mid:
            xi = _twist(self._R, self._tr, R, tr, (t_mid - self._t_mid) * 1e-6)
            self._xi = xi if not self._has_velocity else self._xi + self.velocity_gain * (xi - self._xi)
            self._has_velocity = True
        self._R, self._tr, self._t_mid = R.copy(), tr.copy(), t_mid
        self._lost = False

    def _row(self, t_last: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, bool]:
        R, tr, _ = self._predict(t_last)
        R_wc = R.T
        return (t_last, -(R_wc @ tr), np.asarray(rot_to_quat(R_wc)), self._xi.copy(), False)

    def _coast(self, t: int) -> None:
        """Lost for longer than ``coast_us`` by ``t`` µs: stop predicting motion."""
        if self._lost and self._has_velocity and t - self._t_mid > self.coast_us:
            self._has_velocity = False
            self._xi = np.zeros(6)

    def _lost_row(self, t_last: int, lose: bool = False) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, bool]:
        """A lost row at ``t_last``: the prediction (coasting at the last
        velocity for ``coast_us``, then the last good pose held)."""
        assert self._R is not None
        if lose:
            self._lost = True
        self._coast(t_last)
        R, tr, _ = self._predict(t_last)
        R_wc = R.T
        xi = self._xi.copy() if self._has_velocity else np.zeros(6)
        return (t_last, -(R_wc @ tr), np.asarray(rot_to_quat(R_wc)), xi, True)

    def _emit(self, rows: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, bool]], watermark: int) -> list[Packet]:
        assert self._mark is not None
        if not rows:
            return []
        t = np.array([r[0] for r in rows], np.int64)
        xi = np.array([r[3] for r in rows]).reshape(-1, 6)
        R_wc = np.asarray(quat_to_rot(np.array([r[2] for r in rows]).reshape(-1, 4))).reshape(-1, 3, 3)
        out = PosePacket(t, position=np.array([r[1] for r in rows]).reshape(-1, 3),
                         orientation=np.array([r[2] for r in rows]).reshape(-1, 4),
                         linear_velocity=np.einsum("nij,nj->ni", R_wc, xi[:, 3:]), angular_velocity=xi[:, :3],
                         lost=np.array([r[4] for r in rows], bool), t_start=self._mark,
                         t_end=max(watermark, int(t[-1]) + 1))
        self._mark = out.t_end
        return [out]


def _twist(R0: np.ndarray, t0: np.ndarray, R1: np.ndarray, t1: np.ndarray, dt: float) -> np.ndarray:
    """The body twist (ω, v) per s (camera frame) taking camera-from-world
    ``(R0, t0)`` to ``(R1, t1)`` in ``dt`` s: world-from-camera
    ``T1 = T0 exp(ξ dt)``."""
    # T0^-1 T1 with T = world-from-camera = (R^T, -R^T t)
    R_rel = R0 @ R1.T
    t_rel = R0 @ (-(R1.T @ t1)) + t0
    return np.asarray(se3_log(R_rel, t_rel)) / max(dt, 1e-9)


def _points_scene(duration_us: int, sensor: tuple[int, int], f: float, speed: float = 0.5, n_points: int = 60,
                  period_us: int = 100, seed: int = 0, depth: tuple[float, float] = (1.0, 3.0),
                  omega: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> dict[str, Packet]:
    """Events of ``n_points`` world points ``depth`` m away (one event per visible
    point every ``period_us`` at its rounded projection) seen by a pinhole
    camera (focal ``f`` px, centred) sliding along x at ``speed`` m/s and
    turning at ``omega`` rad/s (camera frame: world-from-camera ``exp(ω t)``);
    its poses and gyro (``imu``, exact) at 1 kHz and a map of the points from
    the first pose. For the conformance check and tests."""
    rng = np.random.default_rng(seed)
    w, h = sensor
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    Z = rng.uniform(depth[0], depth[1], n_points)
    X = (rng.uniform(0.05, 0.95, n_points) * w - cx) / f * Z
    Y = (rng.uniform(0.05, 0.95, n_points) * h - cy) / f * Z
    P = np.stack([X, Y, Z], axis=1)
    om = np.asarray(omega, np.float64)
    ts = np.arange(0, duration_us, period_us, dtype=np.int64)
    t_all, x_all, y_all = [], [], []
    for t in ts:
        R_wc = so3_exp(om * t * 1e-6)
        pc = (P - np.array([speed * t * 1e-6, 0.0, 0.0])) @ R_wc  # R_wcᵀ (P - c), row by row
        u = np.round(f * pc[:, 0] / pc[:, 2] + cx)
        v = np.round(f * pc[:, 1] / pc[:, 2] + cy)
        ok = (u >= 0) & (v >= 0) & (u <= w - 1) & (v <= h - 1) & (pc[:, 2] > 0)
        t_all.append(np.full(int(ok.sum()), t))
        x_all.append(u[ok])
        y_all.append(v[ok])
    t_ev = np.concatenate(t_all)
    ev = EventPacket.from_arrays(t_ev, np.concatenate(x_all), np.concatenate(y_all), np.ones(len(t_ev), np.int8),
                                 sensor=sensor, t_start=0, t_end=duration_us)
    tp = np.arange(0, duration_us + 1, 1000, dtype=np.int64)
    pos = np.zeros((len(tp), 3))
    pos[:, 0] = speed * tp * 1e-6
    poses = PosePacket(tp, position=pos, orientation=np.asarray(rot_to_quat(so3_exp(np.outer(tp * 1e-6, om)))),
                       t_start=0, t_end=duration_us + 1)
    imu = ImuPacket(tp, accel=np.zeros((len(tp), 3)), gyro=np.tile(om, (len(tp), 1)), t_start=0,
                    t_end=duration_us + 1)
    dmap = np.full((h, w), np.nan, np.float32)
    u0 = np.round(f * X / Z + cx).astype(np.int64)
    v0 = np.round(f * Y / Z + cy).astype(np.int64)
    dmap[v0, u0] = Z
    K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
    maps = MapPacket(np.array([0], np.int64), depth=dmap[None], K=K[None],
                     pose=np.array([[0, 0, 0, 0, 0, 0, 1.0]]), t_start=0, t_end=duration_us + 1)
    return {"events": ev, "maps": maps, "poses": poses, "imu": imu}
