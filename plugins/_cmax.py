"""The contrast-maximisation (CMax) core: warps, the image of warped events
(IWE), its focus and the focus's analytic gradient, as numba kernels, for
``tracker.angular_velocity``, ``flow.contrast_max`` (its translation search
votes and scores each event with :func:`add_sq`) and any CMax method.

Contrast maximisation (Gallego, Rebecq & Scaramuzza, CVPR 2018; for
rotation Gallego & Scaramuzza, RA-L 2017, "Accurate angular velocity
estimation with an event camera") warps each event ``x_k`` observed at
``t_k`` to a reference time with candidate motion parameters ``θ``, votes
the warped points into an image, and picks the ``θ`` that makes that image
sharpest.

**Voting.** Each warped point (u, v) (px) votes with a separable quadratic
B-spline over its 3 x 3 nearest pixels (weights ``0.5 (0.5 - d)^2``,
``0.75 - d^2``, ``0.5 (0.5 + d)^2`` for an offset ``d`` in [-0.5, 0.5] from
the nearest pixel centre, summing to 1). That is bilinear voting followed
by a one-pixel box filter: a Gaussian-like blob of standard deviation
0.5 px. Plain bilinear votes make the focus piecewise quadratic in θ with a
gradient that jumps whenever a point crosses a pixel boundary, and favour
whole-pixel displacements; the B-spline's weights are C1 in (u, v), so the
focus is C1 in θ and a quasi-Newton optimiser sees a consistent gradient.

**Focus.** The sum of squares of the IWE, ``F = Σ_pixels I^2`` (:func:`focus`).
On a fixed image holding a fixed number of votes this is the IWE's variance
up to a constant (Gallego et al.'s measure, with the smoothing done by the
votes). Computing it costs O(events) per evaluation and never sweeps or
blurs the whole image: ``F = Σ_k Σ_{pixels of k} B_k I`` (each event's
3 x 3 weights dotted with the image), and its gradient with respect to the
warped positions is ``dF/du_k = 2 Σ_{pixels of k} I dB_k/du`` (likewise
v), so a vote pass, a gather pass and a clear pass give F and its exact
gradient. A Gaussian blur of the whole image per evaluation (the paper's
variance of the smoothed IWE) would cost ``H W`` work per evaluation
instead.

The whole image's sum of squares is biased when the events of a window do
not all stay in view: a warp that keeps them inside a smaller area makes
the same votes denser, so it scores higher (for a rotation: rates
underestimated by up to ~10 % at coarse IWE pixels, measured on simulated
scenes). :func:`rotation_focus_grad` therefore scores the **variance over a
fixed rectangle** ``R`` of the IWE, ``Σ_R I^2 - (Σ_R I)^2 / |R|``: its area
does not change with the warp, and the mean term removes the gain of
pulling votes into it. Its gradient needs, besides ``Σ_R I dB/du``, the
derivative of the votes' mass inside ``R``, non-zero only for events whose
3 x 3 votes straddle its edge (``Σ_{p in R} dB/du``; the B-spline's
derivatives sum to zero over all nine pixels).

**Rotational warp** (tracker.angular_velocity). An event's undistorted
normalised coordinates ``b = (x, y, 1)`` at time ``t`` are rotated to the
reference time ``t_ref`` by the camera's angular velocity ω (rad/s, camera
frame, OpenCV axes: x right, y down, z forward): ``b' = exp([ω dt]x) b``
with ``dt = t - t_ref`` (a static direction ``d`` seen at ``t`` is
``R(t)^T d``; with ``R(t) = R(t_ref) exp([ω dt]x)`` it is
``exp([ω dt]x) b`` at ``t_ref``), here to **first order** (small angle):
``b' = b + dt ω x b``, projected ``u = f_x X'/Z' + c_x``. The dropped
second-order term is ``|ω dt|^2 / 2`` rad: at 1000 °/s and 2.5 ms from
the reference (a 5 ms window) 0.0095 rad^2/2 = 0.05 mrad, under 0.01 px at
f = 200 px; at 20 ms from the reference it reaches about 0.6 px (even in
``dt``: both ends of a window shift alike, a blur rather than a bias).

All kernels are pure functions on arrays; callers validate and allocate.
The image passed in must be zero and is left zero.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["bspline", "vote_sq", "add_sq", "iwe", "focus", "focus_grad", "rotation_warp", "rotation_focus_grad",
           "maximise_rotation"]


# -- one point's votes ---------------------------------------------------------------------------
@njit(cache=True, nogil=True, inline="always")
def bspline(w):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Nearest pixel ``n`` of a coordinate ``w`` (px) and the quadratic
    B-spline weights of pixels n-1, n, n+1 with their derivatives in ``w``."""
    f = np.floor(w + 0.5)
    d = w - f
    a = 0.5 - d
    b = 0.5 + d
    return int(f), 0.5 * a * a, 0.75 - d * d, 0.5 * b * b, -a, -2.0 * d, b


