"""``tracker.led_markers``: active LED markers blinking at distinct
frequencies (Censi, Strubel, Brandli, Delbruck & Scaramuzza, IROS 2013,
"Low-latency localization by active LED markers tracking using a dynamic
vision sensor"), and the 6-DoF pose of the body carrying them.

Each pixel's transitions (the first event of a burst of one polarity, see
:mod:`._leds`) give one period of the light it sees, ON to ON or OFF to
OFF; ``1e6 / interval`` Hz is an observation of a frequency at that pixel.
An observation within ``tol`` (relative) of an LED's frequency, that is in
``f / (1 + tol) .. f (1 + tol)``, belongs to that LED; one near a rejected
frequency (``reject_hz``: 50 and 100 Hz, the flicker of lamps on 50 Hz mains;
add 60 and 120 for 60 Hz mains) is counted as flicker and dropped, as is
one in no band. Every ``update_us`` µs each LED's observations of the last
``window_us`` µs give its position: the per-axis median, then the mean of
the observations within ``blob_px`` of it (sub-pixel); an LED with fewer
than ``min_hits`` such observations is not seen at that time.

Output: a :class:`~tectum.TrackPacket` per update with a row per seen LED
(``id`` = the LED's id, ``x``, ``y`` px, ``quality`` = the observations its
position averages); with a ``layout=`` file (the LEDs' 3-D positions, see
:mod:`.layout`) and a calibration (``calib=``, or the ``calib.txt`` beside
the recording), a :class:`~tectum.PosePacket` per update where at least 4
LEDs are seen: ``cv2.solvePnP`` (SQPnP, refined by Levenberg-Marquardt) on
the undistorted positions, kept when the reprojection RMS is at most
``max_reproj_px`` (else counted, ``poses_rejected``). The pose is the camera
in the layout's frame (world = marker body, world-from-camera as every
tectum pose stream, so ``--sink pose.tum`` writes it as TUM).

Frequencies: a window must hold a few periods of the slowest LED (the
default 4 ms holds 4 at 1 kHz); a pixel gives observations only while the
LED stays on it for a whole period, so an LED of ``d`` px across blinking
at ``f`` Hz is seen up to about ``d f`` px/s; LEDs must differ by more than
the tolerance (``tol`` 0.1: bands of ±10 %, so 1000 Hz and 1250 Hz are
fine, 1000 and 1150 are not); a layout that breaks this is refused before
the run with the two frequencies named. The positions lag a moving LED by
about half the window (``v window_us / 2``).

Cost: per event a pixel update and, for transitions, a scan of the bands;
per update and LED a pass over its ring of ``ring`` observations. State:
3 int64 per pixel (2.2 MB at 346x260) and ``ring`` observations per LED.
"""

from __future__ import annotations

import math

import numpy as np

from tectum import EventPacket, Kind, Operator, Packet, PosePacket, TrackPacket

from ._leds import C_FLICKER, C_OBSERVED, C_UNMATCHED, led_kernel
from .layout import MarkerLayout, check_bands, read_layout

__all__ = ["LedMarkers", "solve_pose"]


def solve_pose(points: np.ndarray, pixels: np.ndarray, K: np.ndarray, D: np.ndarray,
               fisheye: bool = False) -> tuple[np.ndarray, np.ndarray, float] | None:
    """World-from-camera pose from >= 4 world points (n, 3) m and their
    pixels (n, 2): ``(position (3,) m, orientation (4,) xyzw, reprojection
    RMS px)``, or None when OpenCV finds none. Pixels are undistorted first
    (``D`` radtan coefficients, or equidistant with ``fisheye``)."""
    import cv2

    from tectum.camera import rot_to_quat

    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 1, 3)
    pix = np.ascontiguousarray(pixels, np.float64).reshape(-1, 1, 2)
    if len(D):
        und = cv2.fisheye.undistortPoints(pix, K, D) if fisheye else cv2.undistortPoints(pix, K, D)
        pix = (und.reshape(-1, 2) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]).reshape(-1, 1, 2)
    try:
        ok, rvec, tvec = cv2.solvePnP(pts, pix, K, None, flags=cv2.SOLVEPNP_SQPNP)
        if ok:
            rvec, tvec = cv2.solvePnPRefineLM(pts, pix, K, None, rvec, tvec)
    except cv2.error:
        return None
    if not ok or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        return None
    proj, _ = cv2.projectPoints(pts, rvec, tvec, K, None)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - pix.reshape(-1, 2)) ** 2, axis=1))))
    R_cw, _ = cv2.Rodrigues(rvec)
    R_wc = R_cw.T
    return -R_wc @ tvec.ravel(), rot_to_quat(R_wc), rms


