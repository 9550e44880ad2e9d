"""Numba kernels of ``tracker.pose_6dof``: the generative event model
against a photometric map (Gallego et al., TPAMI 2018; Bryner et al., ICRA
2019), one batch of events at a time.

**Model.** A pixel fires when its log intensity has changed by the contrast
``C`` since its last event, so the events since a reference time, summed
with their polarity, sample the brightness increment since then (an OFF
threshold other than the ON one scales the OFF events' and residues'
terms, the ``off`` of :func:`event_weights`):
``ΔL_obs(u) = Σ_k w_k`` at pixel ``u`` (blurred by a Gaussian of σ px,
:func:`splat`), with ``w_k = C p_k`` plus the half-threshold term of
:func:`event_weights`, refined per pixel by the time since its last event
(:func:`residue_image`, added at the map points by
:func:`point_corrections`). The map predicts that increment: a map point ``P``
(world, m) with log intensity ``L_map(m)`` seen at pixel ``m`` of the map
lands at ``u1 = π(T1⁻¹ P)`` now (pose ``T1``, world-from-camera) and at
``u0`` in the reference view (``T0``). The pixel ``u1`` saw at ``T0`` the
map point ``m' ≈ m + A (u1 - u0)``, ``A = (∂u/∂m)⁻¹`` the local
map-to-image warp at ``T0`` (the surface taken fronto-parallel to the map's
view around ``m``), so the predicted increment at ``u1`` is
``ΔL_pred = L_map(m) - L_map(m')``: to first order the papers'
``-∇L · u̇ Δt`` (brightness gradient dotted with the motion), without the
linearisation, so the camera may move several pixels from the reference
view (at the map's own view ``m' = u1``: exact).

**Silent pixels.** A pixel with no event yet has a change that no timing
can tell, only bound: it did not fire, so ``|ΔL| < C`` since the start.
For such a pixel the observation is the model's own change within that
bound, ``ΔL_obs + clip(ΔL_pred - ΔL_obs, -C, C)``: no residual while the
model keeps it below the threshold, the excess when the model says it
should have fired. At a point between firing and silent pixels (share
``q`` of silent ones, sampled bilinearly), ``q`` of it is so treated
(``r = (1 - q)(ΔL_obs - ΔL_pred)`` inside the bound). On a sensor that
started from rest the bound is exact (every pixel at its reference
level); on a running one each pixel had crossed an unknown part of its
threshold before the start, so its silence says less: there a pixel
without events counts as ``unfired`` of a silent one (the rest of it
holds its observed 0, at ``(1 - unfired)²`` of a firing pixel's weight).
A pixel silent past twice its last interval is not counted silent: its
timed estimate has fallen to its last event's level by then, and counted
silent it cost accuracy on simulated sensors with a refractory period and
timestamp jitter (``docs/pose_6dof.md``). A pixel silent since before a
reference view other than the start is held to ``C`` from that view's
level too (its level there taken as its last event's; ``2C``, the strict
bound, measured no different).

**Estimation.** ``T1 = T1 exp(δ)`` (δ = (ω, v), camera frame) minimises a
robust sum over the map's points of ``r = ΔL_obs(u1) - ΔL_pred`` by
Gauss-Newton with analytic Jacobians
``∂r/∂δ = (∇ΔL_obs(u1) + Aᵀ ∇L_map(m'))ᵀ ∂u1/∂δ``,
``∂u1/∂δ = ∂π/∂X [ [X]ₓ  -I ]``, a Huber weight per point (scale from the
median absolute residual of the points mostly seen by firing pixels: the
inlier/outlier mixture made robust), and a
small Levenberg damping. The fit's quality is the correlation of observed
and predicted increments over the points in view
(``Σ obs·pred / sqrt(Σ obs² Σ pred²)``), its support the pose's
covariance from the last Gauss-Newton step (a faint texture or few firing
pixels fit well yet pin the pose loosely: its σ says so).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.ndimage import gaussian_filter

from tectum._rigid import se3_exp_kernel

__all__ = ["event_weights", "residue_image", "point_corrections", "splat", "splat_bilinear", "blur_and_gradients",
           "reference_warp", "fit_batch"]


@njit(cache=True, nogil=True)
def splat(ux, uy, p, c, sigma, img):  # type: ignore[no-untyped-def]
    """Add ``c * p_k`` to ``img`` (H, W) around each event's position
    ``(ux_k, uy_k)`` (px, float) with a normalised Gaussian of ``sigma`` px
    (separable, cut at 3σ). The taps of an axis are computed again only
    when the position's fraction of a pixel changes (never, for events on
    whole pixels)."""
    H, W = img.shape
    r = int(math.ceil(3.0 * sigma))
    n = 2 * r + 1
    wx = np.empty(n)
    wy = np.empty(n)
    inv = 1.0 / (2.0 * sigma * sigma)
    fx_last = -1.0
    fy_last = -1.0
    sx = 1.0
    sy = 1.0
    for k in range(ux.shape[0]):
        bx = math.floor(ux[k])
        by = math.floor(uy[k])
        x0 = int(bx) - r
        y0 = int(by) - r
        fx = ux[k] - bx
        fy = uy[k] - by
        if fx != fx_last:
            fx_last = fx
            sx = 0.0
            for i in range(n):
                dx = i - r - fx
                wx[i] = math.exp(-dx * dx * inv)
                sx += wx[i]
        if fy != fy_last:
            fy_last = fy
            sy = 0.0
            for i in range(n):
                dy = i - r - fy
                wy[i] = math.exp(-dy * dy * inv)
                sy += wy[i]
        a = c * p[k] / (sx * sy)
        if 0 <= x0 and x0 + n <= W and 0 <= y0 and y0 + n <= H:  # inside: no test per pixel
            for j in range(n):
                b = a * wy[j]
                row = img[y0 + j]
                for i in range(n):
                    row[x0 + i] += b * wx[i]
            continue
        for j in range(n):
            y = y0 + j
            if y < 0 or y >= H:
                continue
            b = a * wy[j]
            for i in range(n):
                x = x0 + i
                if 0 <= x < W:
                    img[y, x] += b * wx[i]


@njit(cache=True, nogil=True)
def event_weights(x, y, t, p, c, last, tlast, dtp, out, first=1.5, refractory=0.0, off=1.0):  # type: ignore[no-untyped-def]
    """Each event's share of the brightness increment, in order: ``c p``
    plus ``c/2 (p - p_prev)``, ``p_prev`` the polarity of the pixel's
    previous event (``last`` (H, W) int8 keeps them and is updated; 0
    before its first). The second term models the change still below the
    threshold at a batch's end: after an event of polarity ``p`` a pixel
    whose brightness keeps moving holds on average ``c/2`` more, unseen; the
    sum over a window telescopes to ``c/2 (p_last(end) - p_last(start))``,
    so the increments of a window are not biased towards a lag of half a
    threshold (:func:`residue_image` refines that ``c/2`` by the time since
    the pixel's last event). A pixel's first event weighs ``first c p``:
    1.5 (a threshold and the half after it) when the pixel started at its
    reference level, as a simulation from rest does; 1 when the sensor was
    running and the part of that threshold crossed before the start is
    unknown (half a threshold expected). ``tlast`` (H, W) int64 gets each
    pixel's last event time (µs), ``dtp`` (H, W) int64 the interval from the
    event before it when both had this polarity, else -1.

    ``refractory`` (µs, 0: none): a pixel holds its reset that long after
    each event and then takes its level there as its new reference, so the
    change during the hold is never signalled. A pixel changing at a steady
    rate fires every ``d = refractory + C / rate``: its event after such an
    interval stands for ``C d / (d - refractory)`` of change (at most 4 C),
    not ``C`` (:func:`residue_image` scales its estimate the same way).

    ``off``: the OFF threshold over the ON one, ``C_off / C_on`` (``c`` is
    ``C_on``): an OFF event stands for ``off c``, and so do the half
    thresholds of pixels whose last event was OFF."""
    for k in range(x.shape[0]):
        q = last[y[k], x[k]]
        d = t[k] - tlast[y[k], x[k]] if q == p[k] else -1
        cp = c if p[k] > 0 else off * c  # this event's threshold, and the last one's
        cq = c if q > 0 else off * c
        half = 0.5 * (cp * p[k] - cq * q) if q != 0 else (first - 1.0) * cp * p[k]
        out[k] = cp * p[k] * _gain(d, refractory) + half
        dtp[y[k], x[k]] = d
        tlast[y[k], x[k]] = t[k]
        last[y[k], x[k]] = p[k]


@njit(cache=True, nogil=True, inline="always")
def _gain(d, refractory):  # type: ignore[no-untyped-def]
    """The change per threshold of a pixel whose last interval was ``d`` µs
    (-1 unknown) after a refractory hold of ``refractory`` µs."""
    if refractory <= 0.0 or d <= 0:
        return 1.0
    return min(d / max(d - refractory, 1.0), 4.0)


@njit(cache=True, nogil=True, inline="always")
def _residue(p, tl, d, t_now, c, refractory):  # type: ignore[no-untyped-def]
    """One pixel's term of :func:`residue_image` (last polarity ``p``, time
    ``tl`` µs, interval ``d`` µs or -1)."""
    if p == 0 or d <= 0:
        return 0.0
    f = (t_now - tl) / d
    g = f if f <= 1.0 else max(0.0, 2.0 - f)
    return c * p * (g * _gain(d, refractory) - 0.5)


@njit(cache=True, nogil=True)
def residue_image(last, tlast, dtp, t_now, c, base, out, quiet, unfired=1.0, refractory=0.0, off=1.0):  # type: ignore[no-untyped-def]
    """``out`` (H, W): the sub-threshold change of each pixel at ``t_now``
    (µs) beyond the ``c/2`` of :func:`event_weights`, log intensity, less
    ``base`` (H, W; e.g. the same at the reference view). A pixel
    whose last two events had one polarity ``p``, ``dt`` µs apart, is taken
    to go on at that rate: ``x = (t_now - t_last) / dt`` of a threshold has
    built up (``c p x``) until the next event is due (``x = 1``); past that
    it has slowed or turned back, and the estimate falls back to 0 by ``x =
    2``. Other pixels keep ``c/2`` (0 here). A pixel firing steadily so
    holds its true residue rather than half a threshold; one the motion
    has left (at a turn of the camera) no longer claims a change it does
    not have.

    With ``refractory`` (µs) the estimate is scaled as the events are
    (:func:`event_weights`): the change since the last event goes on at
    ``C / (dt - refractory)`` per µs. ``off`` (``C_off / C_on``, ``c`` being
    ``C_on``): a pixel whose last event was OFF holds ``off`` times as much.

    The pixels whose change this cannot tell, those without an event yet,
    get ``unfired`` in ``quiet`` (H, W; their share of a silent pixel, see
    the module; 0 elsewhere; empty: not computed). A pixel past twice its
    interval is not among them: its estimate, its last event's level, is
    as good as a firing pixel's."""
    H, W = out.shape
    with_quiet = quiet.shape[0] > 0
    for y in range(H):
        for x in range(W):
            p = last[y, x]
            tl = tlast[y, x]
            d = dtp[y, x]
            out[y, x] = _residue(p, tl, d, t_now, c if p > 0 else off * c, refractory) - base[y, x]
            if with_quiet:
                quiet[y, x] = unfired if p == 0 else 0.0


