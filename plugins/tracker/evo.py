"""``tracker.evo``: EVO, tracking and mapping in parallel (Rebecq et al.,
RA-L 2017), as a pipeline macro.

One name for two nodes and their two-way wiring (see ``tectum run
--explain``):

* ``<id>.tracker``: ``tracker.edge_align`` aligns event images to the
  latest semi-dense map; its ``maps`` port reads the mapper's maps
  ``delay_us`` late (the loop's delayed edge), its ``poses`` port the
  source's poses when there are any (the bootstrap, ``bootstrap_us``),
  its ``imu`` port the source's IMU (its gyro turns the camera between
  steps with ``gyro_rad`` > 0);
* ``<id>.mapper``: ``map.emvs`` builds those maps from the events and the
  tracker's poses (rows the tracker flags lost are not used; lost for 20 ms
  or more, they end the map in progress, which goes to the tracker at once,
  and a new reference view starts when tracking is back).

With ``tracker="pose_6dof"`` (intensity frames at hand: a DAVIS's APS
frames on the ``frames`` port) the tracker is photometric, and a third node
closes the loop:

* ``<id>.tracker``: ``tracker.pose_6dof`` tracks against photometric maps
  (``maps`` port, ``delay_us`` late); it hands on the source's poses for
  ``bootstrap_us`` (needed: the first maps are made from them) and tracks
  from the bootstrap's end;
* ``<id>.mapper``: ``map.emvs`` as above, from the tracker's poses;
* ``<id>.photo``: ``map.photometric`` makes each EMVS map a photometric map:
  the last frame exposed before it (its log intensity) with the map's depth
  seen from the frame's pose (the tracker's, interpolated).

The node ``<id>`` hands on the tracker's and the mapper's outputs: poses
(``--sink traj.tum``) and maps with their point clouds (``--sink maps.npz``).
"""

from __future__ import annotations

from typing import Any

from tectum import Expansion, Kind, Macro, Port
from tectum.errors import PipelineError

__all__ = ["Evo"]

#: parameters handed to ``tracker.edge_align``, ``tracker.pose_6dof``, ``map.photometric`` and ``map.emvs``
_TRACKER = ("bootstrap_us", "plane_depth", "window_events", "step_events", "gyro_rad", "gyro_bias", "imu_rotation",
            "imu_time_offset_us")
_POSE_6DOF = ("bootstrap_us", "batch_events", "contrast")
_PHOTO = ("gain", "median_px")
_MAPPER = ("planes", "min_depth", "max_depth", "keyframe_baseline", "min_baseline", "overlap", "interim",
           "segment_us", "surface", "focus", "plane_maps")


