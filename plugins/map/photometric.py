"""``map.photometric``: photometric maps for ``tracker.pose_6dof`` from
depth maps (``map.emvs``) and intensity frames (DAVIS APS).

Each depth map on the ``maps`` port (``depth`` m with NaN unknown, ``K``,
``pose`` world-from-camera of its reference view) becomes one map with an
intensity image, seen from where a frame was taken:

* **the frame**: the last one on ``frames`` whose exposure ended at or
  before the map's time (``exposure_end`` when the frames have it, else the
  frame's own time), so the image is one the camera had when the map was
  made;
* **its pose**: the ``poses`` port's rows (rows flagged ``lost`` are not
  used) interpolated at the frame's time;
* **the depth** (:func:`reproject`): each known pixel back-projected from
  the map's reference view and projected into the frame's (the nearest
  surface kept per pixel), then each known pixel's inverse depth the median
  of the known ones within ``median_px`` (:func:`median_depth`);
* **the image** (:func:`log_image`): ``log(DN / gain + eps)`` (colour
  frames: the mean of the channels first).

Output: one :class:`~tectum.MapPacket` per map, at the map's time, with
``image``, ``depth``, ``K`` and ``pose`` (the frame's), as
``tracker.pose_6dof``'s ``maps`` port takes them.

A map waits until its frame and a good pose at or after the frame's time
have arrived (the ports' watermarks say when nothing earlier can come). It
is dropped, and counted in ``counts``, when no frame came before it
(``no_frame``), no good pose brackets the frame's time (``no_pose``: none
at or before it, or none within ``max_wait_us`` after it), fewer than
``min_pixels`` pixels keep a depth (``few_pixels``), or more than
``max_pending`` maps wait (``overflow``, the oldest).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from tectum import FramePacket, Kind, MapPacket, Operator, Packet, Port, PosePacket
from tectum.camera import depth_points, interpolate_poses, quat_to_rot

__all__ = ["Photometric", "reproject", "median_depth", "log_image", "frame_before"]


def reproject(depth: np.ndarray, K: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Depth (m, NaN unknown) seen from pose ``src`` (tx ty tz qx qy qz qw,
    world-from-camera) as depth seen from ``dst`` with the same intrinsics
    ``K`` (px): each known pixel (:func:`tectum.camera.depth_points`) to the
    nearest pixel, the nearest surface kept; NaN where nothing lands."""
    h, w = depth.shape
    Xw = depth_points(depth, K, quat_to_rot(src[3:]), src[:3])[0]
    Xd = (Xw - dst[:3]) @ np.asarray(quat_to_rot(dst[3:]))
    z = Xd[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uu = np.rint(K[0, 0] * Xd[:, 0] / z + K[0, 2])
        vv = np.rint(K[1, 1] * Xd[:, 1] / z + K[1, 2])
    ok = (z > 0) & (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
    out = np.full((h, w), np.inf)
    np.minimum.at(out, (vv[ok].astype(np.intp), uu[ok].astype(np.intp)), z[ok])
    out[~np.isfinite(out)] = np.nan
    return out


def median_depth(depth: np.ndarray, r: int) -> np.ndarray:
    """Each known pixel's depth (m) from the median inverse depth of the
    known pixels within ``r`` px (a square window); 0: unchanged."""
    if r <= 0:
        return depth
    h, w = depth.shape
    inv = np.pad(1.0 / depth, r, constant_values=np.nan)
    win = sliding_window_view(inv, (2 * r + 1, 2 * r + 1)).reshape(h, w, -1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmedian(win, axis=2)
    return np.where(np.isfinite(depth), 1.0 / m, np.nan)


def log_image(image: np.ndarray, gain: float, eps: float) -> np.ndarray:
    """``log(DN / gain + eps)`` of a frame (H, W) or (H, W, C) (the channels'
    mean), float64: the log intensity the events' contrast counts in."""
    a = np.asarray(image, np.float64)
    if a.ndim == 3:
        a = a.mean(axis=2)
    return np.log(a / gain + eps)


def frame_before(key: np.ndarray, t_us: int) -> int:
    """Index of the last frame whose ``key`` (exposure end, or time, µs,
    sorted) is at or before ``t_us``; -1 when none."""
    return int(np.searchsorted(key, t_us, side="right")) - 1


class Photometric(Operator):
    """Photometric maps (log-intensity image, depth, K, pose) from depth maps
    and intensity frames, for ``tracker.pose_6dof`` (see the module).

    Parameters
    ----------
    gain:
        Frame value (DN) of unit intensity: the image is ``log(DN / gain + eps)``
        (255 for 8-bit frames whose full scale is 1).
    eps:
        Offset inside the log, in units of intensity (the simulator's and
        the event model's ``eps``, 1e-3).
    median_px:
        Radius of the square window whose known pixels' median inverse depth
        each known pixel takes, px (0: none).
    min_pixels:
        Fewest pixels with depth for a map to go out.
    max_wait_us:
        How long after a frame's time, µs of pose time, a map waits for a
        good pose to interpolate the frame's pose from.
    max_pending:
        Most maps waiting at once (the oldest beyond it is dropped).
    """

    name = "map.photometric"
    inputs = {
        "maps": Port(Kind.MAPS, doc="depth maps (depth, K, pose), e.g. map.emvs's"),
        "frames": Port(Kind.FRAMES, doc="intensity frames (DN), e.g. DAVIS APS"),
        "poses": Port(Kind.POSES, doc="the camera's poses (world-from-camera; lost rows not used)"),
    }
    produces = (Kind.MAPS,)

    def __init__(self, gain: float = 255.0, eps: float = 1e-3, median_px: int = 4, min_pixels: int = 200,
                 max_wait_us: int = 200_000, max_pending: int = 16) -> None:
        where = "map.photometric"
        if not gain > 0 or not eps > 0:
            raise ValueError(f"{where}: need gain > 0 (DN per unit intensity) and eps > 0, got {gain}, {eps}")
        if median_px < 0 or min_pixels < 1:
            raise ValueError(f"{where}: need median_px >= 0 px and min_pixels >= 1, got {median_px}, {min_pixels}")
        if max_wait_us < 0 or max_pending < 1:
            raise ValueError(f"{where}: need max_wait_us >= 0 µs and max_pending >= 1, got {max_wait_us}, "
                             f"{max_pending}")
        self.gain, self.eps = float(gain), float(eps)
        self.median_px, self.min_pixels = int(median_px), int(min_pixels)
        self.max_wait_us, self.max_pending = int(max_wait_us), int(max_pending)
        self.counts = {"maps": 0, "out": 0, "no_frame": 0, "no_pose": 0, "few_pixels": 0, "overflow": 0}
        far = -(1 << 62)
        self._wm = {"maps": far, "frames": far, "poses": far}  # each port's watermark, µs
        # frames: time, key (exposure end or time), image
        self._ft = np.empty(0, np.int64)
        self._fk = np.empty(0, np.int64)
        self._fimg: list[np.ndarray] = []
        # good poses: time, position, orientation
        self._pt = np.empty(0, np.int64)
        self._pp = np.empty((0, 3))
        self._pq = np.empty((0, 4))
        # maps waiting: time, depth, K, pose
        self._wait: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """A 48x36 depth map (a plane 2 m away) every 10 ms from 20 ms, a
        frame every 8 ms, poses every 1 ms moving sideways (a few lost)."""
        h, w = 36, 48
        K = np.array([[40.0, 0.0, 23.5], [0.0, 40.0, 17.5], [0.0, 0.0, 1.0]])
        tm = np.arange(20_000, 100_000, 10_000, dtype=np.int64)
        depth = np.full((len(tm), h, w), np.nan)
        depth[:, 4:-4, 4:-4] = 2.0
        pose = np.zeros((len(tm), 7))
        pose[:, 0] = tm * 1e-6
        pose[:, 6] = 1.0
        maps = MapPacket(tm, depth=depth, K=np.repeat(K[None], len(tm), 0), pose=pose, t_start=0, t_end=100_000)
        tf = np.arange(4000, 100_000, 8000, dtype=np.int64)
        rng = np.random.default_rng(3)
        frames = FramePacket(tf, images=rng.integers(0, 256, (len(tf), h, w)).astype(np.uint8),
                             exposure_start=tf - 2000, exposure_end=tf + 2000, t_start=0, t_end=100_000)
        tp = np.arange(0, 100_000, 1000, dtype=np.int64)
        pos = np.stack([tp * 1e-6, np.zeros(len(tp)), 0.01 * np.sin(tp * 1e-4)], axis=1)
        q = np.tile([0.0, 0.0, 0.0, 1.0], (len(tp), 1))
        lost = (tp // 1000) % 17 == 5
        poses = PosePacket(tp, position=pos, orientation=q, lost=lost, t_start=0, t_end=100_000)
        return {"maps": maps, "frames": frames, "poses": poses}

    # -- input -------------------------------------------------------------------------
    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        fr = ports.get("frames")
        if fr is not None:
            assert isinstance(fr, FramePacket)
            if len(fr):
                key = fr.data["exposure_end"] if "exposure_end" in fr.data else fr.t
                self._ft = np.concatenate([self._ft, fr.t])
                self._fk = np.concatenate([self._fk, np.asarray(key, np.int64)])
                self._fimg += list(fr.data["images"])
            self._wm["frames"] = max(self._wm["frames"], fr.t_end)
        ps = ports.get("poses")
        if ps is not None:
            assert isinstance(ps, PosePacket)
            good = ~np.asarray(ps.data["lost"], bool) if "lost" in ps.data else np.ones(len(ps), bool)
            if good.any():
                pos, q = np.asarray(ps.position[good], np.float64), np.asarray(ps.orientation[good], np.float64)
                if not (np.isfinite(pos).all() and np.isfinite(q).all()):
                    raise ValueError("map.photometric: a pose on port 'poses' is not finite")
                self._pt = np.concatenate([self._pt, ps.t[good]])
                self._pp = np.concatenate([self._pp, pos])
                self._pq = np.concatenate([self._pq, q])
            self._wm["poses"] = max(self._wm["poses"], ps.t_end)
        mp = ports.get("maps")
        if mp is not None:
            assert isinstance(mp, MapPacket)
            if len(mp):
                missing = [c for c in ("depth", "K", "pose") if c not in mp.data]
                if missing:
                    raise ValueError(f"map.photometric: the maps on port 'maps' have no {', '.join(missing)} "
                                     "(need depth, K and pose: e.g. map.emvs's)")
                for i in range(len(mp)):
                    self.counts["maps"] += 1
                    self._wait.append((int(mp.t[i]), np.asarray(mp.data["depth"][i], np.float64),
                                       np.asarray(mp.data["K"][i], np.float64),
                                       np.asarray(mp.data["pose"][i], np.float64)))
                while len(self._wait) > self.max_pending:
                    self._wait.pop(0)
                    self.counts["overflow"] += 1
            self._wm["maps"] = max(self._wm["maps"], mp.t_end)
        return self._emit(final=False)

    def finish(self) -> list[Packet]:
        return self._emit(final=True)

    def output_mark(self, watermark: int) -> int:
        """On a loop: a map goes out at its own time, which a waiting map's
        lies before the input's watermark."""
        return min(self._wait[0][0], watermark) if self._wait else watermark

    # -- output ------------------------------------------------------------------------
    def _emit(self, final: bool) -> list[Packet]:
        out: list[Packet] = []
        while self._wait:
            t_map, depth, K, pose = self._wait[0]
            if not final and self._wm["frames"] <= t_map:
                break  # a frame at or before the map may still come
            j = frame_before(self._fk, t_map)
            if j < 0:
                self._drop("no_frame")
                continue
            tf = int(self._ft[j])
            if not len(self._pt) or self._pt[0] > tf:
                if final or self._wm["poses"] > tf:  # no good pose at or before the frame can come now
                    self._drop("no_pose")
                    continue
                break
            k = int(np.searchsorted(self._pt, tf, side="left"))
            if k == len(self._pt) or self._pt[k] > tf + self.max_wait_us:  # none within max_wait_us after it yet
                if final or self._wm["poses"] > tf + self.max_wait_us:
                    self._drop("no_pose")
                    continue
                break
            self._wait.pop(0)
            m = self._make(t_map, depth, K, pose, j, tf)
            if m is None:
                self.counts["few_pixels"] += 1
            else:
                self.counts["out"] += 1
                out.append(m)
        self._prune()
        return out

    def _drop(self, why: str) -> None:
        self._wait.pop(0)
        self.counts[why] += 1

    def _make(self, t_map: int, depth: np.ndarray, K: np.ndarray, pose: np.ndarray, j: int,
              tf: int) -> MapPacket | None:
        """The photometric map of one depth map with frame ``j`` at ``tf`` µs."""
        img = log_image(self._fimg[j], self.gain, self.eps)
        if img.shape != depth.shape:
            raise ValueError(f"map.photometric: the frames are {img.shape[1]}x{img.shape[0]} px, the maps "
                             f"{depth.shape[1]}x{depth.shape[0]} px: they must come from one sensor")
        p, q, _ = interpolate_poses(np.array([tf], np.int64), self._pt, self._pp, self._pq)
        p7 = np.concatenate([p[0], q[0]])
        dep = median_depth(reproject(depth, K, pose, p7), self.median_px)
        if int(np.isfinite(dep).sum()) < self.min_pixels:
            return None
        return MapPacket(np.array([t_map], np.int64), image=img[None], depth=dep[None], K=K[None], pose=p7[None],
                         t_start=t_map, t_end=t_map + 1)

    def _prune(self) -> None:
        """Forget the frames and poses no map to come can use: a later map's
        frame is the last one before the oldest waiting map (or the maps'
        watermark) or a later one, its pose from the last pose before it on."""
        t_next = self._wait[0][0] if self._wait else self._wm["maps"]
        j = frame_before(self._fk, t_next)
        if j > 0:
            self._ft, self._fk, self._fimg = self._ft[j:], self._fk[j:], self._fimg[j:]
        t_keep = int(self._ft[0]) if len(self._ft) else self._wm["frames"]  # no frame to come is earlier
        k = int(np.searchsorted(self._pt, t_keep, side="right")) - 1
        if k > 0:
            self._pt, self._pp, self._pq = self._pt[k:], self._pp[k:], self._pq[k:]
