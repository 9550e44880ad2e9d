"""``map.emvs``: semi-dense depth from events and known camera poses by
event-based multi-view stereo (Rebecq, Gallego, Mueggler, Scaramuzza,
"EMVS: Event-based Multi-View Stereo", BMVC 2016; IJCV 126, 2018).

An edge moving across the sensor fires events along its path; with the
camera's poses known, every event is a ray in space, and the rays of one
edge seen from several viewpoints meet where the edge is. EMVS counts the
rays through each cell of a *disparity space image* (DSI): the view frustum
of a reference camera cut into ``planes`` depth planes between
``min_depth`` and ``max_depth`` (m), spaced uniformly in inverse depth by
default (as the paper does: equal steps of disparity) or in depth
(``spacing="depth"``). Cells where many rays cross are scene points.

Steps (IJCV 2018 Sec. 3-4; the kernels are in :mod:`._dsi`):

1. Events are undistorted (``tectum.camera``: the calibration's lens) and
   grouped into *segments* of ``segment_events`` consecutive events (fewer
   where the next event comes more than ``segment_us`` after a segment's
   first): the camera moves little within one, so all of its events share
   one pose, interpolated at the segment's middle time (linear position,
   slerp orientation). Segments depend on the events only, not on how the
   stream is cut into packets, so the output is the same for any split.
2. Each event's ray is swept through the planes (a plane-sweep transfer,
   two multiply-adds per plane) and votes bilinearly into the DSI.
3. When the camera centre has moved more than ``keyframe_baseline`` times
   the scene depth (the median depth of the previous map; before the first
   map, the geometric mean of ``min_depth`` and ``max_depth``) from the
   reference view, the DSI becomes a map and a new reference view starts at
   the current pose: a long trajectory gives a sequence of maps. The last
   DSI becomes a map at end of stream. With ``overlap`` n > 1, n reference
   views are in progress at once, staggered: a new one starts whenever the
   camera has moved ``keyframe_baseline / n`` times the scene depth from
   the newest, and each ends (becomes a map) after ``keyframe_baseline``,
   so a map comes every ``keyframe_baseline / n`` of travel while each
   still integrates ``keyframe_baseline`` of it (a sliding DSI: fresh maps
   for a tracker without the short baselines' poorer depth; n DSIs, n
   times the votes). Views that end together (at a gap, at the end of
   stream) hold the events of the oldest among them from a later start:
   only the oldest becomes a map (the others counted in ``superseded``).
   With ``interim`` n > 1 (and one view at a time), a view's DSI so far
   also becomes a map after each ``keyframe_baseline / n`` of travel, the
   view going on: maps as often, all from one reference view (its pose,
   its depth planes) until it ends.
4. Map: per pixel the plane with most votes (the depth, refined between
   planes by a parabola when ``refine``) and its vote count (the
   confidence); with ``focus`` r > 0 px the depth is instead the plane
   whose slice is sharpest about the pixel (the largest local variance of
   its votes over a (2r + 1)^2 window: depth from focus), the confidence
   still the most votes. On a smooth texture at a short baseline (the
   EVO bench's plane: blobs ~10 px wide, at most 10 px of disparity
   across the DSI) the most-voted cell is nearly anywhere along the ray,
   and where the DSI's range reaches farther from the surface on one side
   (in inverse depth) the depth is biased to that side; the sharpest slice
   is not (``docs/evo.md``: the median error of the maps' points 44 % ->
   5 %). A window of r px flattens depth over about r px: depth edges
   blur; pixels whose confidence exceeds its Gaussian-filtered
   neighbourhood (σ ``threshold_sigma`` px) by ``threshold_c`` times the
   largest confidence keep their depth (the paper's adaptive threshold);
   then a ``median_size`` median filter over the kept pixels.
5. Surface (``surface``): ``"free"`` (the default) keeps each pixel's own
   depth. ``"plane"`` fits a plane to the map's pixels (robustly, in inverse
   depth, in the reference camera: :mod:`._plane_fit`) and gives the same
   pixels the plane's depth instead; ``"auto"`` does so only when the plane
   explains the map (at least ``plane_inliers`` of its pixels within
   ``plane_tol`` DSI planes of it) and keeps the free depth otherwise. Those
   maps say which they are: columns ``planar`` (1 or 0) and ``plane`` (the
   plane's ``1 / Z = a x + b y + c`` over normalised coordinates, 1/m; NaN
   when free). EMVS's depth of a real plane is seldom close enough for
   ``auto`` (none of its maps of the EVO bench's plane passes: ``docs/evo.md``);
   ``plane`` is a prior for a scene known to be planar. ``"world_plane"``
   is the same prior with one plane for the whole run: the first
   ``plane_maps`` maps get their own planes as with ``plane`` (made from the
   poses at hand then, e.g. a bootstrap's), and from the next map on every
   map's pixels take the depth of their mean, fixed in the world, seen from
   the map's reference pose; so a tracker's later poses no longer reshape
   the surface (in a loop the maps from its turned poses bent each plane
   with them: ``docs/evo.md``).

Output: a :class:`~tectum.MapPacket` per map, stamped at its last event
(µs), with ``depth`` (m, float32 (H, W), NaN where unknown), ``confidence``
(votes), ``K`` (the undistorted reference view's intrinsics), ``pose`` (the
reference view, world-from-camera) and extra columns ``t_ref`` (µs, the
reference view's time) and ``baseline`` (m, the farthest the camera got from
the reference view while its events voted); and with ``points=True`` a
:class:`~tectum.PointPacket` of the same time: the map's pixels
back-projected into the world (m), ``intensity`` the confidence. Both go
out on the one output stream: ``--sink depth.npz`` stores the maps (and the
points), ``--sink cloud.ply`` writes the clouds (a sink takes the kinds it
consumes).

Lost poses (rows of a tracker's pose stream flagged ``lost``: predictions,
not measurements) are not used. Lost rows between two good poses at least
``gap_us`` apart make a *gap*: events whose segment falls in it are not
mapped (counted in ``skipped_lost_poses``); the first such segment ends the
reference view in progress, which becomes a map at once (no later good pose
is needed: a tracker that stays lost still gets the map it waits for), and
the first segment after the gap starts a new reference view. Shorter runs of
lost rows are bridged: the poses either side are interpolated.

No translation, no depth: a reference view from which the camera moved less
than ``min_baseline`` times the scene depth (pure rotation, standing still)
gives no map; it is counted in ``counts["no_translation"]`` and logged.
Events before the first pose or after the last are not mapped (counted in
``skipped_before_poses`` / ``skipped_after_poses``); a stream whose poses
cover none of the events is an error at the end.

Cost: per event one 3x3 product and ``planes`` bilinear votes (numba, plane
by plane); per map an argmax over the DSI, a Gaussian filter and a median
(with ``focus``, also two box sums per cell: ~45 ms a map of 100 planes at
240x180, loaded).
Memory: the DSI (``overlap`` of them), ``planes x H x W x 4`` bytes (100 planes at 240x180:
17.3 MB; at 346x260: 36 MB), plus the events waiting for their pose and
the traces of one block of 65,536 events (1 MB).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.ndimage import gaussian_filter

from tectum import EventPacket, Kind, MapPacket, Operator, Packet, PointPacket, Port, PosePacket
from tectum.camera import QUAT_TOL, Camera, camera_from, depth_points, interpolate_poses, quat_to_rot, rot_to_quat

from ._dsi import BLOCK, argmax_depth, focus_argmax, masked_median, ray_traces, vote
from ._plane_fit import explains, fit_plane, plane_depth, plane_in_view, plane_to_world

__all__ = ["Emvs", "depth_planes", "depth_map"]

log = logging.getLogger("tectum.map.emvs")


def depth_planes(planes: int, min_depth: float, max_depth: float,
                 spacing: Literal["inverse", "depth"] = "inverse") -> np.ndarray:
    """The DSI's plane depths (m), near to far: ``planes`` values from
    ``min_depth`` to ``max_depth``, uniform in inverse depth (``"inverse"``,
    the paper's choice: equal steps of disparity) or in depth."""
    if planes < 2:
        raise ValueError(f"map.emvs: planes must be >= 2, got {planes}")
    if not (0 < min_depth < max_depth and math.isfinite(max_depth)):
        raise ValueError(f"map.emvs: need 0 < min_depth < max_depth (m), got {min_depth}, {max_depth}")
    if spacing == "inverse":
        return np.asarray(1.0 / np.linspace(1.0 / min_depth, 1.0 / max_depth, planes))
    if spacing == "depth":
        return np.linspace(min_depth, max_depth, planes)
    raise ValueError(f"map.emvs: spacing must be 'inverse' or 'depth', got {spacing!r}")


def depth_map(dsi: np.ndarray, depths: np.ndarray, *, refine: bool = True, threshold_sigma: float = 2.0,
              threshold_c: float = 0.05, median_size: int = 5, focus: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A semi-dense depth map from a DSI (P, H, W) of votes whose planes lie
    at ``depths`` (P,) m: ``(depth (H, W) float32 m, NaN where unknown;
    confidence (H, W) float32, the votes of the best plane)``. See the
    module doc for the steps; ``median_size`` 1 skips the median filter."""
    P, H, W = dsi.shape
    if depths.shape != (P,):
        raise ValueError(f"map.emvs: {P} planes in the DSI but {depths.shape} depths")
    if median_size < 1 or median_size % 2 == 0:
        raise ValueError(f"map.emvs: median_size must be odd and >= 1, got {median_size}")
    if focus < 0:
        raise ValueError(f"map.emvs: focus must be >= 0 px, got {focus}")
    index = np.empty((H, W))
    conf = np.empty((H, W), np.float32)
    argmax_depth(dsi, refine, index, conf)
    if focus:  # the depth where the DSI is sharpest about the pixel; the confidence stays its most votes
        focus_argmax(dsi, int(focus), refine, index)
    top = float(conf.max())
    if top <= 0:
        return np.full((H, W), np.nan, np.float32), conf
    c = conf.astype(np.float64) / top
    keep = c > gaussian_filter(c, threshold_sigma, mode="nearest") + threshold_c
    # the fractional plane index -> depth, linearly in the planes' own spacing
    lo = np.clip(np.floor(index).astype(np.int64), 0, P - 2)
    f = index - lo
    uniform_inverse = np.allclose(np.diff(1.0 / depths), (1.0 / depths[-1] - 1.0 / depths[0]) / (P - 1))
    if uniform_inverse:
        depth = 1.0 / ((1 - f) / depths[lo] + f / depths[lo + 1])
    else:
        depth = (1 - f) * depths[lo] + f * depths[lo + 1]
    out = np.empty((H, W))
    if median_size > 1:
        masked_median(depth, keep, median_size // 2, out)
    else:
        out = np.where(keep, depth, np.nan)
    return out.astype(np.float32), conf


@dataclass
class _View:
    """A reference view in progress: world-from-reference rotation
    ``R_wr`` and position ``t_wr`` (m), its time ``t_ref`` (µs) and DSI;
    ``baseline`` the farthest a segment's camera got from it (m),
    ``last_t`` the last event voted into it (µs), ``run`` the first of the
    segments being voted that it takes."""

    R_wr: np.ndarray
    t_wr: np.ndarray
    t_ref: int
    dsi: np.ndarray
    baseline: float = 0.0
    voted: bool = False
    last_t: int = 0
    run: int = 0
    shown: int = 0  # interim maps made so far
    #: traces (4, n) float32 and first planes of events not voted yet (see Emvs._vote), in event order
    pending: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    n_pending: int = 0


class Emvs(Operator):
    """Semi-dense depth maps (and point clouds) from events and camera poses
    by event-based multi-view stereo (EMVS, Rebecq et al. BMVC 2016).

    Parameters
    ----------
    calib:
        Calibration file (OpenCV YAML/JSON, ROS camera_info, UZH calib.txt)
        or inline ``fx;fy;cx;cy[;k1;k2;p1;p2;k3]`` (px); defaults to the
        calibration beside the source recording.
    planes:
        Depth planes of the DSI.
    min_depth:
        Depth of the DSI's nearest plane, m.
    max_depth:
        Depth of its farthest plane, m.
    spacing:
        ``inverse`` (uniform in 1/depth, the paper's) or ``depth``.
    segment_events:
        Events sharing one interpolated pose.
    segment_us:
        Longest time a segment spans, µs.
    keyframe_baseline:
        A new reference view when the camera has moved this fraction of the
        scene depth from the current one.
    min_baseline:
        A reference view whose camera moved less than this fraction of the
        scene depth gives no map (counted as ``no_translation``).
    overlap:
        Reference views in progress at once (1: one after the other): a new
        one every ``keyframe_baseline / overlap`` of the scene depth, each
        integrating ``keyframe_baseline`` of it.
    interim:
        Maps per reference view: its DSI so far becomes a map after each
        ``keyframe_baseline / interim`` of the scene depth (1: at its end
        only); with ``overlap`` 1 only.
    refine:
        Sub-plane depth by a parabola through the votes either side.
    threshold_sigma:
        σ of the adaptive threshold's Gaussian, px.
    threshold_c:
        Margin of the adaptive threshold, a fraction of the largest confidence.
    median_size:
        Side of the median filter on the depth, px (odd; 1: none).
    focus:
        0: a pixel's depth is its plane with most votes (the paper's); r > 0:
        the plane whose votes vary most over the (2r + 1)^2 px about it (the
        sharpest slice, depth from focus), px.
    points:
        Emit each map's point cloud (PointPacket, world frame) as well.
    gap_us:
        Lost pose rows between good poses this far apart or more make a gap
        (not mapped, the map in progress ends), µs.
    surface:
        ``free`` (each pixel its own depth), ``plane`` (a map's pixels get
        the depth of the plane fitted to them), ``auto`` (the plane where
        it explains the map) or ``world_plane`` (one plane in the world,
        from the first ``plane_maps`` maps); see the module, step 5.
    plane_tol:
        ``auto``: a pixel is on the plane within this many DSI planes (of
        inverse depth).
    plane_inliers:
        ``auto``: the share of a map's pixels on the plane for the plane to
        explain it (0..1].
    plane_maps:
        ``world_plane``: the maps whose own planes make the world's (>= 1).
    """

    name = "map.emvs"
    inputs = {
        "events": Port(Kind.EVENTS, doc="the events to map"),
        "poses": Port(Kind.POSES, doc="camera poses (world-from-camera) covering the events (rows flagged lost "
                                      "are not used: they mark a gap)"),
    }
    produces = (Kind.MAPS, Kind.POINTS)
    heavy = True

    def __init__(self, calib: str = "", planes: int = 100, min_depth: float = 0.3, max_depth: float = 5.0,
                 spacing: Literal["inverse", "depth"] = "inverse", segment_events: int = 1024,
                 segment_us: int = 10_000, keyframe_baseline: float = 0.15, min_baseline: float = 0.02,
                 overlap: int = 1, interim: int = 1, refine: bool = True, threshold_sigma: float = 2.0,
                 threshold_c: float = 0.05, median_size: int = 5, points: bool = True, gap_us: int = 20_000,
                 surface: Literal["free", "plane", "auto", "world_plane"] = "free", plane_tol: float = 2.0,
                 plane_inliers: float = 0.8, focus: int = 0, plane_maps: int = 3) -> None:
        self.camera: Camera = camera_from(calib)
        self.depths = depth_planes(planes, min_depth, max_depth, spacing)
        self.rho = np.ascontiguousarray(1.0 / self.depths)
        if segment_events < 1 or segment_us < 1:
            raise ValueError("map.emvs: segment_events and segment_us must be >= 1")
        if not 0 <= min_baseline < keyframe_baseline:
            raise ValueError(f"map.emvs: need 0 <= min_baseline < keyframe_baseline, got {min_baseline}, "
                             f"{keyframe_baseline}")
        if median_size < 1 or median_size % 2 == 0:
            raise ValueError(f"map.emvs: median_size must be odd and >= 1, got {median_size}")
        if focus < 0:
            raise ValueError(f"map.emvs: focus must be >= 0 px, got {focus}")
        self.segment_events, self.segment_us = int(segment_events), int(segment_us)
        self.keyframe_baseline, self.min_baseline = float(keyframe_baseline), float(min_baseline)
        if overlap < 1:
            raise ValueError(f"map.emvs: overlap must be >= 1 reference view, got {overlap}")
        self.overlap = int(overlap)
        if interim < 1 or (interim > 1 and overlap > 1):
            raise ValueError(f"map.emvs: interim must be >= 1 map per view, and overlap or interim 1 (one of them "
                             f"at a time), got interim {interim}, overlap {overlap}")
        self.interim = int(interim)
        self.map_options = {"refine": bool(refine), "threshold_sigma": float(threshold_sigma),
                            "threshold_c": float(threshold_c), "median_size": int(median_size), "focus": int(focus)}
        self.points = bool(points)
        if gap_us < 1:
            raise ValueError(f"map.emvs: gap_us must be >= 1 µs, got {gap_us}")
        self.gap_us = int(gap_us)
        if surface not in ("free", "plane", "auto", "world_plane"):
            raise ValueError(f"map.emvs: surface must be 'free', 'plane', 'auto' or 'world_plane', got {surface!r}")
        if plane_maps < 1:
            raise ValueError(f"map.emvs: plane_maps must be >= 1 map, got {plane_maps}")
        if not plane_tol > 0 or not 0 < plane_inliers <= 1:
            raise ValueError(f"map.emvs: need plane_tol > 0 (DSI planes) and 0 < plane_inliers <= 1, got "
                             f"{plane_tol}, {plane_inliers}")
        self.surface = surface
        # the tolerance in inverse depth (1/m): plane_tol times the DSI's median plane spacing
        self.plane_tol = float(plane_tol) * float(np.median(np.abs(np.diff(self.rho))))
        self.plane_inliers = float(plane_inliers)
        self.plane_maps = int(plane_maps)
        #: world_plane: the world planes (unit normal, offset m) of the first maps
        self.world_planes: list[tuple[np.ndarray, float]] = []
        self.K = np.array([[self.camera.fx, 0, self.camera.cx], [0, self.camera.fy, self.camera.cy], [0, 0, 1.0]])
        self.counts = {"maps": 0, "no_translation": 0, "skipped_before_poses": 0, "skipped_after_poses": 0,
                       "outside_view": 0, "lost_poses": 0, "skipped_lost_poses": 0, "superseded": 0,
                       "planar_maps": 0}
        self.scene_depth = math.sqrt(min_depth * max_depth)  # m, until a map says better
        self._sensor: tuple[int, int] | None = None
        self._rays = np.empty((0, 0, 2))
        # poses so far: times (µs), positions (m), orientations (x, y, z, w)
        self._kt = np.empty(0, np.int64)
        self._kp = np.empty((0, 3))
        self._kq = np.empty((0, 4))
        self._klost = np.empty(0, np.int64)  # per pose: the last lost row before the next pose, µs (-1: none)
        # events waiting for their segment to close or its pose to come
        self._t = np.empty(0, np.int64)
        self._x = np.empty(0, np.uint16)
        self._y = np.empty(0, np.uint16)
        self._events_seen = 0
        # the reference views in progress and their DSIs, oldest first
        self._views: list[_View] = []
        self._mark = 0        # µs, the events' watermark
        self._first_pose: int | None = None  # µs

    #: For the conformance check: inline intrinsics of a 48x36 sensor, few planes.
    conformance_params = {"calib": "40;40;23.5;17.5", "planes": 16, "min_depth": 0.5, "max_depth": 4.0,
                          "segment_events": 64, "keyframe_baseline": 0.012, "min_baseline": 0.004, "overlap": 2}

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """Events of points at 1-3 m seen by a camera sliding sideways, and
        its poses at 1 kHz (for the conformance check)."""
        return translating_points(duration_us=60_000, sensor=(48, 36), f=40.0)

    def warmup(self) -> None:
        z = np.zeros(2, np.uint16)
        seg = np.zeros(2, np.int64)
        trace = np.empty((4, 2), np.float32)
        ray_traces(z, z, seg, np.zeros((1, 1, 2)), np.eye(3)[None], np.zeros((1, 3)), 1.0, 1.0, 0.0, 0.0, trace)
        dsi = np.zeros((2, 2, 2), np.float32)
        vote(trace, seg, np.ones(2), dsi)
        depth_map(dsi, np.array([1.0, 2.0]), median_size=3, focus=int(self.map_options["focus"]))

    # -- input ------------------------------------------------------------------
    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        poses = ports.get("poses")
        if poses is not None and len(poses):
            self._add_poses(poses)  # type: ignore[arg-type]
        ev = ports.get("events")
        if ev is not None:
            self._mark = ev.t_end
            if len(ev):
                self._add_events(ev)  # type: ignore[arg-type]
        return self._advance(final=False)

    def output_mark(self, watermark: int) -> int:
        """A map is stamped with the last event voted into it, which may lie
        before the input's watermark: no later map or cloud is stamped
        before the last event voted so far (a reference view in progress),
        else before the first event still waiting for its pose."""
        voted = [v.last_t for v in self._views if v.voted]
        if voted:
            return min(voted)
        return int(self._t[0]) if self._t.size else watermark

    def finish(self) -> list[Packet]:
        out = self._advance(final=True) + self._end_views(self._views, [], np.empty((0, 3)), np.empty((0, 4)))
        self._views = []
        if self._events_seen and self.counts["skipped_before_poses"] + self.counts["skipped_after_poses"] \
                == self._events_seen:
            span = (f"the poses span [{int(self._kt[0])}, {int(self._kt[-1])}] µs" if self._kt.size
                    else "no pose arrived")
            raise ValueError(f"map.emvs: none of the {self._events_seen} events lies within the poses on port "
                             f"'poses' ({span}): connect poses that cover the events")
        return out

    def _add_poses(self, poses: PosePacket) -> None:
        lost = poses.data.get("lost")
        last_lost = np.full(len(poses), -1, np.int64)  # per good row: the last lost row after it, µs
        if lost is not None and lost.any():  # a tracker's predictions, not measurements: not used
            lost = np.asarray(lost, bool)
            self.counts["lost_poses"] += int(lost.sum())
            keep = np.flatnonzero(~lost)
            # each lost row goes to the good row before it (in this packet, or the last one so far)
            before = np.searchsorted(keep, np.flatnonzero(lost)) - 1
            t_lost = poses.t[lost]
            if self._kt.size and (before < 0).any():
                self._klost[-1] = int(t_lost[before < 0].max())
            np.maximum.at(last_lost, keep[before[before >= 0]], t_lost[before >= 0])
            last_lost = last_lost[keep]
            poses = poses.take(keep)  # type: ignore[assignment]
            if not len(poses):
                return
        t = poses.t
        pos = np.asarray(poses.position, np.float64)
        q = np.asarray(poses.orientation, np.float64)
        bad = np.flatnonzero(~np.isfinite(pos).all(axis=1) | ~np.isfinite(q).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"map.emvs: pose at t={int(t[i])} µs (port 'poses') is not finite: position "
                             f"{pos[i].tolist()}, orientation {q[i].tolist()}")
        norm = np.linalg.norm(q, axis=1)
        off = np.flatnonzero(np.abs(norm - 1.0) > QUAT_TOL)
        if off.size:
            i = int(off[0])
            raise ValueError(f"map.emvs: pose at t={int(t[i])} µs (port 'poses') has an orientation of norm "
                             f"{norm[i]:.6g}, not a unit quaternion (x, y, z, w)")
        prev = int(self._kt[-1]) if self._kt.size else None
        if prev is not None and int(t[0]) < prev:
            raise ValueError(f"map.emvs: poses go back in time on port 'poses': {int(t[0])} µs after {prev} µs")
        if self._first_pose is None:  # the first pose: events before it have none
            self._first_pose = int(t[0])
            self._drop_before(self._first_pose)
        self._kt = np.concatenate([self._kt, t])
        self._kp = np.concatenate([self._kp, pos])
        self._kq = np.concatenate([self._kq, q / norm[:, None]])
        self._klost = np.concatenate([self._klost, last_lost])

    def _add_events(self, ev: EventPacket) -> None:
        if self._sensor is None:
            self._start(ev.sensor)
        elif ev.sensor != self._sensor:
            raise ValueError(f"map.emvs: the sensor changed from {self._sensor} to {ev.sensor}")
        self._events_seen += len(ev)
        self._t = np.concatenate([self._t, ev.t])
        self._x = np.concatenate([self._x, ev.x])
        self._y = np.concatenate([self._y, ev.y])
        if self._first_pose is not None:
            self._drop_before(self._first_pose)

    def _start(self, sensor: tuple[int, int]) -> None:
        w, h = sensor
        size = self.camera.size
        if size is not None and tuple(size) != (w, h):
            raise ValueError(f"map.emvs: the calibration is for {size[0]}x{size[1]} px, the events for {w}x{h}")
        self._sensor = (w, h)
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        xy = self.camera.back_project(np.stack([u.ravel(), v.ravel()], axis=1), 1.0)[:, :2]
        self._rays = np.ascontiguousarray(xy.reshape(h, w, 2))

    def _drop_before(self, t0: int) -> None:
        n = int(np.searchsorted(self._t, t0, side="left"))
        if n:
            self.counts["skipped_before_poses"] += n
            self._t, self._x, self._y = self._t[n:], self._x[n:], self._y[n:]

    # -- segments -----------------------------------------------------------------
    def _segments(self, final: bool) -> list[tuple[int, int]]:
        """The closed segments of the waiting events, as index ranges: full
        (``segment_events``), or ended by time (an event, or the events'
        watermark, ``segment_us`` after its first); at the end, all."""
        t, n, out, a = self._t, len(self._t), [], 0
        while a < n:
            b = min(a + self.segment_events, int(np.searchsorted(t, t[a] + self.segment_us, side="left")))
            if b >= n and a + self.segment_events > n and not final and self._mark < t[a] + self.segment_us:
                break  # open: more events may join it
            out.append((a, min(b, n)))
            a = out[-1][1]
        return out

    def _advance(self, final: bool) -> list[Packet]:
        """Vote every closed segment whose pose can be interpolated, skip
        those in a gap of lost poses; emit the maps whose reference view the
        camera has left or a gap ended."""
        segs = self._segments(final) if self._kt.size else []
        t = self._t
        mids = np.array([(int(t[a]) + int(t[b - 1])) // 2 for a, b in segs], np.int64)
        ready = int(np.searchsorted(mids, int(self._kt[-1]), side="right")) if segs else 0
        gap = self._gaps()
        if segs and gap[-1]:  # lost rows for gap_us after the last pose: a gap up to the last of them
            ready = int(np.searchsorted(mids, int(self._klost[-1]), side="right"))
        if final and self._t.size:  # what no pose covers now never will be
            key = "skipped_after_poses" if self._kt.size else "skipped_before_poses"
            self.counts[key] += int(len(t) - (segs[ready][0] if ready < len(segs) else len(t)))
        if not ready:
            if final:
                self._t, self._x, self._y = self._t[:0], self._x[:0], self._y[:0]
            return []
        segs, mids = segs[:ready], mids[:ready]
        # the pose before each segment's middle, and whether the segment lies in a gap after it
        knot = np.searchsorted(self._kt, mids, side="right") - 1
        in_gap = gap[knot] & (mids > self._kt[knot])
        # a reference view starts at its first segment's first event, or at the pose that ends a gap
        starts = np.array([a for a, _ in segs], np.int64)
        ends_gap = (knot > 0) & gap[np.maximum(knot - 1, 0)]
        t_ref = np.where(ends_gap, np.maximum(t[starts], self._kt[knot]), t[starts])
        pos, q, _ = interpolate_poses(np.concatenate([mids, t_ref]), self._kt, self._kp, self._kq)
        n = len(segs)
        for v in self._views:  # each view votes from its run's first segment (here: all of them)
            v.run = 0
        out: list[Packet] = []
        for s in range(n):
            if in_gap[s]:  # every view in progress ends
                out += self._end_views(self._views, segs[:s], pos[:s], q[:s])
                self._views = []
                self.counts["skipped_lost_poses"] += segs[s][1] - segs[s][0]
                continue
            if not self._views:
                self._views.append(self._new_view(q[n + s], pos[n + s], int(t_ref[s]), s))
            reach = self.keyframe_baseline * self.scene_depth
            left = []  # the views the camera has left
            for v in self._views:
                b = float(np.linalg.norm(pos[s] - v.t_wr))
                if b > reach and (s > v.run or v.voted):
                    left.append(v)
                else:
                    v.baseline = max(v.baseline, b)
                    if v.baseline > reach * (v.shown + 1) / self.interim and (s > v.run or v.voted):
                        self._vote(v, segs[v.run:s], pos[v.run:s], q[v.run:s])  # an interim map, view goes on
                        v.run = s
                        out += self._finalize(v, interim=True)
                        v.shown = int(v.baseline * self.interim / reach)
            if left:
                out += self._end_views(left, segs[:s], pos[:s], q[:s])
                self._views = [v for v in self._views if all(v is not w for w in left)]
            newest = self._views[-1] if self._views else None
            if newest is None or (float(np.linalg.norm(pos[s] - newest.t_wr)) > reach / self.overlap
                                  and (s > newest.run or newest.voted)):
                self._views.append(self._new_view(q[n + s], pos[n + s], int(t[starts[s]]), s))
        for v in self._views:
            self._vote(v, segs[v.run:], pos[v.run:], q[v.run:])
        end = len(t) if final else segs[-1][1]
        self._t, self._x, self._y = self._t[end:], self._x[end:], self._y[end:]
        self._drop_knots(int(self._t[0]) if self._t.size else int(self._kt[-1]))
        return out

    def _gaps(self) -> np.ndarray:
        """Per pose: whether a gap follows it (lost rows, and the next good
        pose ``gap_us`` or more later; without a next pose yet, lost rows
        ``gap_us`` or more after it)."""
        lost = self._klost >= 0
        span = np.empty(len(self._kt), np.int64)
        span[:-1] = np.diff(self._kt)
        if len(span):
            span[-1] = self._klost[-1] - self._kt[-1]
        return lost & (span >= self.gap_us)

    def _new_view(self, q: np.ndarray, p: np.ndarray, t_ref: int, run: int) -> _View:
        """A reference view at orientation ``q`` (x, y, z, w) and position
        ``p`` (m), time ``t_ref`` µs, voted into from segment ``run`` of
        the segments being voted."""
        assert self._sensor is not None
        w, h = self._sensor
        return _View(np.asarray(quat_to_rot(q)), p.copy(), t_ref, np.zeros((len(self.depths), h, w), np.float32),
                     run=run)

    def _end_views(self, views: list[_View], segs: list[tuple[int, int]], pos: np.ndarray,
                   q: np.ndarray) -> list[Packet]:
        """End ``views`` (oldest first) after they take their share of
        ``segs`` (and poses): the oldest with votes becomes a map; the
        others end with it and hold a subset of its events (they started
        later), so they are dropped (counted in ``superseded``)."""
        out: list[Packet] = []
        ended = False
        for v in views:
            self._vote(v, segs[v.run:], pos[v.run:], q[v.run:])
            if v.voted and ended:
                self.counts["superseded"] += 1
            elif v.voted:
                out += self._finalize(v)
                ended = True
        return out

    def _vote(self, view: _View, segs: list[tuple[int, int]], pos: np.ndarray, q: np.ndarray) -> None:
        """The events of ``segs`` (with their poses) vote into ``view``'s DSI."""
        if not segs:
            return
        R_wr, t_wr = view.R_wr, view.t_wr
        a, b = segs[0][0], segs[-1][1]
        R_re = np.einsum("ji,njk->nik", R_wr, np.asarray(quat_to_rot(q)))
        C = (pos - t_wr) @ R_wr  # rows: R_wr^T (t_we - t_wr), the event camera centres in the reference frame
        # planes in front of each segment's camera: Z_k > C_z (near to far)
        first = np.searchsorted(self.depths, C[:, 2], side="right").astype(np.int64)
        seg = np.repeat(np.arange(len(segs), dtype=np.int64), [e - s for s, e in segs])
        R_re, C = np.ascontiguousarray(R_re), np.ascontiguousarray(C)
        cam = self.camera
        trace = np.empty((4, b - a), np.float32)
        ok = ray_traces(self._x[a:b], self._y[a:b], seg, self._rays, R_re, C, cam.fx, cam.fy, cam.cx, cam.cy, trace)
        self.counts["outside_view"] += (b - a) - int(ok)
        # the votes wait until a block's worth of events is in (or the map is made): a pass over the
        # DSI brings each of its planes (100 x 173 kB at 240x180, more than the caches keep between
        # calls) back from memory, which cost 2-3 ms a call on 5 ms slices of 4,600 events (7.6 ns a
        # vote on the boxes' loop, against 2.8 in one big call); cells still get their votes in event
        # order, so the sums are the same
        view.pending.append((trace, first[seg]))
        view.n_pending += b - a
        if view.n_pending >= BLOCK:
            self._flush(view)
        view.last_t, view.voted = int(self._t[b - 1]), True

    def _flush(self, view: _View) -> None:
        """The votes ``view`` holds back go into its DSI (in blocks of
        :data:`~._dsi.BLOCK` events: the vote kernel's)."""
        if not view.pending:
            return
        trace = view.pending[0][0] if len(view.pending) == 1 else np.concatenate([p[0] for p in view.pending], axis=1)
        first = view.pending[0][1] if len(view.pending) == 1 else np.concatenate([p[1] for p in view.pending])
        view.pending, view.n_pending = [], 0
        vote(trace, first, self.rho, view.dsi)

    def _finalize(self, view: _View, interim: bool = False) -> list[Packet]:
        """``view``'s DSI as a map (and cloud), or nothing when the camera
        did not translate enough; an ``interim`` map leaves the scene depth
        as it is."""
        R_wr, t_wr, t_ref, t_map = view.R_wr, view.t_wr, view.t_ref, view.last_t
        if view.baseline < self.min_baseline * self.scene_depth:
            self.counts["no_translation"] += 1
            # said once a run (a tracker lost for a while ends a view every few ms: one line each
            # flooded the terminal); the rest are counted (the node's stats, `no_translation`)
            (log.warning if self.counts["no_translation"] == 1 else log.debug)(
                "map.emvs: the camera moved %.3g m from the reference view at %d µs, less than min_baseline x "
                "scene depth = %.3g m: too little translation for depth (pure rotation or standing still), no "
                "map%s", view.baseline, t_ref, self.min_baseline * self.scene_depth,
                " (further views without depth are counted: no_translation)"
                if self.counts["no_translation"] == 1 else "")
            return []
        self._flush(view)
        depth, conf = depth_map(view.dsi, self.depths, **self.map_options)  # type: ignore[arg-type]
        extra: dict[str, np.ndarray] = {}
        if self.surface != "free":
            depth, extra = self._surface(depth, R_wr, t_wr)
        known = np.isfinite(depth)
        if known.any() and not interim:
            self.scene_depth = float(np.median(depth[known]))
        self.counts["maps"] += 1
        pose = np.concatenate([t_wr, rot_to_quat(R_wr)])
        tt = np.array([t_map], np.int64)
        out: list[Packet] = [MapPacket(tt, depth=depth[None], confidence=conf[None], K=self.K[None],
                                       pose=pose[None], t_ref=np.array([t_ref], np.int64),
                                       baseline=np.array([view.baseline]), **extra, t_start=t_map,
                                       t_end=t_map + 1)]
        if self.points:
            out.append(self._cloud(depth, conf, R_wr, t_wr, t_map))
        return out

    def _surface(self, depth: np.ndarray, R_wr: np.ndarray,
                 t_wr: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """``depth`` with the plane's depth at its known pixels when
        ``surface`` is ``plane``, ``auto`` and the plane explains it, or
        ``world_plane`` (the world's plane once ``plane_maps`` maps made it,
        seen from the reference pose ``R_wr``, ``t_wr``); and the map's
        columns ``planar`` and ``plane``."""
        coef: np.ndarray | None = None
        if self.surface == "world_plane" and len(self.world_planes) >= self.plane_maps:
            n = np.mean([p[0] for p in self.world_planes], axis=0)
            coef = plane_in_view(n / np.linalg.norm(n), float(np.mean([p[1] for p in self.world_planes])),
                                 R_wr, t_wr)
        else:
            fit = fit_plane(depth, self.K)
            if fit is not None and (self.surface in ("plane", "world_plane")
                                    or explains(fit, self.plane_tol, self.plane_inliers)):
                coef = fit.coef
                if self.surface == "world_plane":
                    self.world_planes.append(plane_to_world(coef, R_wr, t_wr))
        planar = coef is not None
        if coef is None:
            coef = np.full(3, np.nan)
        else:
            flat = plane_depth(coef, self.K, depth.shape).astype(np.float32)
            depth = np.where(np.isfinite(depth), flat, np.float32(np.nan))
            self.counts["planar_maps"] += 1
        return depth, {"planar": np.array([int(planar)], np.int8), "plane": coef[None]}

    def _cloud(self, depth: np.ndarray, conf: np.ndarray, R_wr: np.ndarray, t_wr: np.ndarray,
               t_map: int) -> PointPacket:
        pw, v, u = depth_points(depth, self.K, R_wr, t_wr)
        return PointPacket(np.full(len(pw), t_map, np.int64), position=pw, intensity=conf[v, u],
                           t_start=t_map, t_end=t_map + 1)

    def _drop_knots(self, t_keep: int) -> None:
        """Forget poses no waiting event needs (keep the last at or before ``t_keep``)."""
        k = int(np.searchsorted(self._kt, t_keep, side="right")) - 1
        if k > 0:
            self._kt, self._kp, self._kq, self._klost = self._kt[k:], self._kp[k:], self._kq[k:], self._klost[k:]


def translating_points(duration_us: int, sensor: tuple[int, int], f: float, velocity: tuple[float, float, float] = (
        0.5, 0.0, 0.0), n_points: int = 40, depth: tuple[float, float] = (1.0, 3.0), rate_hz: float = 1000.0,
        period_us: int = 100, seed: int = 0) -> dict[str, Packet]:
    """Events of ``n_points`` world points (depths uniform in ``depth``, m)
    seen by a pinhole camera (focal ``f`` px, centred, no rotation) moving
    at ``velocity`` (m/s, world = camera axes) from the origin: one event per
    visible point every ``period_us``, at its rounded projection; and the
    poses at ``rate_hz``. For tests and the conformance check."""
    rng = np.random.default_rng(seed)
    w, h = sensor
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    Z = rng.uniform(depth[0], depth[1], n_points)
    X = (rng.uniform(0.1, 0.9, n_points) * w - cx) / f * Z
    Y = (rng.uniform(0.1, 0.9, n_points) * h - cy) / f * Z
    ts = np.arange(0, duration_us, period_us, dtype=np.int64)
    v = np.asarray(velocity, np.float64)
    t_all, x_all, y_all = [], [], []
    for t in ts:
        c = v * t * 1e-6
        Zc = Z - c[2]
        u = f * (X - c[0]) / Zc + cx
        vv = f * (Y - c[1]) / Zc + cy
        ok = (Zc > 0) & (u > -0.5) & (vv > -0.5) & (u < w - 0.5) & (vv < h - 0.5)
        t_all.append(np.full(int(ok.sum()), t))
        x_all.append(np.round(u[ok]))
        y_all.append(np.round(vv[ok]))
    t_ev = np.concatenate(t_all)
    ev = EventPacket.from_arrays(t_ev, np.concatenate(x_all), np.concatenate(y_all), np.ones(len(t_ev), np.int8),
                                 sensor=sensor, t_start=0, t_end=duration_us)
    tp = np.arange(0, duration_us + 1, int(1e6 / rate_hz), dtype=np.int64)
    poses = PosePacket(tp, position=np.outer(tp * 1e-6, v), orientation=np.tile([0, 0, 0, 1.0], (len(tp), 1)),
                       t_start=0, t_end=duration_us + 1)
    return {"events": ev, "poses": poses}