@njit(cache=True, nogil=True)
def point_corrections(P, R, t, fx, fy, cx, cy, sensor_at, diff, sigma, nblur, out):  # type: ignore[no-untyped-def]
    """``out[m, i]``: image ``diff[m]`` (n, H, W, sensor pixels; e.g. the
    change of :func:`residue_image` since the reference view and its silent
    pixels) at where world point ``P[i]`` lands seen from pose ``(R, t)``
    (world-from-camera): its pinhole pixel ``u``, taken to the sensor by
    ``sensor_at`` (H, W, 2: the sensor position of each pinhole pixel,
    bilinear; empty: the identity). 0 out of view. The first ``nblur``
    images blurred by a normalised Gaussian of ``sigma`` px (cut at 3σ)
    there: what :func:`splat` of those pixels would add, the lens's local
    stretch ignored; the others sampled bilinearly (a share of pixels:
    measured as good as its blur, at a tenth of the cost), 0 where the
    lens takes the point off the sensor."""
    nimg, H, W = diff.shape
    r = int(math.ceil(3.0 * sigma))
    n = 2 * r + 1
    inv = 1.0 / (2.0 * sigma * sigma)
    norm = 0.0
    for i in range(n):
        norm += math.exp(-(i - r) * (i - r) * inv)
    norm = 1.0 / (norm * norm)
    # the Gaussian's taps by the point's offset from the nearest pixel, in 1/64 px (no exp per point)
    nb = 64
    taps = np.empty((nb + 1, n))
    for b in range(nb + 1):
        f = b / nb - 0.5
        for i in range(n):
            d = i - r - f
            taps[b, i] = math.exp(-d * d * inv)
    for k in range(P.shape[0]):
        for m in range(nimg):
            out[m, k] = 0.0
        u, v, _, _, _, front = _project(P, k, R, t, fx, fy, cx, cy)
        if not (front and 0.0 <= u < W - 1.0 and 0.0 <= v < H - 1.0):
            continue
        if sensor_at.shape[0]:
            x0 = int(u)
            y0 = int(v)
            ax = u - x0
            ay = v - y0
            su = (1 - ay) * ((1 - ax) * sensor_at[y0, x0, 0] + ax * sensor_at[y0, x0 + 1, 0]) + \
                ay * ((1 - ax) * sensor_at[y0 + 1, x0, 0] + ax * sensor_at[y0 + 1, x0 + 1, 0])
            sv = (1 - ay) * ((1 - ax) * sensor_at[y0, x0, 1] + ax * sensor_at[y0, x0 + 1, 1]) + \
                ay * ((1 - ax) * sensor_at[y0 + 1, x0, 1] + ax * sensor_at[y0 + 1, x0 + 1, 1])
            u, v = su, sv
        cu = math.floor(u + 0.5)
        cv = math.floor(v + 0.5)
        wx = taps[int((u - cu + 0.5) * nb + 0.5)]
        wy = taps[int((v - cv + 0.5) * nb + 0.5)]
        xs = int(cu) - r
        ys = int(cv) - r
        i0 = max(0, -xs)
        i1 = min(n, W - xs)
        j0 = max(0, -ys)
        j1 = min(n, H - ys)
        if 0.0 <= u < W - 1.0 and 0.0 <= v < H - 1.0:  # through the lens it may land off the sensor: 0 there
            x0 = int(u)
            y0 = int(v)
            ax = u - x0
            ay = v - y0
            for m in range(nblur, nimg):
                out[m, k] = (1 - ay) * ((1 - ax) * diff[m, y0, x0] + ax * diff[m, y0, x0 + 1]) + \
                    ay * ((1 - ax) * diff[m, y0 + 1, x0] + ax * diff[m, y0 + 1, x0 + 1])
        for m in range(nblur):
            acc = 0.0
            for j in range(j0, j1):
                y = ys + j
                a = 0.0
                for i in range(i0, i1):
                    a += diff[m, y, xs + i] * wx[i]
                acc += a * wy[j]
            out[m, k] = acc * norm