class LedMarkers(Operator):
    """LED markers by blink frequency, and the pose of their body (see the module).

    Parameters
    ----------
    layout:
        Layout file: per LED its id, x y z (m) and frequency (Hz), see
        :mod:`tectum.plugins.tracker.layout`; gives the pose stream.
    freqs:
        Without a layout: the LEDs' frequencies, Hz (``"700;950;1200"``; ids 1, 2, ...).
    calib:
        Calibration for the pose (UZH calib.txt, OpenCV YAML/JSON, ROS
        camera_info, or inline ``fx;fy;cx;cy[;k1;k2;p1;p2;k3]``); defaults to
        the calibration beside the recording; needed with a layout.
    tol:
        Relative half width of each LED's frequency band.
    reject_hz:
        Frequencies (Hz) of lights that are not markers (mains flicker), rejected within ``tol``.
    update_us:
        Output every this many µs.
    window_us:
        Observations of the last this many µs give a position.
    blob_px:
        Observations farther than this (L-inf, px) from the median are left out.
    min_hits:
        Fewest observations a position averages.
    max_reproj_px:
        Poses with a larger reprojection RMS (px) are dropped (counted).
    ring:
        Observations kept per LED.
    """

    name = "tracker.led_markers"
    consumes = (Kind.EVENTS,)
    produces = (Kind.TRACKS, Kind.POSES)

    #: For the conformance check: four LEDs of :func:`_conformance_body`.
    conformance_params = {"freqs": (1000.0, 1400.0, 1900.0, 2600.0), "update_us": 500, "window_us": 3000}

    @staticmethod
    def conformance_stream() -> Packet:
        """Four blinking LEDs on a small sensor, with a moving edge and noise."""
        return _blinking_events(duration_us=30_000)

    def __init__(self, layout: str = "", freqs: tuple[float, ...] = (), calib: str = "", tol: float = 0.1,
                 reject_hz: tuple[float, ...] = (50.0, 100.0), update_us: int = 1000, window_us: int = 4000,
                 blob_px: float = 3.0, min_hits: int = 4, max_reproj_px: float = 3.0, ring: int = 1024) -> None:
        if not 0 < tol < 1 or update_us < 1 or window_us < 1 or not blob_px > 0 or min_hits < 1 or ring < 1:
            raise ValueError("need 0 < tol < 1, update_us >= 1, window_us >= 1, blob_px > 0, min_hits >= 1, ring >= 1")
        if not max_reproj_px > 0 or any(not (math.isfinite(f) and f > 0) for f in reject_hz):
            raise ValueError("need max_reproj_px > 0 and reject_hz frequencies > 0")
        self.layout: MarkerLayout | None = None
        if layout:
            if freqs:
                raise ValueError("tracker.led_markers: give layout= or freqs=, not both (the layout has the "
                                 "frequencies)")
            self.layout = read_layout(layout)
            ids, f = self.layout.ids, self.layout.freqs
        elif freqs:
            f = np.array([float(v) for v in (freqs.split(";") if isinstance(freqs, str) else freqs)])
            if not np.isfinite(f).all() or (f <= 0).any():
                raise ValueError(f"tracker.led_markers: freqs must be > 0 Hz, got {list(freqs)}")
            ids = np.arange(1, len(f) + 1, dtype=np.int64)
        else:
            raise ValueError("tracker.led_markers needs the LEDs' frequencies: layout= (a layout file, which also "
                             "gives the pose) or freqs= ('f1;f2;...' Hz)")
        check_bands(f, tol, reject_hz, self.layout.source if self.layout else "freqs")
        self.camera = None
        if self.layout is not None:
            if not calib:
                raise ValueError("tracker.led_markers with a layout needs the camera intrinsics for the pose: give "
                                 "calib= (a calibration file or inline 'fx;fy;cx;cy[;k1;k2;p1;p2;k3]' px), or put a "
                                 "calib.txt beside the recording")
            from tectum.camera import camera_from

            self.camera = camera_from(calib)
        self.ids = ids
        self.freqs = np.asarray(f, np.float64)
        # bands as interval limits, µs
        self.bands = np.stack([1e6 / (self.freqs * (1 + tol)), 1e6 * (1 + tol) / self.freqs], axis=1)
        rej = np.asarray(reject_hz, np.float64).reshape(-1)
        self.rejects = np.stack([1e6 / (rej * (1 + tol)), 1e6 * (1 + tol) / rej], axis=1)
        self.par = np.array([update_us, window_us, blob_px, min_hits], np.float64)
        self.max_reproj_px = float(max_reproj_px)
        M = len(f)
        self.ring_t = np.zeros((M, ring), np.int64)
        self.ring_xy = np.zeros((M, ring, 2))
        self.ring_n = np.zeros(M, np.int64)
        self._work = np.empty((ring, 2))
        self.meta = np.full(1, -1, np.int64)
        self._counts = np.zeros(3, np.int64)
        self.counts = {"observations": 0, "flicker": 0, "unmatched": 0, "poses": 0, "poses_rejected": 0,
                       "too_few_leds": 0}
        self._pix: np.ndarray | None = None
        self._mark: int | None = None  # start of the next track packet's interval, µs
        self._pose_mark: int | None = None  # the same for poses (updates without a pose give none)

    def warmup(self) -> None:
        twin = LedMarkers(**self.conformance_params)  # type: ignore[arg-type]
        stream = self.conformance_stream()
        assert isinstance(stream, EventPacket)
        twin.process(stream)
        if self.layout is not None:
            solve_pose(self.layout.points, self.layout.points[:, :2] * 100 + 50, np.array(
                [[100.0, 0, 50], [0, 100, 50], [0, 0, 1]]), np.zeros(0))

    def process(self, packet: EventPacket) -> list[Packet]:
        if self._mark is None:
            self._mark = packet.t_start
        if self._pix is None or self._pix.shape[:2] != (packet.sensor[1], packet.sensor[0]):
            self._pix = np.zeros((packet.sensor[1], packet.sensor[0], 3), np.int64)
            self._pix[:, :, 1:] = -1
        M = len(self.freqs)
        parts, i = [], 0
        while True:
            cap = max(64, 4 * M)
            otm, oq = np.empty((cap, 2), np.int64), np.empty((cap, 3))
            r, i, done = led_kernel(packet.t, packet.x, packet.y, packet.p, i, packet.t_end, self._pix, self.bands,
                                    self.rejects, self.ring_t, self.ring_xy, self.ring_n, self.meta, self.par,
                                    self._counts, self._work, otm, oq)
            if r:
                parts.append((otm[:r, 0], otm[:r, 1], oq[:r]))
            if done:
                break
        for name, k in (("observations", C_OBSERVED), ("flicker", C_FLICKER), ("unmatched", C_UNMATCHED)):
            self.counts[name] = int(self._counts[k])
        if not parts:
            return []
        ot, om, oq = (np.concatenate([q[j] for q in parts]) for j in range(3))
        mark, self._mark = self._mark, packet.t_end
        out: list[Packet] = [TrackPacket(ot, id=self.ids[om], x=oq[:, 0], y=oq[:, 1], quality=oq[:, 2],
                                         t_start=mark, t_end=packet.t_end)]
        if self.layout is not None:
            start = mark if self._pose_mark is None else self._pose_mark
            poses = self._poses(ot, om, oq[:, :2], start, packet.t_end)
            if poses is not None:
                out.append(poses)
                self._pose_mark = packet.t_end
            elif self._pose_mark is None:
                self._pose_mark = mark  # the pose stream's intervals start where the tracks' do
        return out

    def _poses(self, t: np.ndarray, m: np.ndarray, xy: np.ndarray, t0: int, t1: int) -> PosePacket | None:
        assert self.layout is not None and self.camera is not None
        cam = self.camera
        rows = []
        times, starts = np.unique(t, return_index=True)
        for T, a, b in zip(times, starts, list(starts[1:]) + [len(t)]):
            if b - a < 4:
                self.counts["too_few_leds"] += 1
                continue
            sol = solve_pose(self.layout.points[m[a:b]], xy[a:b], cam.K, cam.D, cam.model == "equidistant")
            if sol is None or sol[2] > self.max_reproj_px:
                self.counts["poses_rejected"] += 1
                continue
            self.counts["poses"] += 1
            rows.append((int(T), sol[0], sol[1]))
        if not rows:
            return None
        return PosePacket(np.array([r[0] for r in rows], np.int64), position=np.array([r[1] for r in rows]),
                          orientation=np.array([r[2] for r in rows]), t_start=t0, t_end=t1)