@njit(cache=True, nogil=True, inline="always")
def vote_sq(img, u, v):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Vote the point (u, v) (px) into ``img``; returns ``(e, ix, iy)``: the
    increase ``e`` of the image's sum of squares (:func:`add_sq`), or -1.0
    when the point is too near the border to vote (nothing changed), and
    its nearest pixel."""
    ih, iw = img.shape
    fx = np.floor(u + 0.5)
    fy = np.floor(v + 0.5)
    ix, iy = int(fx), int(fy)
    if not (1 <= ix < iw - 1 and 1 <= iy < ih - 1):
        return -1.0, ix, iy
    return add_sq(img, ix, iy, u - fx, v - fy), ix, iy


@njit(cache=True, nogil=True, inline="always")
def add_sq(img, ix, iy, dx, dy):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Add the 3 x 3 votes of the point ``(ix + dx, iy + dy)`` (px, ``|dx|,
    |dy| <= 0.5``; the caller checks the bounds) to ``img`` and return the
    increase of the image's sum of squares: adding ``w`` to a pixel holding
    ``a`` adds ``2 a w + w^2``, and the ``w^2`` of the 3 x 3 votes is
    separable. (One float out and no early exit: the translation search of
    ``flow.contrast_max`` calls it in its innermost loop.)"""
    a, b = 0.5 - dx, 0.5 + dx
    ax0, ax1, ax2 = 0.5 * a * a, 0.75 - dx * dx, 0.5 * b * b
    a, b = 0.5 - dy, 0.5 + dy
    ay0, ay1, ay2 = 0.5 * a * a, 0.75 - dy * dy, 0.5 * b * b
    row = img[iy - 1]
    u0, u1, u2 = row[ix - 1], row[ix], row[ix + 1]
    row[ix - 1], row[ix], row[ix + 1] = u0 + ay0 * ax0, u1 + ay0 * ax1, u2 + ay0 * ax2
    e = ay0 * (ax0 * u0 + ax1 * u1 + ax2 * u2)
    row = img[iy]
    u0, u1, u2 = row[ix - 1], row[ix], row[ix + 1]
    row[ix - 1], row[ix], row[ix + 1] = u0 + ay1 * ax0, u1 + ay1 * ax1, u2 + ay1 * ax2
    e += ay1 * (ax0 * u0 + ax1 * u1 + ax2 * u2)
    row = img[iy + 1]
    u0, u1, u2 = row[ix - 1], row[ix], row[ix + 1]
    row[ix - 1], row[ix], row[ix + 1] = u0 + ay2 * ax0, u1 + ay2 * ax1, u2 + ay2 * ax2
    e += ay2 * (ax0 * u0 + ax1 * u1 + ax2 * u2)
    return 2.0 * e + (ax0 * ax0 + ax1 * ax1 + ax2 * ax2) * (ay0 * ay0 + ay1 * ay1 + ay2 * ay2)