@njit(cache=True, nogil=True)
def splat_bilinear(ux, uy, p, c, img):  # type: ignore[no-untyped-def]
    """Add ``c * p_k`` to ``img`` (H, W) at each event's position (px,
    float), split bilinearly over the 4 nearest pixels."""
    H, W = img.shape
    for k in range(ux.shape[0]):
        x0 = int(math.floor(ux[k]))
        y0 = int(math.floor(uy[k]))
        fx = ux[k] - x0
        fy = uy[k] - y0
        a = c * p[k]
        for j in range(2):
            y = y0 + j
            if y < 0 or y >= H:
                continue
            wy = fy if j else 1.0 - fy
            for i in range(2):
                x = x0 + i
                if 0 <= x < W:
                    img[y, x] += a * wy * (fx if i else 1.0 - fx)


@njit(cache=True, nogil=True)
def _bilinear(img, x, y):  # type: ignore[no-untyped-def]
    """Value and gradient (central differences of the bilinear
    interpolant's cells) of ``img`` at ``(x, y)`` px; the caller keeps
    ``1 <= x < W - 2`` and ``1 <= y < H - 2``."""
    x0 = int(x)
    y0 = int(y)
    fx = x - x0
    fy = y - y0
    a = img[y0, x0]
    b = img[y0, x0 + 1]
    c = img[y0 + 1, x0]
    d = img[y0 + 1, x0 + 1]
    v = (1 - fy) * ((1 - fx) * a + fx * b) + fy * ((1 - fx) * c + fx * d)
    gx = (1 - fy) * (b - a) + fy * (d - c)
    gy = (1 - fx) * (c - a) + fx * (d - b)
    return v, gx, gy