class Evo(Macro):
    """EVO: ``tracker.edge_align`` and ``map.emvs`` in a loop, bootstrapped
    from the source's first poses (or a plane); or ``tracker.pose_6dof``,
    ``map.emvs`` and ``map.photometric`` with intensity frames. Expands into
    ``<id>.tracker``, ``<id>.mapper`` (and ``<id>.photo``; see the module).
    Each parameter but ``tracker``, ``calib`` and ``delay_us`` goes to one
    part; one not given keeps that operator's own default (see
    ``tracker.edge_align``, ``tracker.pose_6dof``, ``map.photometric``,
    ``map.emvs``).

    Parameters
    ----------
    tracker:
        ``edge_align`` (edge-map alignment, events alone) or ``pose_6dof``
        (photometric, against maps with the ``frames`` port's images).
    calib:
        Calibration for both nodes (file or inline ``fx;fy;cx;cy[;...]``,
        px); defaults to the calibration beside the recording.
    delay_us:
        Delay of the maps on their way back to the tracker, µs: a map made
        by time ``t`` is used from ``t + delay_us``. At least the mapper's
        lag: ``segment_us`` and the tracker's pose spacing.
    bootstrap_us:
        Tracker: output the source's poses (port ``poses``) for this long
        from the first one, µs (needed with ``pose_6dof``).
    plane_depth:
        Tracker: without bootstrap poses, the first window's edges as a plane
        this far in front of the camera, m (0: off).
    window_events:
        Tracker: events per event image.
    step_events:
        Tracker: events between poses.
    gyro_rad:
        Tracker ``edge_align``: σ of the rotation about the gyro's (port
        ``imu``) per step, rad; 0 (the default): no gyro.
    gyro_bias:
        Tracker ``edge_align``: the gyro's bias, rad/s (camera frame); empty:
        measured over the bootstrap.
    imu_rotation:
        Tracker ``edge_align``: camera-from-IMU rotation (3 numbers, rad, or 9).
    imu_time_offset_us:
        Tracker ``edge_align``: camera time minus IMU time, µs.
    batch_events:
        Tracker ``pose_6dof``: events per pose.
    contrast:
        Tracker ``pose_6dof``: the events' contrast threshold (log intensity).
    gain:
        ``map.photometric``: frame value (DN) of unit intensity.
    median_px:
        ``map.photometric``: radius of the inverse-depth median, px.
    planes:
        Mapper: depth planes of the DSI.
    min_depth:
        Mapper: nearest plane, m.
    max_depth:
        Mapper: farthest plane, m.
    keyframe_baseline:
        Mapper: a new reference view when the camera has moved this fraction
        of the scene depth.
    min_baseline:
        Mapper: a view whose camera moved less than this fraction of the
        scene depth gives no map.
    overlap:
        Mapper: reference views in progress at once (a map every
        ``keyframe_baseline / overlap`` of the scene depth, each over
        ``keyframe_baseline``).
    interim:
        Mapper: maps per reference view (its DSI so far after each
        ``keyframe_baseline / interim``).
    segment_us:
        Mapper: longest time a segment of events sharing one pose spans, µs.
    surface:
        Mapper: ``free`` (each pixel its own depth), ``plane`` (each map's
        pixels at the depth of the plane fitted to them), ``auto`` (the
        plane where it explains the map) or ``world_plane`` (one plane in
        the world, made by the first ``plane_maps`` maps).
    plane_maps:
        Mapper, ``world_plane``: the maps whose planes make the world's.
    focus:
        Mapper: 0 (a pixel's depth at its most-voted plane) or the radius, px,
        of the window whose sharpest plane is its depth (depth from focus).
    """

    name = "tracker.evo"
    inputs = {
        "events": Port(Kind.EVENTS, doc="the events (both nodes)"),
        "poses": Port(Kind.POSES, required=False, doc="bootstrap poses for the tracker (e.g. ground truth)"),
        "frames": Port(Kind.FRAMES, required=False, doc="intensity frames (tracker=pose_6dof's maps' images)"),
        "imu": Port(Kind.IMU, required=False, doc="the gyro for tracker=edge_align with gyro_rad > 0"),
    }

    def __init__(self, calib: str = "", delay_us: int = 20_000, bootstrap_us: int | None = None,
                 plane_depth: float | None = None, window_events: int | None = None, step_events: int | None = None,
                 planes: int | None = None, min_depth: float | None = None, max_depth: float | None = None,
                 keyframe_baseline: float | None = None, min_baseline: float | None = None,
                 overlap: int | None = None, interim: int | None = None, segment_us: int | None = None,
                 surface: str | None = None, focus: int | None = None, plane_maps: int | None = None,
                 tracker: str = "edge_align", batch_events: int | None = None, contrast: float | None = None,
                 gain: float | None = None, median_px: int | None = None, gyro_rad: float | None = None,
                 gyro_bias: tuple[float, ...] | None = None, imu_rotation: tuple[float, ...] | None = None,
                 imu_time_offset_us: int | None = None) -> None:
        if delay_us < 1:
            raise ValueError(f"tracker.evo: delay_us must be >= 1 µs, got {delay_us}")
        if tracker not in ("edge_align", "pose_6dof"):
            raise ValueError(f"tracker.evo: tracker must be edge_align or pose_6dof, got {tracker!r}")
        self.calib, self.delay_us, self.kind = calib, int(delay_us), tracker
        # only what was given goes to the parts: the rest keeps each operator's own default
        given = {k: v for k, v in locals().items()
                 if k not in ("self", "calib", "delay_us", "tracker") and v is not None}
        # the tracker's own parameters, and map.photometric's
        parts, photo = (_TRACKER, ()) if tracker == "edge_align" else (_POSE_6DOF, _PHOTO)
        own = parts + photo
        wrong = sorted(k for k in given if k not in own + _MAPPER)
        if wrong:
            raise ValueError(f"tracker.evo: {', '.join(wrong)} not for tracker={tracker} (its tracker's: "
                             f"{', '.join(own)})")
        if tracker == "pose_6dof" and not given.get("bootstrap_us"):
            raise ValueError("tracker.evo: tracker=pose_6dof needs bootstrap_us > 0 µs of the source's poses (port "
                             "poses): the first maps are made from them")
        self.tracker: dict[str, Any] = {k: given[k] for k in parts if k in given}
        self.photo: dict[str, Any] = {k: given[k] for k in photo if k in given}
        self.mapper: dict[str, Any] = {k: given[k] for k in _MAPPER if k in given}

    def expand(self, x: Expansion) -> None:
        calib: dict[str, Any] = {"calib": self.calib} if self.calib else {}
        if self.kind == "edge_align":
            x.op("tracker", "tracker.edge_align", events=x.port("events"), poses=x.port("poses"), imu=x.port("imu"),
                 maps=x.delayed("mapper", self.delay_us), **calib, **self.tracker)
        else:
            frames = x.port("frames")
            if frames is None:
                raise PipelineError("tracker.evo: tracker=pose_6dof needs intensity frames on port frames (e.g. a "
                                    "DAVIS recording's APS frames)")
            x.op("tracker", "tracker.pose_6dof", events=x.port("events"), poses=x.port("poses"),
                 maps=x.delayed("photo", self.delay_us), **calib, **self.tracker)
            x.op("photo", "map.photometric", maps=x.part("mapper"), frames=frames, poses=x.part("tracker"),
                 **self.photo)
        x.op("mapper", "map.emvs", events=x.port("events"), poses=x.part("tracker"), **calib, **self.mapper)
        x.output("tracker", "mapper")