@njit(cache=True, nogil=True, inline="always")
def _clear(img, u, v):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    ix = int(np.floor(u + 0.5))
    iy = int(np.floor(v + 0.5))
    for r in range(iy - 1, iy + 2):
        img[r, ix - 1] = 0.0
        img[r, ix] = 0.0
        img[r, ix + 1] = 0.0


@njit(cache=True, nogil=True, inline="always")
def _add9(img, ix, iy, dx, dy):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Add the 3 x 3 B-spline votes of a point ``(ix + dx, iy + dy)`` (px,
    ``|dx|, |dy| <= 0.5``) to ``img``; the caller checks the bounds. (No
    return value: a voting helper returning a tuple after an early exit ran
    3x slower, measured.)"""
    a, b = 0.5 - dx, 0.5 + dx
    ax0, ax1, ax2 = 0.5 * a * a, 0.75 - dx * dx, 0.5 * b * b
    a, b = 0.5 - dy, 0.5 + dy
    ay0, ay1, ay2 = 0.5 * a * a, 0.75 - dy * dy, 0.5 * b * b
    img[iy - 1, ix - 1] += ay0 * ax0
    img[iy - 1, ix] += ay0 * ax1
    img[iy - 1, ix + 1] += ay0 * ax2
    img[iy, ix - 1] += ay1 * ax0
    img[iy, ix] += ay1 * ax1
    img[iy, ix + 1] += ay1 * ax2
    img[iy + 1, ix - 1] += ay2 * ax0
    img[iy + 1, ix] += ay2 * ax1
    img[iy + 1, ix + 1] += ay2 * ax2


@njit(cache=True, nogil=True, inline="always")
def _gather9(img, ix, iy, ax0, ax1, ax2, dx0, dx1, dx2, ay0, ay1, ay2, dy0, dy1, dy2):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """(Σ B I, Σ dB/du I, Σ dB/dv I) over the 3 x 3 pixels around (ix, iy)
    with the given separable weights and derivatives."""
    a0, a1, a2 = img[iy - 1, ix - 1], img[iy - 1, ix], img[iy - 1, ix + 1]
    h0 = ax0 * a0 + ax1 * a1 + ax2 * a2
    k0 = dx0 * a0 + dx1 * a1 + dx2 * a2
    a0, a1, a2 = img[iy, ix - 1], img[iy, ix], img[iy, ix + 1]
    h1 = ax0 * a0 + ax1 * a1 + ax2 * a2
    k1 = dx0 * a0 + dx1 * a1 + dx2 * a2
    a0, a1, a2 = img[iy + 1, ix - 1], img[iy + 1, ix], img[iy + 1, ix + 1]
    h2 = ax0 * a0 + ax1 * a1 + ax2 * a2
    k2 = dx0 * a0 + dx1 * a1 + dx2 * a2
    return ay0 * h0 + ay1 * h1 + ay2 * h2, ay0 * k0 + ay1 * k1 + ay2 * k2, dy0 * h0 + dy1 * h1 + dy2 * h2


@njit(cache=True, nogil=True, inline="always")
def _gather(img, u, v):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """For a point that voted: (Σ B I, Σ dB/du I, Σ dB/dv I) over its 3 x 3 pixels."""
    ix, ax0, ax1, ax2, dx0, dx1, dx2 = bspline(u)
    iy, ay0, ay1, ay2, dy0, dy1, dy2 = bspline(v)
    return _gather9(img, ix, iy, ax0, ax1, ax2, dx0, dx1, dx2, ay0, ay1, ay2, dy0, dy1, dy2)


# -- on warped positions ---------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def iwe(u, v, img):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The image of warped events: every point (u[k], v[k]) (px) voted into
    ``img`` (added, not cleared); returns the number that voted."""
    m = 0
    for k in range(u.shape[0]):
        if vote_sq(img, u[k], v[k])[0] >= 0.0:
            m += 1
    return m