def blur_and_gradients(img: np.ndarray, sigma: float, out: np.ndarray) -> None:
    """``out[0]`` the Gaussian blur (σ px, cut at 3σ, edges replicated) of
    ``img``, ``out[1]``, ``out[2]`` its x and y central differences (px⁻¹;
    one-sided halves at the edges). Once per map and level, and per
    relocalisation attempt: not a hot loop."""
    b = gaussian_filter(np.asarray(img, np.float64), sigma, mode="nearest", truncate=3.0)
    out[0] = b
    p = np.pad(b, 1, mode="edge")
    out[1] = 0.5 * (p[1:-1, 2:] - p[1:-1, :-2])
    out[2] = 0.5 * (p[2:, 1:-1] - p[:-2, 1:-1])


@njit(cache=True, nogil=True, inline="always")
def _in_camera(P, i, R, t):  # type: ignore[no-untyped-def]
    """World point ``P[i]`` in the camera of world-from-camera pose ``(R, t)``: ``Rᵀ (P - t)``."""
    px, py, pz = P[i, 0] - t[0], P[i, 1] - t[1], P[i, 2] - t[2]
    return (R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz, R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz,
            R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz)


@njit(cache=True, nogil=True, inline="always")
def _project(P, i, R, t, fx, fy, cx, cy):  # type: ignore[no-untyped-def]
    """Pinhole pixel ``(u, v)`` of world point ``P[i]`` from pose ``(R, t)``,
    its camera-frame ``(X, Y, Z)``, and whether it is in front (``Z > 1e-6``)."""
    X, Y, Z = _in_camera(P, i, R, t)
    if Z <= 1e-6:
        return 0.0, 0.0, X, Y, Z, False
    return fx * X / Z + cx, fy * Y / Z + cy, X, Y, Z, True


