"""``tracker.features``: corners found on frames, tracked by the events
between them (the DAVIS way: Gehrig et al., "EKLT", IJCV 2020; Kueng et
al., "Low-latency visual odometry using event-based feature tracks", IROS
2016).

Corners (Shi-Tomasi, or Harris with ``detector="harris"``: OpenCV's
``goodFeaturesToTrack``) are found on an image: the APS frames on port
``frames`` (a DAVIS recording, ``simulate:...?davis=true`` with a scene
that has frames, an ECD folder's ``images.txt``), or, for a sensor without
frames, the log-intensity maps of a reconstruction on port ``maps`` (e.g.
``map.high_pass``); frames win when both are connected. Each corner becomes
a feature with a template taken from that image, and the events then move
it (``method``):

* ``eklt`` (default): EKLT's generative alignment (:mod:`._eklt`): the
  patch of its latest events against the brightness increment the
  template predicts for a flow direction, normalised, by Gauss-Newton on
  the warp (translation, plus a rotation with ``rotation=true``) and the
  flow direction. ``quality`` is the patches' correlation (1 perfect).
* ``icp``: event-to-template ICP (:mod:`._icp`): the latest events onto
  the template's Canny edges, translation only. Cheaper, less precise.
  ``quality`` is the inlier fraction, discounted by the mean distance.

A feature aligns each time about ``update_fraction`` of its window of
events is new (:mod:`._feature_events`); each alignment is one row of the
output :class:`~tectum.TrackPacket` (``t`` µs: the event completing the
window; ``id``; ``x``, ``y`` px sub-pixel, origin top-left; ``quality``),
and a feature's first row is its detection at the image's time (quality 1).
A feature is dropped when its quality falls below ``min_quality``, an
alignment jumps by more than half a patch, or it leaves the image (closer
than half a template to the border); ``counts`` say how many went which
way. ``redetect=true`` looks for corners again on each new image, away from
the live features, up to ``max_tracks``; otherwise only the first image
gives features. Events before the first image are not tracked (counted
as ``events_before_image``).

The output depends only on the streams' contents: events are processed in
order, an image at time ``t`` is applied before the events at ``t`` and
later, whatever the packets.

Cost: per event a test against each live feature (50 comparisons with 50
features), per alignment about 10 Levenberg-Marquardt iterations over a
``patch_px``² patch (EKLT) or a brute-force nearest-neighbour ICP.
Memory per feature: the ring of ``max_events`` events (12 bytes each), the
template (two float64 images of ``(patch_px + 2 a)²``, ``a ≈ 0.21
patch_px + 2``) and the edge model (up to ``patch_px²`` points, 16 bytes).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Literal

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

from tectum import EventPacket, FramePacket, Kind, MapPacket, Operator, Packet, Port, TrackPacket
from tectum.plugins.map._integrate import log_frame

from ._eklt import event_target
from ._feature_events import (
    ALIVE,
    COLUMNS,
    EKLT,
    ICP,
    NE,
    OX,
    OY,
    P_C,
    P_H,
    P_MIN,
    P_ROT,
    P_W,
    PARAMS,
    PHI,
    STATS,
    TM,
    XR,
    YR,
    X,
    Y,
    track_events,
)

__all__ = ["FeatureTracker", "image_derivatives", "edge_image", "edge_model"]

_ROWS = 65_536  # output rows per kernel call
ICP_EVENTS_PER_POINT = 0.5  # ICP window: events per model point (measured best of 0.25-2 on the rotation scene)


def image_derivatives(log_image: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Derivatives of a log-intensity image smoothed by a Gaussian of
    ``sigma`` px (central differences, per px): (5, H, W) float64 gx, gy,
    gxx, gxy, gyy (x along columns, y down the rows)."""
    sm = gaussian_filter(np.asarray(log_image, np.float64), sigma, mode="nearest")
    gy, gx = np.gradient(sm)
    gxy, gxx = np.gradient(gx)
    gyy, _ = np.gradient(gy)
    return np.stack([gx, gy, gxx, gxy, gyy])