@njit(cache=True, nogil=True)
def focus(u, v, img):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Sum of squares of the IWE of the points (u, v) (px); ``img`` zero
    on entry, zero on return."""
    s = 0.0
    for k in range(u.shape[0]):
        e, _, _ = vote_sq(img, u[k], v[k])
        if e >= 0.0:
            s += e
    ih, iw = img.shape
    for k in range(u.shape[0]):
        if 1 <= np.floor(u[k] + 0.5) < iw - 1 and 1 <= np.floor(v[k] + 0.5) < ih - 1:
            _clear(img, u[k], v[k])
    return s


@njit(cache=True, nogil=True)
def focus_grad(u, v, img, gu, gv):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Sum of squares ``F`` of the IWE of the points (u, v) (px) and its
    gradient ``gu[k] = dF/du[k]``, ``gv[k] = dF/dv[k]`` (0 for points that
    do not vote); ``img`` zero on entry, zero on return."""
    ih, iw = img.shape
    n = u.shape[0]
    for k in range(n):
        vote_sq(img, u[k], v[k])
    s = 0.0
    for k in range(n):
        gu[k] = 0.0
        gv[k] = 0.0
        if 1 <= np.floor(u[k] + 0.5) < iw - 1 and 1 <= np.floor(v[k] + 0.5) < ih - 1:
            a, b, c = _gather(img, u[k], v[k])
            s += a
            gu[k] = 2.0 * b
            gv[k] = 2.0 * c
    for k in range(n):
        if 1 <= np.floor(u[k] + 0.5) < iw - 1 and 1 <= np.floor(v[k] + 0.5) < ih - 1:
            _clear(img, u[k], v[k])
    return s


# -- rotation ------------------------------------------------------------------------------------------
@njit(cache=True, nogil=True, inline="always")
def _rot(x, y, dt, wx, wy, wz, cam):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """First-order rotated point: (X', Y', Z') and its projection (u, v) px."""
    X = x + dt * (wy - wz * y)
    Y = y + dt * (wz * x - wx)
    Z = 1.0 + dt * (wx * y - wy * x)
    iz = 1.0 / Z
    return X, Y, Z, iz, cam[0] * X * iz + cam[2], cam[1] * Y * iz + cam[3]