@njit(cache=True, nogil=True)
def reference_warp(P, Xr, R0, t0, R_wr, fx, fy, cx, cy, out):  # type: ignore[no-untyped-def]
    """What the fit needs of the reference view ``(R0, t0)`` (world-from-
    camera), per map point: ``out[i]`` (M, 7) = its pixel ``(u0, v0)`` there,
    ``A = (∂u/∂m)⁻¹`` (``a00, a01, a10, a11``: the local map-to-image
    warp's inverse, the surface taken fronto-parallel to the map's view
    ``R_wr`` around the point's map pixel ``Xr[i]``, depth ``Xr[i, 2]``),
    and 1 where the point is in front of that view with a warp that has an
    inverse, else 0. Fixed while the reference is: once per reference
    view, not per iteration."""
    R_0r = np.empty((3, 3))
    _rel(R0, t0, R_wr, R_0r)
    for i in range(P.shape[0]):
        out[i, :] = 0.0
        u0, v0, X0, Y0, Z0, front = _project(P, i, R0, t0, fx, fy, cx, cy)
        if not front:
            continue
        # du/dm at T0: dpi/dX0 . R_0r . d [1/fx 0; 0 1/fy; 0 0]
        d = Xr[i, 2]
        c0x = R_0r[0, 0] * d / fx
        c0y = R_0r[1, 0] * d / fx
        c0z = R_0r[2, 0] * d / fx
        c1x = R_0r[0, 1] * d / fy
        c1y = R_0r[1, 1] * d / fy
        c1z = R_0r[2, 1] * d / fy
        iz = 1.0 / Z0
        a00 = fx * iz * (c0x - X0 * iz * c0z)
        a10 = fy * iz * (c0y - Y0 * iz * c0z)
        a01 = fx * iz * (c1x - X0 * iz * c1z)
        a11 = fy * iz * (c1y - Y0 * iz * c1z)
        det = a00 * a11 - a01 * a10
        if abs(det) < 1e-9:
            continue
        out[i, 0] = u0
        out[i, 1] = v0
        out[i, 2] = a11 / det
        out[i, 3] = -a01 / det
        out[i, 4] = -a10 / det
        out[i, 5] = a00 / det
        out[i, 6] = 1.0