def edge_image(log_image: np.ndarray) -> np.ndarray:
    """Canny edges (uint8, 255 on an edge) of a log-intensity image smoothed
    by σ 1 px and stretched to 0..255; the hysteresis thresholds are the
    85th percentile of the Sobel magnitude and half of it."""
    sm = gaussian_filter(np.asarray(log_image, np.float64), 1.0, mode="nearest")
    lo, hi = float(sm.min()), float(sm.max())
    img8 = np.zeros(sm.shape, np.uint8) if hi <= lo else ((sm - lo) * (255.0 / (hi - lo))).astype(np.uint8)
    mag = np.hypot(cv2.Sobel(img8, cv2.CV_64F, 1, 0), cv2.Sobel(img8, cv2.CV_64F, 0, 1))
    top = float(np.percentile(mag, 85))
    return np.asarray(cv2.Canny(img8, 0.5 * top, top, L2gradient=True))


def edge_model(edges: np.ndarray, x: float, y: float, half: int) -> np.ndarray:
    """The edge pixels of ``edges`` (:func:`edge_image`) within ``half`` px
    (in x and y) of ``(x, y)``, as offsets (n, 2) px from it: the ICP template."""
    x0, x1 = max(int(math.floor(x - half)), 0), int(math.ceil(x + half)) + 1
    y0, y1 = max(int(math.floor(y - half)), 0), int(math.ceil(y + half)) + 1
    rows, cols = np.nonzero(edges[y0:y1, x0:x1])
    off = np.stack([cols + x0 - x, rows + y0 - y], axis=1).astype(np.float64)
    return off[(np.abs(off[:, 0]) <= half) & (np.abs(off[:, 1]) <= half)]


