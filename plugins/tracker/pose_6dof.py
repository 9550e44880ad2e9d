"""``tracker.pose_6dof``: the camera's 6-DoF pose from events against a
known photometric map, with the generative event model (Gallego et al.,
"Event-based, 6-DOF camera tracking from photometric depth maps", TPAMI
2018; Bryner et al., "Event-based, direct camera tracking from a
photometric 3D map using nonlinear optimization", ICRA 2019).

**Map.** ``map=FILE.npz`` (``image`` log intensity, ``depth`` m with NaN
unknown, ``K``, ``pose`` tx ty tz qx qy qz qw world-from-camera; see
:mod:`._photomap`; ``tectum simulate SCENE out.npz --map map.npz`` makes one
of a simulated scene), or the first map on the ``maps`` port (a
:class:`~tectum.MapPacket` with image, depth, K and pose; a later map
replaces it from the first batch whose last event is at or after the map's
time, so the choice does not depend on how the ports are packed; the
reference view the increments count from stays, now the tracker's own).
The map's size and intrinsics must be the sensor's (and the calibration's,
when ``calib=`` is given or found beside the recording: then the events are
undistorted onto the map's pinhole ``K``); a mismatch is an error before the
first pose.

**Start.** At the map's pose, unless ``init=tx;ty;tz;qx;qy;qz;qw`` gives
one, or the ``poses`` port does (the pose at the first event's time,
interpolated; later poses on the port are not used).

**Bootstrap** (``bootstrap_us`` > 0: a loop with a mapper, ``tracker.evo``
with ``tracker="pose_6dof"``). The ``poses`` port's rows from its first
for ``bootstrap_us`` are the output as they are (not lost, zero velocity,
``fit`` NaN), so a mapper can make the first maps from them; the events
until then only set the pixels' states, and tracking starts at the first
event at or after the bootstrap's end (and the first map), from the port's
pose there (interpolated), against the latest map made by then. Events that come
before the map (on the ``maps`` port) are not tracked, but they give each
pixel's state at the start (its last event and interval: its residue
there, which the increments count from) and say that the sensor was
running: no pixel then starts at its reference level, and a pixel's first
event counts one threshold (half crossed before the start, half after, on
average) rather than the one and a half of a sensor starting from rest (a
simulation from t = 0). Started 40 ms into a simulated slide without
them, the camera lags by 4-5 mm; with them, by about 1 mm.

**Tracking** (kernels and the model in :mod:`._generative`). The events are
cut into batches of ``batch_events`` (fewer when ``batch_us`` µs pass
first), by the events alone, so the output does not depend on how the
stream is packed. The events accumulate (``contrast`` × polarity, blurred
by σ, plus each pixel's change still below the threshold: with
``timed_residue`` estimated from the time since its last event and its
last interval between events, else half a threshold; with
``unseen_bound`` a pixel without an event yet counts as the model's change
for it, within the threshold its silence bounds; on a running sensor, whose
pixels' levels at the start are unknown, only ``unseen_running`` of it) into the
brightness increment since a reference view (the start, then the pose
where the image has moved ``keyframe_px`` from the last one, or
``map_view_px`` from the start when that is the map's own view); per
batch the pose at its last event is predicted at the velocity of the
last ``velocity_us``, then refined by Gauss-Newton on the robust
difference between that increment and the one the map predicts between
the reference pose and this one, coarse to fine over ``sigmas`` px. Counting
from a reference view rather than from the last batch keeps the pose tied
to the map: a batch's own increment (a tenth of a pixel of motion) says
little about where the camera is, the increment since the reference (up to
``keyframe_px``) a lot; a gap in the events or a burst of noise is bridged.

**Output.** One :class:`~tectum.PosePacket` row per batch, at its last
event: ``position`` m, ``orientation`` (x, y, z, w), ``linear_velocity``
(m/s, world), ``angular_velocity`` (rad/s, camera frame), ``lost``, and
``fit`` (the correlation of observed and predicted increments, 0..1).

**Lost.** A batch whose fit is below ``min_fit``, with fewer than
``min_points`` map points in view, or whose pose the events pin down
loosely (its 1σ uncertainty from the fit's covariance, as the angle the
scene may move by, past ``max_sd_deg``: a faint texture fits well but
says little; so does a relocalisation from a last good pose that was
itself loose; the motion since the reference is also bounded by
``drift_deg_s``: the first batches, a few milliseconds from the given
start, are kept on it; the reference pose's own σ adds to it, and passes
to the next reference only as far as the map's gradients stay alike over
the image's motion between them, :func:`gradient_correlation`, so a fast
camera's many references do not add up on a fine texture) is not
trusted: its row carries the last good pose (the prediction, zero
velocity) with ``lost`` true, never a confident guess. The next batches
try to relocalise from the last good pose with a wider blur (``sigmas``
with ``4 × sigmas[0]`` in front), the increments counting again from the
loss; tracking resumes when a fit reaches ``recover_fit`` and the uncertainty is within
bounds. ``counts`` holds ``batches``,
``lost``, ``relocalised``, ``skipped_before_map`` and ``references`` (the
reference views, the start's included).

Cost per batch: a Gaussian splat per event and level (a (6σ+1)² window),
then per iteration a projection, two bilinear samples and a 6x6 update per
map point (at most ``max_points``).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.fft import next_fast_len

from tectum import EventPacket, Kind, MapPacket, Operator, Packet, Port, PosePacket, concat
from tectum.camera import (
    Camera,
    camera_from,
    interpolate_poses,
    quat_to_rot,
    rot_to_quat_kernel,
    se3_exp_kernel,
    se3_log_kernel,
)

from ._generative import (
    blur_and_gradients,
    event_weights,
    fit_batch,
    point_corrections,
    reference_warp,
    residue_image,
    splat,
    splat_bilinear,
)
from ._photomap import PhotoMap, check_map, load_map, map_from_packet

__all__ = ["Pose6Dof"]

#: with a bootstrap, the poses port's rows kept this long past its end, µs: the start pose is theirs at the first
#: tracked event (interpolated)
_BOOT_KEEP_US = 20_000


def _quat(R: np.ndarray) -> np.ndarray:
    """The quaternion (x, y, z, w) of rotation ``R``, without
    :func:`~tectum.camera.rot_to_quat`'s checks (``R`` is the fit's own)."""
    q = np.empty(4)
    rot_to_quat_kernel(R, q)
    return q


def gradient_correlation(image: np.ndarray, depth: np.ndarray, sigma: float, max_px: int,
                         blurred: np.ndarray | None = None) -> np.ndarray:
    """How alike the map's log-intensity gradient stays under a shift: for
    each length ``0..max_px`` px, the mean over the whole-pixel shifts ``d``
    of that length (rounded) of ``∇L(x)·∇L(x + d)`` per pair of pixels with
    depth, its magnitude over the same at ``d = 0`` (1 there; near 0 past
    the texture's grain). ``image`` blurred by σ px (the tracker's finest
    level) first (``blurred``: that blur already made, :func:`blur_and_gradients`
    of ``image`` at σ).

    A reference pose's error moves a later pose's fit as far as the
    gradients the fit sees at the two views are alike: fully while the
    image is still where the reference saw it, not at all once it has
    moved past the grain (the map then pins each pose on its own)."""
    if blurred is None:
        out = np.empty((3, *image.shape))
        blur_and_gradients(image, sigma, out)
    else:
        out = blurred
    m = np.isfinite(depth).astype(np.float64)
    h, w = image.shape
    shape = (next_fast_len(h + max_px), next_fast_len(w + max_px))  # zero-padded: no wrap-around up to max_px

    def acf(a: np.ndarray) -> np.ndarray:
        f = np.fft.rfft2(a, shape)
        return np.fft.irfft2(f * np.conj(f), shape)

    g, n = acf(out[1] * m) + acf(out[2] * m), acf(m)  # n: the pairs with depth at each shift
    dy = np.fft.fftfreq(shape[0], 1.0 / shape[0])[:, None]
    dx = np.fft.fftfreq(shape[1], 1.0 / shape[1])[None, :]
    r = np.rint(np.hypot(dy, dx)).astype(np.int64)
    keep = (r <= max_px) & (n > 0.5)
    r, per = r[keep], g[keep] / n[keep]
    mean = np.bincount(r, per, max_px + 1) / np.maximum(np.bincount(r, None, max_px + 1), 1)
    rho = np.abs(mean) / max(float(mean[0]), 1e-300)
    return np.minimum(rho, 1.0)


class _Level:
    """The map at one blur: image and the points' values (σ px);
    ``blurred`` (3, H, W): :func:`blur_and_gradients` of the map's image at σ."""

    def __init__(self, blurred: np.ndarray, sigma: float, mx: np.ndarray, my: np.ndarray) -> None:
        self.sigma = sigma
        self.image = np.ascontiguousarray(blurred[0])
        self.Lm = np.ascontiguousarray(self.image[my, mx])