@njit(cache=True, nogil=True)
def _residuals(P, Xr, Lm, obs_img, corr, quiet, c, map_img, warp, R1, t1, fx, fy, cx, cy, with_jac, res, obs, prd,  # type: ignore[no-untyped-def]
               jac, ok, disp):
    """Per map point: residual ``r``, the observed increment ``obs`` (before
    the silent pixels' share takes the model's values: the fit's
    correlation uses it, so a wrong map or pose cannot look right through
    the model's own numbers), the predicted ``prd`` (and with ``with_jac``
    the residual's 6 Jacobian entries); ``ok`` false where the point is
    out of view (either pose: ``warp`` of :func:`reference_warp` for the
    reference's), or its ``m'`` off the map. Returns the number of points
    in view."""
    H, W = obs_img.shape
    Hm, Wm = map_img.shape
    n_ok = 0
    for i in range(P.shape[0]):
        ok[i] = False
        u1, v1, X, Y, Z, front = _project(P, i, R1, t1, fx, fy, cx, cy)
        if not (front and 1.0 <= u1 < W - 2.0 and 1.0 <= v1 < H - 2.0) or warp[i, 6] == 0.0:
            continue
        u0, v0 = warp[i, 0], warp[i, 1]
        b00, b01, b10, b11 = warp[i, 2], warp[i, 3], warp[i, 4], warp[i, 5]
        du, dv = u1 - u0, v1 - v0
        mx = Xr[i, 0] + b00 * du + b01 * dv
        my = Xr[i, 1] + b10 * du + b11 * dv
        if not (1.0 <= mx < Wm - 2.0 and 1.0 <= my < Hm - 2.0):
            continue
        lm2, gmx, gmy = _bilinear(map_img, mx, my)
        e, gex, gey = _bilinear(obs_img, u1, v1)
        e += corr[i]
        pred = Lm[i] - lm2
        obs[i] = e
        prd[i] = pred
        scale = 1.0
        q = quiet[i]
        if q > 0.0:  # pixels that did not fire: the model's change for them, within the threshold
            gap = pred - e
            if gap >= c:
                e += q * c
            elif gap <= -c:
                e -= q * c
            else:
                e += q * gap
                scale = 1.0 - q
        res[i] = e - pred
        disp[i] = math.sqrt(du * du + dv * dv)
        ok[i] = True
        n_ok += 1
        if with_jac:
            # dr/du1 = grad obs + A^T grad map(m')
            gu = gex + b00 * gmx + b10 * gmy
            gv = gey + b01 * gmx + b11 * gmy
            izz = 1.0 / Z
            jx0 = fx * izz
            jx2 = -fx * X * izz * izz
            jy1 = fy * izz
            jy2 = -fy * Y * izz * izz
            # dX/d(omega) = [X]x = [[0, -Z, Y], [Z, 0, -X], [-Y, X, 0]], dX/dv = -I
            du_w0 = jx2 * (-Y)
            du_w1 = jx0 * (-Z) + jx2 * X
            du_w2 = jx0 * Y
            dv_w0 = jy1 * Z + jy2 * (-Y)
            dv_w1 = jy2 * X
            dv_w2 = jy1 * (-X)
            gu *= scale
            gv *= scale
            jac[i, 0] = gu * du_w0 + gv * dv_w0
            jac[i, 1] = gu * du_w1 + gv * dv_w1
            jac[i, 2] = gu * du_w2 + gv * dv_w2
            jac[i, 3] = -gu * jx0
            jac[i, 4] = -gv * jy1
            jac[i, 5] = -(gu * jx2 + gv * jy2)
    return n_ok


@njit(cache=True, nogil=True)
def _rel(R0, t0, R_wr, out):  # type: ignore[no-untyped-def]
    """``R_0r = R0ᵀ R_wr`` (the map's view in the camera frame at T0)."""
    for a in range(3):
        for b in range(3):
            out[a, b] = R0[0, a] * R_wr[0, b] + R0[1, a] * R_wr[1, b] + R0[2, a] * R_wr[2, b]