def _blinking_events(duration_us: int, sensor: tuple[int, int] = (32, 24), seed: int = 3) -> EventPacket:
    """Events of four LEDs (2x2 px, 1000/1400/1900/2600 Hz, a few µs of
    jitter) with a vertical edge sweeping across and uniform noise: a small
    stream that exercises every path of the operator."""
    rng = np.random.default_rng(seed)
    ts, xs, ys, ps = [], [], [], []
    for (cx, cy), hz in zip(((5, 5), (20, 5), (5, 16), (22, 18)), (1000.0, 1400.0, 1900.0, 2600.0)):
        period = 1e6 / hz
        k = np.arange(int(duration_us / period))
        for dx in (0, 1):
            for dy in (0, 1):
                for half, pol in ((0.0, 1), (0.5, -1)):
                    t = k * period + half * period + rng.integers(0, 6, len(k))
                    ts.append(t.astype(np.int64))
                    xs.append(np.full(len(k), cx + dx))
                    ys.append(np.full(len(k), cy + dy))
                    ps.append(np.full(len(k), pol))
    edge_t = np.arange(0, duration_us, 40)
    ts.append(edge_t)
    xs.append(edge_t * sensor[0] // duration_us)
    ys.append(rng.integers(0, sensor[1], len(edge_t)))
    ps.append(np.ones(len(edge_t), int))
    nt = rng.integers(0, duration_us, 300)
    ts.append(nt)
    xs.append(rng.integers(0, sensor[0], 300))
    ys.append(rng.integers(0, sensor[1], 300))
    ps.append(rng.choice([-1, 1], 300))
    t = np.concatenate(ts)
    order = np.argsort(t, kind="stable")
    x, y, p = (np.concatenate(a)[order] for a in (xs, ys, ps))
    return EventPacket(t[order], x.astype(np.uint16), y.astype(np.uint16), p.astype(np.int8), sensor=sensor, t_start=0,
                       t_end=duration_us)