class Pose6Dof(Operator):
    """6-DoF camera pose from events against a known photometric map
    (generative event model).

    Parameters
    ----------
    map:
        Map file (``.npz``: image, depth, K, pose); or connect a ``maps`` port.
    init:
        Initial pose ``tx;ty;tz;qx;qy;qz;qw`` (m, quaternion, world-from-camera);
        default the ``poses`` port's, else the map's.
    calib:
        Calibration (file or ``fx;fy;cx;cy[;k1;k2;p1;p2;k3]``); when given
        (or found beside the recording) its intrinsics must be the map's,
        and the events are undistorted.
    contrast:
        Contrast threshold ``C`` (log intensity per event).
    batch_events:
        Events per pose update.
    batch_us:
        Longest time a batch spans, µs.
    sigmas:
        Blur of the coarse-to-fine levels, px (``2;1``: two levels).
    iterations:
        Gauss-Newton iterations per level.
    max_points:
        Map points used (the strongest-gradient pixels with depth, spread
        over the map).
    min_gradient:
        Smallest log-intensity gradient of a map point, per px.
    huber:
        Huber threshold in robust standard deviations of the residual.
    min_fit:
        Below this fit a batch is lost.
    recover_fit:
        Fit that ends a loss.
    max_sd_deg:
        Largest uncertainty of a trusted pose, deg: the 1σ angle by which
        the scene may move within the fit's covariance at the events' own
        noise (a threshold's, ``contrast / √12``; the position's σ over the
        mean depth of the points in view, with the rotation's σ).
        Measured: up to 0.07 on the simulated scenes of
        ``tectum bench pose`` after their first batches (0.16 at the first),
        0.08 at 1000 °/s (a new reference every 3 ms), 0.04 on
        ``slider_depth``, 0.14 with 20 Hz of shot noise; 0.25-0.78 on a
        faint texture (log-contrast 0.1) that is 6-35 mm off when trusted;
        0.2-0.3 in the first batches at log-contrast 0.25, kept by the
        start's certainty (``drift_deg_s``).
    drift_deg_s:
        How far the camera may have turned since the reference pose, deg/s
        of the time since it: the motion since the reference is known to
        ``1/σ² = 1/σ_fit² + 1/(drift Δt)²`` (the fit sees only the events
        since), the pose to that and the reference pose's own σ (the given
        start's: 0; a relocalisation's: the last good pose's; a new
        reference's: the old reference's times the map's
        :func:`gradient_correlation` at the image's motion between them,
        and the motion's) in quadrature, for ``max_sd_deg``. 20: a faint
        texture's first batch (20 ms) is not kept by it, a textured one's
        (5-12 ms) is.
    min_points:
        Fewest map points in view for a trusted pose.
    keyframe_px:
        A new reference view when the image has moved this far (median over
        the map points in view) from one, px.
    map_view_px:
        The same from the map's own view (the start at the map's pose),
        px: there the predicted increment is exact (no local warp), so the
        first switch may come later.
    velocity_us:
        The velocity (output and prediction) is the motion over the good
        poses of this last stretch, µs.
    timed_residue:
        Estimate each pixel's change still below the threshold from the
        time since its last event and its last interval between events
        (:func:`._generative.residue_image`); false: half a threshold in
        the last event's direction, always.
    unseen_bound:
        With ``timed_residue``: a pixel without an event yet counts as the
        change the model predicts for it, clipped to the threshold
        ``contrast`` (it did not fire), rather than no change
        (:mod:`._generative`, "Silent pixels").
    unseen_running:
        The same on a running sensor (events before the map): the share,
        0..1, of such a pixel that so counts; the rest holds no change.
        There each pixel had crossed an unknown part of its threshold
        before the start, so its silence bounds its change less. On a
        simulated slide (0.3 m/s, 240x180, started 40 ms in) with the
        ``realistic`` sensor: 2.1-2.3 % of the path counted whole (1), 1.7-2.0
        % at 0.35 (four noise seeds; 0 and 0.2 do a little better there
        but worse on the ideal sensor: 2.3 and 2.1 %, against 1.7 whole and
        1.9 at 0.35).
    refractory_us:
        The sensor's refractory period, µs (0: none): the change a pixel
        sees while it holds its reset after an event is lost, so an event
        after a same-polarity interval ``d`` stands for
        ``C d / (d - refractory_us)`` (at most 4 C) and the timed residue grows as fast
        (:func:`._generative.event_weights`). On a simulated slide with a
        2.5 ms refractory period (240x180, ``realistic`` otherwise) 3.4 ->
        1.9 % of the path; on ``slider_depth`` (no interval below 2.5 ms)
        it makes it far worse (21 %): off by default.
    contrast_off:
        The OFF events' threshold, log intensity (0: ``contrast``, one
        threshold for both): an OFF event stands for ``contrast_off``, an ON
        one for ``contrast``, and so do the sub-threshold residues after
        them (the silent pixels' bound stays ``contrast``). A simulated
        slide (240x180, C_on 0.2, C_off 0.14): 2.9 % of the path with one
        threshold (the camera lagging 1.1 mm), 1.7 % with it given.
    bootstrap_us:
        Output the ``poses`` port's rows for this long from its first, µs,
        and track from its end (0: no bootstrap; see the module).
    """

    name = "tracker.pose_6dof"
    inputs = {
        "events": Port(Kind.EVENTS, doc="the events"),
        "poses": Port(Kind.POSES, required=False,
                      doc="the initial pose (at the first event; later ones unused), or the bootstrap's poses"),
        "maps": Port(Kind.MAPS, required=False, doc="the photometric map (image, depth, K, pose), instead of map="),
    }
    produces = (Kind.POSES,)
    heavy = True

    def __init__(self, map: str = "", init: tuple[float, ...] = (), calib: str = "", contrast: float = 0.2,
                 batch_events: int = 1500, batch_us: int = 20_000, sigmas: tuple[float, ...] = (1.0,),
                 iterations: int = 4, max_points: int = 2000, min_gradient: float = 0.02, huber: float = 1.345,
                 min_fit: float = 0.35, recover_fit: float = 0.5, min_points: int = 100,
                 keyframe_px: float = 8.0, velocity_us: int = 10_000, timed_residue: bool = True,
                 unseen_bound: bool = True, map_view_px: float = 24.0, max_sd_deg: float = 0.2,
                 drift_deg_s: float = 20.0, unseen_running: float = 0.35, refractory_us: float = 0.0,
                 contrast_off: float = 0.0, bootstrap_us: int = 0) -> None:
        where = "tracker.pose_6dof"
        if not contrast > 0:
            raise ValueError(f"{where}: contrast must be > 0 (log intensity per event), got {contrast}")
        if batch_events < 16 or batch_us < 1:
            raise ValueError(f"{where}: need batch_events >= 16 and batch_us >= 1, got {batch_events}, {batch_us}")
        if not sigmas or any(not (0.3 <= s <= 16) for s in sigmas):
            raise ValueError(f"{where}: sigmas must be blurs in [0.3, 16] px, got {list(sigmas)}")
        if iterations < 1 or max_points < 16 or min_points < 12:
            raise ValueError(f"{where}: need iterations >= 1, max_points >= 16, min_points >= 12")
        if not 0 <= min_fit <= recover_fit <= 1:
            raise ValueError(f"{where}: need 0 <= min_fit <= recover_fit <= 1, got {min_fit}, {recover_fit}")
        if init and len(init) != 7:
            raise ValueError(f"{where}: init must be 7 numbers tx;ty;tz;qx;qy;qz;qw, got {len(init)}")
        self.camera: Camera | None = camera_from(calib) if calib else None
        self.contrast, self.batch_events, self.batch_us = float(contrast), int(batch_events), int(batch_us)
        self.sigmas = tuple(float(s) for s in sigmas)
        self.iterations, self.max_points, self.min_gradient = int(iterations), int(max_points), float(min_gradient)
        self.huber, self.min_fit, self.recover_fit = float(huber), float(min_fit), float(recover_fit)
        self.min_points = int(min_points)
        if not max_sd_deg > 0:
            raise ValueError(f"{where}: max_sd_deg must be > 0 (deg), got {max_sd_deg}")
        if not drift_deg_s >= 0:
            raise ValueError(f"{where}: drift_deg_s must be >= 0 (deg/s), got {drift_deg_s}")
        self.max_sd, self.drift = float(np.radians(max_sd_deg)), float(np.radians(drift_deg_s)) * 1e-6
        self._sd_good = 0.0  # the last good pose's uncertainty, rad
        self._sd_ref = (0.0, 0)  # the reference pose's uncertainty (rad) and time (µs)
        if not keyframe_px > 0:
            raise ValueError(f"{where}: keyframe_px must be > 0, got {keyframe_px}")
        self.keyframe_px = float(keyframe_px)
        self.init: tuple[np.ndarray, np.ndarray] | None = None
        if init:
            m = check_map(np.zeros((8, 8)), np.ones((8, 8)), np.eye(3), init, f"{where} init")
            self.init = (np.asarray(quat_to_rot(m.orientation)), m.position)
        self.map: PhotoMap | None = None
        self._levels: list[_Level] = []
        self.counts = {"batches": 0, "lost": 0, "relocalised": 0, "skipped_before_map": 0, "references": 0}
        self._sensor: tuple[int, int] | None = None
        self._lut: np.ndarray | None = None  # (2, H W) undistorted pixel (x; y) of each sensor pixel, raster order
        # events waiting for their batch to close: t (µs), undistorted x, y (px), polarity
        self._t = np.empty(0, np.int64)
        self._x = np.empty(0)
        self._y = np.empty(0)
        self._p = np.empty(0, np.int8)
        self._ix = np.empty(0, np.uint16)  # sensor pixel of each waiting event
        self._iy = np.empty(0, np.uint16)
        self._last: np.ndarray | None = None  # (H, W) int8 polarity of each pixel's last event
        self._tlast = np.zeros((0, 0), np.int64)  # (H, W) its time, µs
        self._dtp = np.zeros((0, 0), np.int64)  # (H, W) the interval before it (same polarity), µs; -1 unknown
        self.timed_residue = bool(timed_residue)
        self._running = False  # events came before the map: the sensor was running, no pixel starts at its reference
        # the sub-threshold residues (residue_image) at the reference view; per pixel at the last batch: their change
        # since, and the silent pixels (1)
        self._dref = np.zeros((0, 0))
        self._pix = np.zeros((2, 0, 0))
        self.unseen_bound = bool(unseen_bound)
        if not 0 <= unseen_running <= 1:
            raise ValueError(f"{where}: unseen_running must be in [0, 1] (a share), got {unseen_running}")
        self.unseen_running = float(unseen_running)
        if not refractory_us >= 0:
            raise ValueError(f"{where}: refractory_us must be >= 0 (µs), got {refractory_us}")
        self.refractory_us = float(refractory_us)
        if not contrast_off >= 0:
            raise ValueError(f"{where}: contrast_off must be >= 0 (log intensity per OFF event; 0: contrast), got "
                             f"{contrast_off}")
        self.contrast_off = float(contrast_off) if contrast_off > 0 else self.contrast
        self._off = self.contrast_off / self.contrast  # C_off / C_on, for the kernels
        if not map_view_px > 0:
            raise ValueError(f"{where}: map_view_px must be > 0, got {map_view_px}")
        self.map_view_px = float(map_view_px)
        self._sensor_at = np.zeros((0, 0, 2))  # (H, W, 2) sensor position of each pinhole pixel; empty: identity
        self._mark = -(1 << 62)
        # state: the last good pose (R, t) and its time (µs); the body twist per µs of the last good batch
        self._pose: tuple[np.ndarray, np.ndarray, int] | None = None
        self._twist = np.zeros(6)
        self._history: list[tuple[np.ndarray, np.ndarray, int]] = []  # recent good poses (R, t, µs)
        self.velocity_us = int(velocity_us)
        self._lost = False
        self._init_poses: PosePacket | None = None
        if bootstrap_us < 0:
            raise ValueError(f"{where}: bootstrap_us must be >= 0 µs, got {bootstrap_us}")
        self.bootstrap_us = int(bootstrap_us)
        self._boot_end: int | None = None  # µs: the first pose on the poses port + bootstrap_us
        self._boot: list[PosePacket] = []  # the poses port's rows up to _BOOT_KEEP_US past its end: the start pose
        self._queued: list[tuple[int, PhotoMap]] = []  # maps on the port not yet in use: (time µs, map)
        self._first_map_us: int | None = None  # the time of the first map (map=: long before any event)
        # the reference view (R, t) the increments count from, and the events since, accumulated: unblurred
        # (bilinear) and blurred at each tracking level
        self._ref: tuple[np.ndarray, np.ndarray] | None = None
        self._ref_is_map = False  # it is the map's own view
        self._raw: np.ndarray | None = None
        self._obs: list[np.ndarray] = []
        self._warp: np.ndarray | None = None  # reference_warp of the reference view and map; None: to compute
        self._rho: np.ndarray | None = None  # gradient_correlation of the map, per px of shift (at first use)
        self._coarse: _Level | None = None  # the relocalising level (at first use)
        self._fine = np.zeros((3, 0, 0))  # blur_and_gradients of the map at the finest level
        if map:
            self._set_map(load_map(map))
            self._first_map_us = -(1 << 62)

    #: For the conformance check: a few small batches.
    conformance_params = {"batch_events": 200, "max_points": 400, "min_points": 20, "iterations": 3}

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """A 48x36 camera moving before a textured plane: events and the
        scene's map at t = 0 on the ``maps`` port."""
        from tectum.sources.simulate import simulate
        from tectum.sources.simulate.photomap import scene_map

        scene = {"planes": [{"center": [0, 0, 2.0], "texel_m": 0.04,
                             "texture": {"kind": "noise", "size": 128, "contrast": 0.5, "blur": 2.0}}],
                 "motion": {"velocity": [1.0, 0.4, 0.2], "angular_velocity": [0.3, 0.6, 0.2]}, "fov_deg": 90}
        ev, _ = simulate(scene, 40_000, sensor="48x36")
        m = scene_map(scene, 0, sensor="48x36")
        maps = MapPacket(np.array([0], np.int64), image=m["image"][None], depth=m["depth"][None], K=m["K"][None],
                         pose=m["pose"][None], t_start=0, t_end=1)
        return {"events": ev.without_columns(*ev.columns), "maps": maps}

    def warmup(self) -> None:
        img = np.zeros((8, 8))
        splat(np.array([3.5]), np.array([3.5]), np.array([1.0]), 0.2, 1.0, img)
        out = np.empty((3, 8, 8))
        blur_and_gradients(img, 1.0, out)
        P = np.array([[0.0, 0.0, 1.0]] * 16)
        Xr = np.array([[3.5, 3.5, 1.0]] * 16)
        z = np.zeros(16)
        warp = np.empty((16, 7))
        reference_warp(P, Xr, np.eye(3), np.zeros(3), np.eye(3), 4.0, 4.0, 3.5, 3.5, warp)
        fit_batch(P, Xr, z, img, z, z, 0.2, img, warp, np.eye(3), np.zeros(3), 4.0, 4.0, 3.5, 3.5, 1, 1.345, 1e-3,
                  np.zeros(7))
        splat_bilinear(np.array([3.5]), np.array([3.5]), np.array([1.0]), 0.2, img)
        one = np.zeros((1, 1), np.int64)
        event_weights(np.zeros(1, np.uint16), np.zeros(1, np.uint16), np.zeros(1, np.int64), np.ones(1, np.int8), 0.2,
                      np.zeros((1, 1), np.int8), one, one, np.empty(1), 1.5, 0.0)
        residue_image(np.zeros((1, 1), np.int8), one, one, 0, 0.2, np.zeros((1, 1)), np.empty((1, 1)), np.empty((1, 1)),
                      1.0, 0.0)
        point_corrections(P, np.eye(3), np.zeros(3), 4.0, 4.0, 3.5, 3.5, np.zeros((0, 0, 2)), img[None], 1.0, 1,
                          np.empty((1, 16)))

    # -- the map ----------------------------------------------------------------------
    def _check_map(self, m: PhotoMap) -> None:
        """A map's intrinsics and size against the calibration's and the sensor's."""
        if self.camera is not None:
            self._check_intrinsics(m, self.camera)
        if self._sensor is not None and m.size != self._sensor:
            raise ValueError(f"tracker.pose_6dof: the map is {m.size[0]}x{m.size[1]} px, the events "
                             f"{self._sensor[0]}x{self._sensor[1]} px")

    def _set_map(self, m: PhotoMap) -> None:
        self._check_map(m)
        blurred: dict[float, np.ndarray] = {}  # per σ: each blur once (the finest serves three uses)
        for s in self.sigmas:
            if s not in blurred:
                blurred[s] = np.empty((3, *m.image.shape))
                blur_and_gradients(m.image, s, blurred[s])
        fine = blurred[self.sigmas[-1]]
        ok = np.isfinite(m.depth) & (np.hypot(fine[1], fine[2]) >= self.min_gradient)
        ok[:3, :] = ok[-3:, :] = False
        ok[:, :3] = ok[:, -3:] = False
        my, mx = np.nonzero(ok)
        if len(mx) < self.min_points:
            raise ValueError(f"tracker.pose_6dof: the map has {len(mx)} pixels with depth and a gradient >= "
                             f"{self.min_gradient}/px, fewer than min_points={self.min_points}: nothing to track")
        if len(mx) > self.max_points:  # spread over the map: every k-th in raster order
            keep = np.linspace(0, len(mx) - 1, self.max_points).round().astype(np.int64)
            mx, my = mx[keep], my[keep]
        K = m.K
        d = m.depth[my, mx]
        Xc = np.stack([(mx - K[0, 2]) / K[0, 0] * d, (my - K[1, 2]) / K[1, 1] * d, d], axis=1)
        R_wr = np.asarray(quat_to_rot(m.orientation))
        self._P = np.ascontiguousarray(Xc @ R_wr.T + m.position)
        self._Xr = np.ascontiguousarray(np.stack([mx.astype(np.float64), my.astype(np.float64), d], axis=1))
        self._R_wr = R_wr
        self._K = m.K
        self._levels = [_Level(blurred[s], s, mx, my) for s in self.sigmas]
        self._coarse = None
        self._fine = fine
        self._rho = None
        self._warp = None
        self.map = m
        # a reference view already in use is the tracker's own, not this map's (it keeps the keyframe step)
        self._ref_is_map = False

    # what only some runs need, made at its first use: the same numbers as made with the map
    def _coarse_level(self) -> _Level:
        """The relocalising level (σ = 4 × ``sigmas[0]``)."""
        if self._coarse is None:
            assert self.map is not None
            sigma = 4.0 * self.sigmas[0]
            out = np.empty((3, *self.map.image.shape))
            blur_and_gradients(self.map.image, sigma, out)
            self._coarse = _Level(out, sigma, self._Xr[:, 0].astype(np.int64), self._Xr[:, 1].astype(np.int64))
        return self._coarse

    def _gradient_rho(self) -> np.ndarray:
        """:func:`gradient_correlation` of the map at the finest level, to
        twice the keyframe step (past it the last value holds; the map's
        own view has no σ to pass on), for a new reference view."""
        if self._rho is None:
            assert self.map is not None
            reach = min(int(np.ceil(2 * self.keyframe_px)), min(self.map.size) - 1)
            self._rho = gradient_correlation(self.map.image, self.map.depth, self.sigmas[-1], reach,
                                             blurred=self._fine)
        return self._rho

    @staticmethod
    def _check_intrinsics(m: PhotoMap, cam: Camera) -> None:
        k = np.array([cam.fx, cam.fy, cam.cx, cam.cy])
        km = np.array([m.K[0, 0], m.K[1, 1], m.K[0, 2], m.K[1, 2]])
        if not np.allclose(k, km, rtol=1e-3, atol=0.05):
            raise ValueError(f"tracker.pose_6dof: the map's intrinsics fx, fy, cx, cy = {km.round(3).tolist()} are "
                             f"not the calibration's {k.round(3).tolist()}")
        if cam.size is not None and tuple(cam.size) != m.size:
            raise ValueError(f"tracker.pose_6dof: the map is {m.size[0]}x{m.size[1]} px, the calibration "
                             f"{cam.size[0]}x{cam.size[1]} px")

    # -- input -------------------------------------------------------------------------
    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        maps = ports.get("maps")
        if maps is not None and len(maps):
            assert isinstance(maps, MapPacket)
            for i in range(len(maps)):  # each in use from the first batch that ends at or after its time
                m = map_from_packet(maps, i)
                if self.map is None:  # the first: at once (no event before it is tracked)
                    self._set_map(m)
                else:
                    self._check_map(m)
                    self._queued.append((int(maps.t[i]), m))
                if self._first_map_us is None:
                    self._first_map_us = int(maps.t[i])
        boot: list[Packet] = []
        poses = ports.get("poses")
        if poses is not None and len(poses):
            assert isinstance(poses, PosePacket)
            if self.bootstrap_us:
                boot = self._bootstrap(poses)
            elif self._pose is None:
                self._init_poses = poses if self._init_poses is None else self._init_poses
        ev = ports.get("events")
        if ev is None:
            return boot
        assert isinstance(ev, EventPacket)
        self._mark = max(self._mark, ev.t_end)
        if len(ev):
            self._add_events(ev)
        return boot + self._advance(final=False)

    def output_mark(self, watermark: int) -> int:
        """On a loop: a row is stamped with its batch's last event, so none
        comes before the first event still waiting for its batch."""
        return min(int(self._t[0]), watermark) if self._t.size else watermark

    def _bootstrap(self, poses: PosePacket) -> list[Packet]:
        """Keep the poses port's rows for the start pose; hand on those
        before the bootstrap's end as output rows (not lost, fit NaN)."""
        if self._boot_end is None:
            self._boot_end = int(poses.t[0]) + self.bootstrap_us
        keep = poses.t < self._boot_end + _BOOT_KEEP_US
        if keep.any():
            pos, q = np.asarray(poses.position[keep], np.float64), np.asarray(poses.orientation[keep], np.float64)
            if not (np.isfinite(pos).all() and np.isfinite(q).all()):
                raise ValueError("tracker.pose_6dof: a bootstrap pose on port 'poses' is not finite")
            self._boot.append(PosePacket(poses.t[keep], position=pos, orientation=q, t_start=poses.t_start,
                                         t_end=poses.t_end))
        k = int(np.searchsorted(poses.t, self._boot_end, side="left"))
        if not k:
            return []
        ts = poses.t[:k]
        q = np.asarray(poses.orientation[:k], np.float64)
        return [PosePacket(ts, position=np.asarray(poses.position[:k], np.float64),
                           orientation=q / np.linalg.norm(q, axis=1, keepdims=True), linear_velocity=np.zeros((k, 3)),
                           angular_velocity=np.zeros((k, 3)), lost=np.zeros(k, bool), fit=np.full(k, np.nan),
                           t_start=int(ts[0]), t_end=int(ts[-1]) + 1)]

    def _track_from(self) -> int | None:
        """The time from which events are tracked, µs: the first map's, and
        with a bootstrap its end; None: not known yet."""
        if self._first_map_us is None or (self.bootstrap_us and self._boot_end is None):
            return None
        return max(self._first_map_us, self._boot_end) if self._boot_end is not None else self._first_map_us

    def _use_maps(self, t_us: int) -> None:
        """Take the latest queued map made at or before ``t_us`` µs (a batch's
        last event: the maps up to it have all come, the ports being joined
        by time)."""
        k = 0
        while k < len(self._queued) and self._queued[k][0] <= t_us:
            k += 1
        if k:
            self._set_map(self._queued[k - 1][1])
            del self._queued[:k]

    def finish(self) -> list[Packet]:
        if self.map is None and not self._queued and self.counts["skipped_before_map"]:
            raise ValueError(f"tracker.pose_6dof: no map came for the {self.counts['skipped_before_map']} events: give "
                             "map=FILE.npz (image, depth, K, pose) or connect a maps port")
        if self.bootstrap_us and self._boot_end is None and self.counts["skipped_before_map"]:
            raise ValueError(f"tracker.pose_6dof: bootstrap_us={self.bootstrap_us} but no pose came on port 'poses' "
                             f"for the {self.counts['skipped_before_map']} events: connect the bootstrap's poses")
        return self._advance(final=True)

    def _add_events(self, ev: EventPacket) -> None:
        if self._sensor is None:
            self._start(ev.sensor)
        elif ev.sensor != self._sensor:
            raise ValueError(f"tracker.pose_6dof: the sensor changed from {self._sensor} to {ev.sensor}")
        t_from = self._track_from()
        k = len(ev) if t_from is None else int(np.searchsorted(ev.t, t_from, side="left"))
        if k:  # before the map (or the bootstrap's end): not tracked, but they tell each pixel's state, and that the
            # sensor is running
            self.counts["skipped_before_map"] += k
            event_weights(ev.x[:k], ev.y[:k], ev.t[:k], ev.p[:k], self.contrast, self._last, self._tlast, self._dtp,
                          np.empty(k), 1.0, self.refractory_us, self._off)
            self._running = True
            if k == len(ev):
                return
            ev = ev.slice_time(t_from)
        assert self._lut is not None and self._sensor is not None
        at = ev.y.astype(np.intp) * self._sensor[0] + ev.x  # flat indices: a tenth of the cost of lut[y, x]
        self._t = np.concatenate([self._t, ev.t])
        self._x = np.concatenate([self._x, self._lut[0][at]])
        self._y = np.concatenate([self._y, self._lut[1][at]])
        self._p = np.concatenate([self._p, ev.p])
        self._ix = np.concatenate([self._ix, ev.x])
        self._iy = np.concatenate([self._iy, ev.y])

    def _start(self, sensor: tuple[int, int]) -> None:
        w, h = sensor
        if self.map is not None and self.map.size != (w, h):
            raise ValueError(f"tracker.pose_6dof: the map is {self.map.size[0]}x{self.map.size[1]} px, the events "
                             f"{w}x{h} px: a map must be seen by the sensor that gives the events")
        if self.camera is not None and self.camera.size is not None and tuple(self.camera.size) != (w, h):
            raise ValueError(f"tracker.pose_6dof: the calibration is for {self.camera.size[0]}x"
                             f"{self.camera.size[1]} px, the events for {w}x{h}")
        self._sensor = (w, h)
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        pix = np.stack([u.ravel(), v.ravel()], axis=1)
        if self.camera is not None and self.camera.D is not None and np.any(self.camera.D):
            pix = self.camera.undistort_points(pix)
            # and back: the sensor position of each pinhole pixel (the residues are kept per sensor pixel)
            c = self.camera
            rays = np.stack([(u.ravel() - c.cx) / c.fx, (v.ravel() - c.cy) / c.fy, np.ones(h * w)], axis=1)
            at = c.project(rays).reshape(h, w, 2)
            self._sensor_at = np.ascontiguousarray(np.nan_to_num(at, nan=-1e6))
        # where the lens model has no inverse (NaN), far outside: such events add nothing
        self._lut = np.ascontiguousarray(np.nan_to_num(pix.T, nan=-1e6))
        self._last = np.zeros((h, w), np.int8)
        self._tlast = np.zeros((h, w), np.int64)
        self._dtp = np.full((h, w), -1, np.int64)
        self._dref = np.zeros((h, w))
        self._pix = np.zeros((2, h, w))

    # -- batches -----------------------------------------------------------------------
    def _advance(self, final: bool) -> list[Packet]:
        t, n, a = self._t, len(self._t), 0
        rows: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool, float]] = []
        while a < n:
            b = min(a + self.batch_events, int(np.searchsorted(t, t[a] + self.batch_us, side="left")))
            if b >= n and a + self.batch_events > n and not final and self._mark < t[a] + self.batch_us:
                break  # open: more events may join it
            b = min(b, n)
            self._use_maps(int(t[b - 1]))
            rows.append(self._batch(a, b))
            a = b
        if a:
            self._t, self._x, self._y, self._p = self._t[a:], self._x[a:], self._y[a:], self._p[a:]
            self._ix, self._iy = self._ix[a:], self._iy[a:]
        if not rows:
            return []
        ts = np.array([r[0] for r in rows], np.int64)
        return [PosePacket(ts, position=np.array([r[1] for r in rows]), orientation=np.array([r[2] for r in rows]),
                           linear_velocity=np.array([r[3] for r in rows]),
                           angular_velocity=np.array([r[4] for r in rows]), lost=np.array([r[5] for r in rows]),
                           fit=np.array([r[6] for r in rows]), t_start=int(ts[0]), t_end=int(ts[-1]) + 1)]

    def _initial(self, t0: int) -> tuple[np.ndarray, np.ndarray]:
        if self.init is not None:
            return self.init[0].copy(), self.init[1].copy()
        ps = concat(self._boot) if self._boot else self._init_poses  # the port's pose at t0 (interpolated)
        if ps is not None:
            assert isinstance(ps, PosePacket)
            tq = min(max(t0, int(ps.t[0])), int(ps.t[-1]))
            p, q, _ = interpolate_poses(np.array([tq], np.int64), ps.t, ps.position, ps.orientation)
            return np.asarray(quat_to_rot(q[0])), p[0]
        assert self.map is not None
        return np.asarray(quat_to_rot(self.map.orientation)), self.map.position.copy()

    def _batch(self, a: int, b: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool, float]:
        """Fit the batch of events ``[a, b)``: its row (time, position,
        orientation, linear and angular velocity, lost, fit)."""
        t_end = int(self._t[b - 1])
        if self._pose is None:
            R, p = self._initial(int(self._t[a]))
            if self._running and self.timed_residue:  # the pixels' residues at the start, from the events before it
                residue_image(self._last, self._tlast, self._dtp, int(self._t[a]), self.contrast, np.zeros_like(
                    self._dref), self._dref, np.empty((0, 0)), 1.0, self.refractory_us, self._off)
            self._pose = (R, p, int(self._t[a]))
            assert self.map is not None
            self._new_reference(R, p, bool(np.allclose(p, self.map.position) and np.allclose(R, self._R_wr)), 0.0,
                                int(self._t[a]))
        assert self._ref is not None and self._raw is not None
        self.counts["batches"] += 1
        x, y = self._x[a:b], self._y[a:b]
        wgt = np.empty(b - a)
        event_weights(self._ix[a:b], self._iy[a:b], self._t[a:b], self._p[a:b], self.contrast, self._last, self._tlast,
                      self._dtp, wgt, 1.0 if self._running else 1.5, self.refractory_us, self._off)
        # per sensor pixel: the residues' change since the reference view and the silent pixels (their share)
        pix = self._pix if self.unseen_bound else self._pix[:1]
        if self.timed_residue:
            residue_image(self._last, self._tlast, self._dtp, t_end, self.contrast, self._dref, pix[0],
                          pix[1] if self.unseen_bound else np.empty((0, 0)),
                          self.unseen_running if self._running else 1.0, self.refractory_us, self._off)
        splat_bilinear(x, y, wgt, 1.0, self._raw)
        for lv, img in zip(self._levels, self._obs):
            splat(x, y, wgt, 1.0, lv.sigma, img)
        Rp, tp, tprev = self._pose
        dt = max(t_end - tprev, 1)
        if self._lost:  # relocalise from the last good pose, coarse to fine
            R1, t1 = Rp.copy(), tp.copy()
            lv0, coarse = self._coarse_level(), np.empty((3, *self._raw.shape))
            blur_and_gradients(self._raw, lv0.sigma, coarse)
            levels = [(lv0, np.ascontiguousarray(coarse[0])), *zip(self._levels, self._obs)]
        else:  # constant velocity
            dR, dp = np.empty((3, 3)), np.empty(3)
            se3_exp_kernel(self._twist * dt, dR, dp)
            R1, t1 = Rp @ dR, Rp @ dp + tp
            levels = list(zip(self._levels, self._obs))
        R1, t1 = np.ascontiguousarray(R1), np.ascontiguousarray(t1)
        K = self._K
        if self._warp is None:
            Ra, ta = self._ref
            self._warp = np.empty((len(self._P), 7))
            reference_warp(self._P, self._Xr, Ra, ta, self._R_wr, K[0, 0], K[1, 1], K[0, 2], K[1, 2], self._warp)
        stats = np.zeros(7)
        at = np.zeros((2, len(self._P)))  # at the points: the residues' change, the share of silent pixels
        for k, (lv, img) in enumerate(levels):
            if self.timed_residue and (k or not self._lost):  # at the prediction; none at a relocalising coarse level
                point_corrections(self._P, R1, t1, K[0, 0], K[1, 1], K[0, 2], K[1, 2], self._sensor_at, pix, lv.sigma,
                                  1, at[:len(pix)])
            fit_batch(self._P, self._Xr, lv.Lm, img, at[0], at[1], self.contrast, lv.image, self._warp, R1, t1, K[0, 0],
                      K[1, 1], K[0, 2], K[1, 2], self.iterations, self.huber, 1e-3, stats)
        fit = float(stats[1])
        # the uncertainty (rad): the motion since the reference, from the fit and from how far it may have gone
        # (independent: the fit sees only the events since), on top of the reference pose's own
        prior = self.drift * (t_end - self._sd_ref[1])
        rel = prior * stats[6] / float(np.hypot(prior, stats[6])) if prior > 0 and stats[6] < np.inf else prior
        sd = float(np.hypot(self._sd_ref[0], rel))
        good = stats[0] >= self.min_points and fit >= (self.recover_fit if self._lost else self.min_fit) \
            and sd <= self.max_sd and bool(np.isfinite(t1).all())
        if not good:
            self.counts["lost"] += 1
            if not self._lost:  # the increments count again from the last good pose
                self._new_reference(Rp, tp, False, self._sd_good, tprev)
            self._lost = True
            self._pose = (Rp, tp, t_end)
            self._twist = np.zeros(6)
            self._history.clear()
            return t_end, tp.copy(), _quat(Rp), np.zeros(3), np.zeros(3), True, fit
        if self._lost:
            self.counts["relocalised"] += 1
            self._history.clear()
        self._lost = False
        self._pose = (R1, t1, t_end)
        self._sd_good = sd
        if stats[5] > (self.map_view_px if self._ref_is_map else self.keyframe_px):
            # the new reference's own: the old one's, as far as it still moves this pose, and the motion's since
            rho_px = self._gradient_rho()
            rho = float(np.interp(stats[5], np.arange(len(rho_px)), rho_px))
            self._new_reference(R1, t1, False, float(np.hypot(rho * self._sd_ref[0], rel)), t_end)
        # the velocity: the motion since the oldest good pose at most velocity_us back (one batch's is noisy)
        self._history = [h for h in self._history if h[2] >= t_end - self.velocity_us]
        Ro, to, t_old = self._history[0] if self._history else (Rp, tp, tprev)
        self._history.append((R1, t1, t_end))
        span = max(t_end - t_old, 1)
        xi = np.empty(6)
        se3_log_kernel(Ro.T @ R1, Ro.T @ (t1 - to), xi)
        self._twist = xi / span
        return t_end, t1, _quat(R1), (t1 - to) / (span * 1e-6), xi[:3] / (span * 1e-6), False, fit

    def _new_reference(self, R: np.ndarray, t: np.ndarray, map_view: bool, sd: float, t_us: int) -> None:
        """The increments count from here: the reference pose is ``(R, t)``
        (``map_view``: the map's own; its uncertainty ``sd`` rad at ``t_us``
        µs), and the accumulated event images start again at zero."""
        assert self._sensor is not None
        w, h = self._sensor
        self._ref = (np.ascontiguousarray(R), np.ascontiguousarray(t))
        self._ref_is_map = map_view
        self._warp = None
        self._sd_ref = (sd, t_us)
        self.counts["references"] += 1
        self._dref += self._pix[0]  # the residues now
        self._pix[0] = 0.0
        self._raw = np.zeros((h, w))
        self._obs = [np.zeros((h, w)) for _ in self._levels]