@njit(cache=True, nogil=True)
def rotation_warp(x, y, dt, w, cam, u, v):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Warp events with undistorted normalised coordinates (x, y) seen
    ``dt`` s after the reference time to it, under angular velocity ``w``
    (3,) rad/s (first order, see the module), projected with
    ``cam = (s fx, s fy, s cx + margin, s cy + margin)`` px into ``u, v``."""
    for k in range(x.shape[0]):
        _, _, _, _, uk, vk = _rot(x[k], y[k], dt[k], w[0], w[1], w[2], cam)
        u[k] = uk
        v[k] = vk


@njit(cache=True, nogil=True, inline="always")
def _masked(w, lo, hi):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """B-spline weights and derivatives of ``w`` with those of pixels outside
    ``[lo, hi]`` set to zero: ``(n, a0, a1, a2, d0, d1, d2)``."""
    n, a0, a1, a2, d0, d1, d2 = bspline(w)
    if n - 1 < lo or n - 1 > hi:
        a0 = d0 = 0.0
    if n < lo or n > hi:
        a1 = d1 = 0.0
    if n + 1 < lo or n + 1 > hi:
        a2 = d2 = 0.0
    return n, a0, a1, a2, d0, d1, d2


@njit(cache=True, nogil=True, fastmath=True)
def rotation_focus_grad(x, y, dt, w, cam, img, u, v, grad, rect):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Focus ``F(ω)`` of the events warped by ``w`` (see
    :func:`rotation_warp`) and its gradient ``grad`` (3,) (F per rad/s).

    ``F`` is the IWE's variance over the rectangle ``rect = (c0, c1, r0,
    r1)`` of IWE pixels (inclusive) times its area ``A``: ``Σ_R I^2 -
    (Σ_R I)^2 / A``. Counting only a fixed region removes the bias of the
    whole IWE's sum of squares towards warps that shrink the warped events'
    support (an underestimated ω keeps the events of a window inside a
    smaller area, denser, so its plain sum of squares is larger); the mean
    term removes the gain of pulling votes into the region. ``u, v`` are
    scratch (n,), ``img`` zero on entry and return. Returns ``(F, number of
    events that voted)``."""
    n = x.shape[0]
    wx, wy, wz = w[0], w[1], w[2]
    c0r, c1r, r0r, r1r = int(rect[0]), int(rect[1]), int(rect[2]), int(rect[3])
    area = float((c1r - c0r + 1) * (r1r - r0r + 1))
    ih, iw = img.shape
    r0, r1, c0, c1 = ih, -1, iw, -1
    m = 0
    for k in range(n):
        _, _, _, _, uk, vk = _rot(x[k], y[k], dt[k], wx, wy, wz, cam)
        u[k] = uk
        v[k] = vk
        fx = np.floor(uk + 0.5)
        fy = np.floor(vk + 0.5)
        ix, iy = int(fx), int(fy)
        if 1 <= ix < iw - 1 and 1 <= iy < ih - 1:
            _add9(img, ix, iy, uk - fx, vk - fy)
            m += 1
            r0, r1, c0, c1 = min(r0, iy), max(r1, iy), min(c0, ix), max(c1, ix)
        else:
            u[k] = -1e9  # marks "did not vote"
    s = mass = 0.0
    g0 = g1 = g2 = 0.0  # d(Σ_R I^2)/dω / 2
    h0 = h1 = h2 = 0.0  # d(Σ_R I)/dω
    fx, fy = cam[0], cam[1]
    for k in range(n):
        uk, vk = u[k], v[k]
        if uk < -1e8:
            continue
        ix = int(np.floor(uk + 0.5))
        iy = int(np.floor(vk + 0.5))
        if c0r < ix < c1r and r0r < iy < r1r:  # all nine pixels inside: mass 1, its derivative 0
            _, ax0, ax1, ax2, dx0, dx1, dx2 = bspline(uk)
            _, ay0, ay1, ay2, dy0, dy1, dy2 = bspline(vk)
            a, gu, gv = _gather9(img, ix, iy, ax0, ax1, ax2, dx0, dx1, dx2, ay0, ay1, ay2, dy0, dy1, dy2)
            mu = mv = 0.0
            mass += 1.0
        elif ix + 1 < c0r or ix - 1 > c1r or iy + 1 < r0r or iy - 1 > r1r:
            continue
        else:
            _, ax0, ax1, ax2, dx0, dx1, dx2 = _masked(uk, c0r, c1r)
            _, ay0, ay1, ay2, dy0, dy1, dy2 = _masked(vk, r0r, r1r)
            a, gu, gv = _gather9(img, ix, iy, ax0, ax1, ax2, dx0, dx1, dx2, ay0, ay1, ay2, dy0, dy1, dy2)
            sx = ax0 + ax1 + ax2
            sy = ay0 + ay1 + ay2
            mass += sx * sy
            mu = (dx0 + dx1 + dx2) * sy
            mv = sx * (dy0 + dy1 + dy2)
        s += a
        xk, yk, dk = x[k], y[k], dt[k]
        X, Y, Z, iz, _, _ = _rot(xk, yk, dk, wx, wy, wz, cam)
        # d(u, v)/dω with dX = dt (0, 1, -y), dY = dt (-1, 0, x), dZ = dt (y, -x, 0)
        pu = X * iz
        pv = Y * iz
        ju0, ju1, ju2 = -pu * yk, 1.0 + pu * xk, -yk
        jv0, jv1, jv2 = -1.0 - pv * yk, pv * xk, xk
        cu = fx * iz * dk
        cv = fy * iz * dk
        g0 += cu * gu * ju0 + cv * gv * jv0
        g1 += cu * gu * ju1 + cv * gv * jv1
        g2 += cu * gu * ju2 + cv * gv * jv2
        if mu != 0.0 or mv != 0.0:
            h0 += cu * mu * ju0 + cv * mv * jv0
            h1 += cu * mu * ju1 + cv * mv * jv1
            h2 += cu * mu * ju2 + cv * mv * jv2
    for r in range(r0 - 1, r1 + 2):  # the votes' bounding box: one sweep, cheaper than per-event clears
        for c in range(c0 - 1, c1 + 2):
            img[r, c] = 0.0
    mean = mass / area
    grad[0] = 2.0 * (g0 - mean * h0)
    grad[1] = 2.0 * (g1 - mean * h1)
    grad[2] = 2.0 * (g2 - mean * h2)
    return s - mass * mean, m