class FeatureTracker(Operator):
    """Corners detected on frames (or reconstructed maps), tracked by events (EKLT or ICP).

    Parameters
    ----------
    method:
        ``eklt`` (generative alignment, Gehrig et al. 2020) or ``icp``
        (event-to-edge ICP, Kueng et al. 2016).
    max_tracks:
        Features tracked at once (the detector asks for the free slots).
    detector:
        ``shi_tomasi`` or ``harris``.
    quality_level:
        Corners weaker than this fraction of the image's strongest are
        not taken (OpenCV's ``qualityLevel``).
    min_distance_px:
        Corners at least this far apart, px, and from the live features.
    patch_px:
        Side of a feature's patch, px (odd).
    redetect:
        Detect again on every new image to keep ``max_tracks`` features.
    rotation:
        EKLT: the warp has a rotation besides the translation.
    contrast:
        Contrast threshold of the sensor (log intensity) for the window
        size: a window holds the events a patch fires while moving ~1 px.
    min_events:
        Smallest window, events.
    max_events:
        Largest window, events (the ring each feature keeps).
    update_fraction:
        Align when this fraction of the window is new events (1: disjoint
        windows; smaller: more rows, more work).
    min_quality:
        Drop a feature whose quality falls below this (EKLT: correlation of
        the patches, default 0.3; ICP: discounted inlier fraction, default
        0.15).
    max_iterations:
        Iterations per alignment (LM for EKLT, ICP rounds).
    icp_max_dist_px:
        ICP: event-to-edge pairs farther than this are outliers, px.
    frame_offset:
        Added to a frame's intensity (1 = full scale) before the log.
    """

    name = "tracker.features"
    inputs = {
        "events": Port(Kind.EVENTS, doc="the events that move the features"),
        "frames": Port(Kind.FRAMES, required=False, doc="APS frames corners are found on"),
        "maps": Port(Kind.MAPS, required=False, doc="or log-intensity maps (map.high_pass) when there are no frames"),
    }
    produces = (Kind.TRACKS,)

    def __init__(self, method: Literal["eklt", "icp"] = "eklt", max_tracks: int = 50,
                 detector: Literal["shi_tomasi", "harris"] = "shi_tomasi", quality_level: float = 0.01,
                 min_distance_px: float = 10.0, patch_px: int = 25, redetect: bool = True, rotation: bool = False,
                 contrast: float = 0.2, min_events: int = 40, max_events: int = 600, update_fraction: float = 0.5,
                 min_quality: float | None = None, max_iterations: int = 10, icp_max_dist_px: float = 2.0,
                 frame_offset: float = 1.0 / 255) -> None:
        where = "tracker.features"
        if method not in ("eklt", "icp"):
            raise ValueError(f"{where}: method must be 'eklt' or 'icp', got {method!r}")
        if detector not in ("shi_tomasi", "harris"):
            raise ValueError(f"{where}: detector must be 'shi_tomasi' or 'harris', got {detector!r}")
        if max_tracks < 1:
            raise ValueError(f"{where}: max_tracks must be >= 1, got {max_tracks}")
        if patch_px < 5 or patch_px % 2 == 0:
            raise ValueError(f"{where}: patch_px must be odd and >= 5, got {patch_px}")
        if not 1 <= min_events <= max_events:
            raise ValueError(f"{where}: need 1 <= min_events <= max_events, got {min_events}, {max_events}")
        if not 0 < update_fraction <= 1:
            raise ValueError(f"{where}: update_fraction must be in (0, 1], got {update_fraction}")
        for label, v in (("quality_level", quality_level), ("contrast", contrast), ("min_distance_px", min_distance_px),
                         ("icp_max_dist_px", icp_max_dist_px), ("frame_offset", frame_offset)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{where}: {label} must be finite and > 0, got {v}")
        if max_iterations < 1:
            raise ValueError(f"{where}: max_iterations must be >= 1, got {max_iterations}")
        self.method, self.detector = method, detector
        self.max_tracks, self.redetect = int(max_tracks), bool(redetect)
        self.quality_level, self.min_distance = float(quality_level), float(min_distance_px)
        self.half = patch_px // 2
        self.margin = int(math.ceil(self.half * (math.sqrt(2.0) - 1.0))) + 2  # room for a rotated patch
        self.size = patch_px + 2 * self.margin  # template side, px
        self.frame_offset = float(frame_offset)
        self.prm = np.zeros(len(PARAMS))
        if min_quality is None:
            min_quality = 0.3 if method == "eklt" else 0.15
        self.prm[:] = [self.half, contrast, min_events, update_fraction, min_quality, 0, 0, float(rotation),
                       max_iterations, EKLT if method == "eklt" else ICP, icp_max_dist_px, self.half]
        T, S = self.max_tracks, self.size
        self.trk = np.zeros((T, len(COLUMNS)))
        self.ids = np.full(T, -1, np.int64)
        self.ring = np.zeros((T, int(max_events), 4), np.int64)  # x, y, p, t (µs) of each feature's latest events
        self.cnt = np.zeros((T, 3), np.int64)
        self.tg = np.zeros((T, 5, S, S))
        self.mdl = np.zeros((T, patch_px * patch_px, 2))
        self.nmdl = np.zeros(T, np.int64)
        self.stats = np.zeros(len(STATS), np.int64)
        self.sensor: tuple[int, int] | None = None  # (w, h) px
        self.next_id = 0
        self.images = 0
        self.counts = {"images": 0, "detected": 0, "updates": 0, "lost_residual": 0, "lost_border": 0,
                       "events_before_image": 0}

    #: For the conformance check: the default EKLT with a few small features.
    conformance_params = {"max_tracks": 8, "patch_px": 11, "min_distance_px": 4.0, "min_events": 10,
                          "max_events": 100}

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """A simulated DAVIS (48x36) turning over a texture: events and a
        frame every 10 ms, 40 ms (for the conformance check)."""
        from tectum.sources.simulate.feature_scenes import davis_rotation

        ev, frames, _ = davis_rotation((48, 36), 40_000, aps_rate_hz=100.0)
        return {"events": ev, "frames": frames}

    @classmethod
    def check_ports(cls, connected: frozenset[str]) -> str | None:
        if "frames" not in connected and "maps" not in connected:
            return ("no image to find corners on: connect the port 'frames' (APS frames: a DAVIS recording, "
                    "an ECD folder with images.txt, simulate:SCENE?davis=true for a scene whose davis section "
                    "has aps_rate_hz) or 'maps' (a reconstruction such as map.high_pass) besides 'events'")
        return None

    def warmup(self) -> None:
        """Compile the kernels on a twin fed a frame with one corner and events around it."""
        twin = FeatureTracker(method=self.method, max_tracks=2, patch_px=7, min_distance_px=3.0, min_events=4,
                              max_events=8, rotation=bool(self.prm[P_ROT]))
        img = np.zeros((1, 32, 32), np.uint8)
        img[0, 12:, 12:] = 200
        n = 64
        t = np.arange(1, n + 1, dtype=np.int64)
        xy = (10 + np.arange(n) % 5).astype(np.uint16)
        ev = EventPacket(t, xy, xy[::-1].copy(), np.ones(n, np.int8), sensor=(32, 32), t_start=0, t_end=n + 1)
        twin.process_ports({"events": ev, "frames": FramePacket([0], images=img, t_start=0, t_end=n + 1)})

    # -- input ------------------------------------------------------------------
    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        first = next(iter(ports.values()))
        got = ports.get("events")
        ev = got if isinstance(got, EventPacket) and len(got) else None
        images = self._images(ports)
        rows: list[tuple[np.ndarray, ...]] = []
        a = 0
        if ev is not None:
            self._check_sensor(ev.sensor, "events")
        for t_img, img in images:  # an image applies to the events at its time and later
            if ev is not None:
                b = int(np.searchsorted(ev.t, t_img, side="left"))
                rows += self._events(ev, a, b)
                a = b
            rows.append(self._detect(t_img, img))
        if ev is not None:
            rows += self._events(ev, a, len(ev))
        t = np.concatenate([r[0] for r in rows]) if rows else np.empty(0, np.int64)
        ids = np.concatenate([r[1] for r in rows]) if rows else np.empty(0, np.int64)
        v = np.concatenate([r[2] for r in rows]) if rows else np.empty((0, 3))
        return [TrackPacket(t, id=ids, x=v[:, 0], y=v[:, 1], quality=v[:, 2], t_start=first.t_start,
                            t_end=first.t_end)]

    def _images(self, ports: Mapping[str, Packet]) -> list[tuple[int, np.ndarray]]:
        """The batch's images as (t µs, log intensity (H, W) float32)."""
        fr = ports.get("frames")
        if fr is not None:
            assert isinstance(fr, FramePacket)
            return [(int(fr.t[k]), log_frame(fr.images[k], self.frame_offset)) for k in range(len(fr))]
        mp = ports.get("maps")
        if mp is None or not len(mp):
            return []
        assert isinstance(mp, MapPacket)
        if "image" not in mp.data:
            raise ValueError(f"{self.name}: the maps on port 'maps' have no 'image' (log intensity) to find corners "
                             f"on (fields: {sorted(mp.data)}); connect a reconstruction such as map.high_pass")
        return [(int(mp.t[k]), np.asarray(mp.image[k], np.float32)) for k in range(len(mp))]

    def _check_sensor(self, size: tuple[int, int], what: str) -> None:
        if self.sensor is None:
            self.sensor = (int(size[0]), int(size[1]))
            self.prm[P_W], self.prm[P_H] = self.sensor
        elif tuple(size) != self.sensor:
            raise ValueError(f"{self.name}: {what} of {size[0]}x{size[1]} px after {self.sensor[0]}x{self.sensor[1]}")

    def _events(self, ev: EventPacket, a: int, b: int) -> list[tuple[np.ndarray, ...]]:
        if b <= a:
            return []
        if not self.images:
            self.counts["events_before_image"] += b - a
            return []
        return [self._track(ev.t[a:b], ev.x[a:b], ev.y[a:b], ev.p[a:b])]

    def _track(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, ...]:
        """Feed events to the features: their rows (t, id, (x, y, quality))."""
        parts_i, parts_v = [], []
        start = 0
        before = self.stats.copy()
        while True:
            out_i = np.empty((_ROWS, 2), np.int64)
            out_v = np.empty((_ROWS, 3))
            n, start = track_events(t, x, y, p, start, self.trk, self.ids, self.ring, self.cnt, self.tg, self.mdl,
                                    self.nmdl, self.prm, self.stats, out_i, out_v)
            parts_i.append(out_i[:n])
            parts_v.append(out_v[:n])
            if start >= len(t):
                break
        for k, name in enumerate(STATS):
            self.counts[name] += int(self.stats[k] - before[k])
        ti = np.concatenate(parts_i)
        return ti[:, 0].copy(), ti[:, 1].copy(), np.concatenate(parts_v)

    # -- detection ------------------------------------------------------------------
    def _detect(self, t: int, log_img: np.ndarray) -> tuple[np.ndarray, ...]:
        """Corners on a new image become features (in the free slots); their rows."""
        h, w = log_img.shape
        self._check_sensor((w, h), "an image")
        self.images += 1
        self.counts["images"] += 1
        empty = (np.empty(0, np.int64), np.empty(0, np.int64), np.empty((0, 3)))
        free = np.flatnonzero(self.trk[:, ALIVE] == 0)
        if (self.images > 1 and not self.redetect) or not free.size:
            return empty
        b = self.size // 2 + 1  # the template inside the image
        if w <= 2 * b or h <= 2 * b:
            return empty
        mask = np.zeros((h, w), np.uint8)
        mask[b:h - b, b:w - b] = 255
        for k in np.flatnonzero(self.trk[:, ALIVE] > 0):
            centre = (int(round(self.trk[k, X])), int(round(self.trk[k, Y])))
            cv2.circle(mask, centre, int(math.ceil(self.min_distance)), 0, -1)
        found = cv2.goodFeaturesToTrack(np.ascontiguousarray(log_img, np.float32), maxCorners=int(free.size),
                                        qualityLevel=self.quality_level, minDistance=self.min_distance, mask=mask,
                                        blockSize=5, useHarrisDetector=self.detector == "harris", k=0.04)
        if found is None or not len(found):
            return empty
        corners = found.reshape(-1, 2).astype(np.float64)
        der = image_derivatives(log_img)
        edges = edge_image(log_img) if self.method == "icp" else None
        S, a = self.size, self.margin
        c = self.prm[P_C]
        for k, (cx, cy) in zip(free, corners):
            ox, oy = int(round(cx)) - S // 2, int(round(cy)) - S // 2
            self.trk[k] = 0.0
            self.trk[k, [X, Y, XR, YR, OX, OY]] = cx, cy, cx, cy, ox, oy
            self.tg[k] = der[:, oy:oy + S, ox:ox + S]
            n_e = event_target(self.tg[k, 0, a:S - a, a:S - a], self.tg[k, 1, a:S - a, a:S - a], math.nan, c)
            self.trk[k, [PHI, TM, ALIVE]] = math.nan, t, 1.0
            self.trk[k, NE] = min(max(n_e, self.prm[P_MIN]), self.ring.shape[1])
            if edges is not None:
                m = edge_model(edges, cx, cy, self.half)[: self.mdl.shape[1]]
                self.mdl[k, :len(m)], self.nmdl[k] = m, len(m)
                self.trk[k, NE] = min(max(len(m) * ICP_EVENTS_PER_POINT, self.prm[P_MIN]), self.ring.shape[1])
            self.cnt[k] = 0
            self.ids[k] = self.next_id
            self.next_id += 1
        n = len(corners)
        self.counts["detected"] += n
        took = free[:n]
        v = np.stack([self.trk[took, X], self.trk[took, Y], np.ones(n)], axis=1)
        return np.full(n, t, np.int64), self.ids[took].copy(), v