@njit(cache=True, nogil=True)
def _robust_scale(res, ok, quiet, work):  # type: ignore[no-untyped-def]
    """1.4826 x the median ``|res|`` of the points in view (``ok``) mostly
    seen by firing pixels (``quiet <= 0.5``), of all in view when fewer than
    12 are (at least 1e-6); ``work`` (M,) scratch."""
    k = 0
    for i in range(res.shape[0]):
        if ok[i] and quiet[i] <= 0.5:
            work[k] = abs(res[i])
            k += 1
    if k < 12:
        k = 0
        for i in range(res.shape[0]):
            if ok[i]:
                work[k] = abs(res[i])
                k += 1
    return max(1.4826 * np.median(work[:k]), 1e-6) if k else 1e-6


@njit(cache=True, nogil=True)
def _normal_equations(res, jac, ok, thr, H, g):  # type: ignore[no-untyped-def]
    """``H = Jᵀ W J`` (6, 6) and ``g = Jᵀ W r`` (6,) over the points ``ok``, ``W``
    the Huber weights at ``thr``. The sums run in scalars (registers), point
    by point in order: the same numbers as accumulating into ``H``."""
    g0 = g1 = g2 = g3 = g4 = g5 = 0.0
    h00 = h01 = h02 = h03 = h04 = h05 = h11 = h12 = h13 = h14 = h15 = 0.0
    h22 = h23 = h24 = h25 = h33 = h34 = h35 = h44 = h45 = h55 = 0.0
    for i in range(res.shape[0]):
        if not ok[i]:
            continue
        r = res[i]
        w = 1.0 if abs(r) <= thr else thr / abs(r)
        j0, j1, j2, j3, j4, j5 = jac[i, 0], jac[i, 1], jac[i, 2], jac[i, 3], jac[i, 4], jac[i, 5]
        ja = w * j0
        g0 += ja * r
        h00 += ja * j0
        h01 += ja * j1
        h02 += ja * j2
        h03 += ja * j3
        h04 += ja * j4
        h05 += ja * j5
        ja = w * j1
        g1 += ja * r
        h11 += ja * j1
        h12 += ja * j2
        h13 += ja * j3
        h14 += ja * j4
        h15 += ja * j5
        ja = w * j2
        g2 += ja * r
        h22 += ja * j2
        h23 += ja * j3
        h24 += ja * j4
        h25 += ja * j5
        ja = w * j3
        g3 += ja * r
        h33 += ja * j3
        h34 += ja * j4
        h35 += ja * j5
        ja = w * j4
        g4 += ja * r
        h44 += ja * j4
        h45 += ja * j5
        ja = w * j5
        g5 += ja * r
        h55 += ja * j5
    g[0] = g0
    g[1] = g1
    g[2] = g2
    g[3] = g3
    g[4] = g4
    g[5] = g5
    H[0, 0] = h00
    H[0, 1] = H[1, 0] = h01
    H[0, 2] = H[2, 0] = h02
    H[0, 3] = H[3, 0] = h03
    H[0, 4] = H[4, 0] = h04
    H[0, 5] = H[5, 0] = h05
    H[1, 1] = h11
    H[1, 2] = H[2, 1] = h12
    H[1, 3] = H[3, 1] = h13
    H[1, 4] = H[4, 1] = h14
    H[1, 5] = H[5, 1] = h15
    H[2, 2] = h22
    H[2, 3] = H[3, 2] = h23
    H[2, 4] = H[4, 2] = h24
    H[2, 5] = H[5, 2] = h25
    H[3, 3] = h33
    H[3, 4] = H[4, 3] = h34
    H[3, 5] = H[5, 3] = h35
    H[4, 4] = h44
    H[4, 5] = H[5, 4] = h45
    H[5, 5] = h55