@njit(cache=True, nogil=True)
def maximise_rotation(x, y, dt, w0, H, cam, img, u, v, max_iter, tol, rect):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Maximise the focus over ω (rad/s) from ``w0`` by BFGS on ``-F/n``
    with a backtracking (Armijo) line search; stops when a step moves ω by
    less than ``tol`` rad/s or after ``max_iter`` iterations. ``H`` (3, 3)
    is the inverse-Hessian estimate to start from and is updated in place
    (a window warm-started from the previous one keeps its curvature, so it
    usually converges in a few steps); ``H[0, 0] <= 0`` means none: the
    first step is then a gradient step scaled to move the events at the
    window's ends by about one IWE pixel. ``rect`` is the focus region (see
    :func:`rotation_focus_grad`). Returns ``(ω (3,), F at ω, events that
    voted, evaluations)``."""
    n = max(x.shape[0], 1)
    w = w0.astype(np.float64)
    g = np.empty(3)
    f, m = rotation_focus_grad(x, y, dt, w, cam, img, u, v, g, rect)
    f = -f / n
    g = -g / n
    span = 0.0
    for k in range(dt.shape[0]):
        span = max(span, abs(dt[k]))
    first = not H[0, 0] > 0.0
    if first:
        H[:, :] = np.eye(3)
    evals = 1
    wn = np.empty(3)
    gn = np.empty(3)
    for _ in range(max_iter):
        p = -(H @ g)
        gp = g @ p
        if not gp < 0.0:  # not a descent direction: restart from the gradient
            H[:, :] = np.eye(3)
            p = -g.copy()
            gp = g @ p
            first = True
        if first:
            pn = np.sqrt(p @ p)
            if pn == 0.0:
                break
            scale = 1.0 / (max(cam[0], 1.0) * max(span, 1e-6) * pn)  # ~1 px at the window's ends
            p = p * scale
            gp = gp * scale
        step = 1.0
        ok = False
        fn = f
        mn = m
        for _ls in range(10):
            for j in range(3):
                wn[j] = w[j] + step * p[j]
            fn, mn = rotation_focus_grad(x, y, dt, wn, cam, img, u, v, gn, rect)
            evals += 1
            fn = -fn / n
            if fn <= f + 1e-4 * step * gp:
                ok = True
                break
            step *= 0.5
        if not ok:
            break
        for j in range(3):
            gn[j] = -gn[j] / n
        s = wn - w
        yv = gn - g
        sy = s @ yv
        if first and sy > 0.0:
            H[:, :] = np.eye(3) * (sy / (yv @ yv))  # Shanno's scaling of the first estimate
        if sy > 1e-300:
            rho = 1.0 / sy
            Hy = H @ yv
            H[:, :] = H + (rho * rho * (yv @ Hy) + rho) * np.outer(s, s) - rho * (np.outer(Hy, s) + np.outer(s, Hy))
        first = False
        w[:] = wn
        g[:] = gn
        f, m = fn, mn
        if np.sqrt(s @ s) < tol:
            break
    return w, -f * n, m, evals