@njit(cache=True, nogil=True)
def fit_batch(P, Xr, Lm, obs_img, corr, quiet, c, map_img, warp, R1, t1, fx, fy, cx, cy, iters, huber_k,  # type: ignore[no-untyped-def]
              damping, stats):
    """Refine ``(R1, t1)`` in place (see the module). ``P`` (M, 3) world
    points, ``Xr`` (M, 3) their map pixel (x, y) and depth (m), ``Lm`` (M,)
    their map log intensity (blurred as ``map_img``), ``warp`` (M, 7)
    :func:`reference_warp` of the reference view, ``corr`` (M,) added to
    the observed increment at each point (:func:`point_corrections`: held
    through the iterations), ``quiet`` (M,) the share of silent pixels at
    each point (:func:`residue_image`'s ``quiet`` sampled at the points;
    zeros: none), ``c`` the contrast threshold. ``stats`` gets
    ``[points in view, correlation, rms residual, iterations, last step,
    median displacement (px) of the points in view from T0 to T1, the
    pose's uncertainty (rad)]``: the 1σ angle by which the scene may move
    within the covariance ``σ² (Jᵀ W J)⁻¹`` (``J`` and the Huber weights
    ``W`` of the last iteration) at the events' own noise, ``σ = c / √12``
    (an increment known to within one threshold; how well the model
    explains the events is the correlation's job, so a wrong reference
    does not inflate it), the position's σ over the
    mean depth of the points in view with the rotation's σ in quadrature
    (inf when no step was taken)."""
    M = P.shape[0]
    res = np.zeros(M)
    obs = np.zeros(M)
    prd = np.zeros(M)
    disp = np.zeros(M)
    jac = np.zeros((M, 6))
    ok = np.zeros(M, np.bool_)
    H = np.empty((6, 6))
    Hu = np.zeros((6, 6))  # the last undamped normal matrix, for the covariance
    have_h = False
    g = np.empty(6)
    dR = np.empty((3, 3))
    dt = np.empty(3)
    step = 0.0
    it = 0
    s = 1.0
    absr = np.empty(M)
    for it in range(iters):
        n_ok = _residuals(P, Xr, Lm, obs_img, corr, quiet, c, map_img, warp, R1, t1, fx, fy, cx, cy, True, res,
                          obs, prd, jac, ok, disp)
        if n_ok < 12:
            break
        if it == 0:  # the robust scale at the start
            s = _robust_scale(res, ok, quiet, absr)
        thr = huber_k * s
        _normal_equations(res, jac, ok, thr, H, g)
        tr = 0.0
        for a in range(6):
            tr += H[a, a]
        if tr <= 0.0:
            break
        Hu[:, :] = H
        have_h = True
        for a in range(6):
            H[a, a] += damping * H[a, a] + 1e-9 * tr
        delta = -np.linalg.solve(H, g)
        se3_exp_kernel(delta, dR, dt)
        # T1 <- T1 exp(delta)
        nt = R1 @ dt + t1
        R1[:, :] = R1 @ dR
        t1[:] = nt
        step = math.sqrt((delta * delta).sum())
        if step < 1e-5:  # rad and m: a few thousandths of a pixel
            break
    n_ok = _residuals(P, Xr, Lm, obs_img, corr, quiet, c, map_img, warp, R1, t1, fx, fy, cx, cy, False, res,
                      obs, prd, jac, ok, disp)
    k = 0
    for i in range(M):
        if ok[i]:
            absr[k] = disp[i]
            k += 1
    stats[5] = np.median(absr[:k]) if k else 0.0
    stats[6] = math.inf
    if have_h and k:
        z = 0.0
        for i in range(M):
            if ok[i]:
                z += _in_camera(P, i, R1, t1)[2]
        z /= k
        tr = 0.0
        for a in range(6):
            tr += Hu[a, a]
        for a in range(6):
            Hu[a, a] += 1e-9 * tr
        cov = np.linalg.inv(Hu)
        rot = cov[0, 0] + cov[1, 1] + cov[2, 2]
        stats[6] = c / math.sqrt(12.0) * math.sqrt(rot + (cov[3, 3] + cov[4, 4] + cov[5, 5]) / (z * z))
    so = 0.0
    sp = 0.0
    sop = 0.0
    rr = 0.0
    for i in range(M):
        if ok[i]:
            e = obs[i]
            pred = prd[i]
            so += e * e
            sp += pred * pred
            sop += e * pred
            rr += res[i] * res[i]
    stats[0] = n_ok
    stats[1] = sop / math.sqrt(so * sp) if so > 0 and sp > 0 else 0.0
    stats[2] = math.sqrt(rr / n_ok) if n_ok else math.inf
    stats[3] = it + 1
    stats[4] = step
