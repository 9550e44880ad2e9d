"""Kernels of ``tracker.edge_align``: the event image and the 6-DoF
alignment of a semi-dense map's points to it (see
:mod:`tectum.plugins.tracker.edge_align`).

Conventions: a pose to estimate is camera-from-world ``(R, t)``, a point
``X`` (world, m) is seen at ``P = R X + t`` and projected by the pinhole
``(fx, fy, cx, cy)`` (px) of the undistorted view. An increment is a twist
``δ = (ω, v)`` (rad, m; rotation first, as :mod:`tectum.camera`) applied on
the left: ``(R, t) <- exp(δ) (R, t)``, so ``∂P/∂ω = -[P]x`` and
``∂P/∂v = I``.

Numerics: the residual of a point is ``r = 1 - E(u)`` with ``E`` the
blurred event image scaled to at most 1 (see :func:`normalise`), so the
residual is bounded (0 on the brightest edges, 1 far from any event) and a
point that lands where no event is has ``r = 1`` and a zero gradient: it
adds to the cost but never pulls the pose. Gauss-Newton with a
Levenberg-Marquardt damping: a step that raises the mean cost is taken back
and the damping grows tenfold.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tectum.camera import se3_exp_kernel, se3_log_kernel

__all__ = ["vote_events", "normalise", "gradients", "align", "INFO"]

#: Fields of :func:`align`'s ``info`` output, by index.
INFO = ("cost", "in_view", "overlap", "iterations")


@njit(cache=True, nogil=True)
def vote_events(xu, yu, img):  # type: ignore[no-untyped-def]
    """Add one vote per event at its undistorted position ``(xu, yu)`` (px),
    split bilinearly over the four pixels around it; events outside the
    image (or NaN) vote nowhere. ``img`` (H, W) is not cleared."""
    h, w = img.shape
    for i in range(xu.shape[0]):
        x, y = xu[i], yu[i]
        if not (x >= 0.0 and y >= 0.0 and x <= w - 1.0 and y <= h - 1.0):
            continue
        x0 = min(int(x), w - 2)
        y0 = min(int(y), h - 2)
        fx, fy = x - x0, y - y0
        img[y0, x0] += (1.0 - fx) * (1.0 - fy)
        img[y0, x0 + 1] += fx * (1.0 - fy)
        img[y0 + 1, x0] += (1.0 - fx) * fy
        img[y0 + 1, x0 + 1] += fx * fy


@njit(cache=True, nogil=True)
def normalise(img, scale):  # type: ignore[no-untyped-def]
    """``img / scale`` clipped to [0, 1], in place."""
    inv = 1.0 / scale
    h, w = img.shape
    for r in range(h):
        for c in range(w):
            v = img[r, c] * inv
            img[r, c] = 1.0 if v > 1.0 else v


@njit(cache=True, nogil=True)
def gradients(img, gx, gy):  # type: ignore[no-untyped-def]
    """Central differences of ``img`` (H, W) along x (columns) and y (rows),
    per px; one-sided on the border."""
    h, w = img.shape
    for r in range(h):
        for c in range(w):
            a, b = max(c - 1, 0), min(c + 1, w - 1)
            gx[r, c] = (img[r, b] - img[r, a]) / (b - a)
            a, b = max(r - 1, 0), min(r + 1, h - 1)
            gy[r, c] = (img[b, c] - img[a, c]) / (b - a)


@njit(cache=True, nogil=True)
def _bilinear(img, x, y):  # type: ignore[no-untyped-def]
    h, w = img.shape
    x0 = min(int(x), w - 2)
    y0 = min(int(y), h - 2)
    fx, fy = x - x0, y - y0
    return ((1.0 - fx) * (1.0 - fy) * img[y0, x0] + fx * (1.0 - fy) * img[y0, x0 + 1]
            + (1.0 - fx) * fy * img[y0 + 1, x0] + fx * fy * img[y0 + 1, x0 + 1])


@njit(cache=True, nogil=True)
def _system(points, R, t, cam, E, gx, gy, huber, margin, min_depth, H, g):  # type: ignore[no-untyped-def]
    """The Gauss-Newton system ``H``, ``g`` (zeroed here) of the points seen
    from ``(R, t)``; returns ``(mean robust cost, points in view, points
    on an edge (E >= 0.5))``."""
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    h, w = E.shape
    H[:, :] = 0.0
    g[:] = 0.0
    J = np.empty(6)
    cost = 0.0
    n = 0
    on = 0
    for i in range(points.shape[0]):
        X0, X1, X2 = points[i, 0], points[i, 1], points[i, 2]
        P0 = R[0, 0] * X0 + R[0, 1] * X1 + R[0, 2] * X2 + t[0]
        P1 = R[1, 0] * X0 + R[1, 1] * X1 + R[1, 2] * X2 + t[1]
        P2 = R[2, 0] * X0 + R[2, 1] * X1 + R[2, 2] * X2 + t[2]
        if P2 < min_depth:
            continue
        iz = 1.0 / P2
        u = fx * P0 * iz + cx
        v = fy * P1 * iz + cy
        if not (u >= margin and v >= margin and u <= w - 1.0 - margin and v <= h - 1.0 - margin):
            continue
        e = _bilinear(E, u, v)
        ex = _bilinear(gx, u, v)
        ey = _bilinear(gy, u, v)
        r = 1.0 - e
        n += 1
        if e >= 0.5:
            on += 1
        # G = ∂E/∂P; r = 1 - E, so ∂r/∂v = -G and ∂r/∂ω = -(P x G)
        G0 = ex * fx * iz
        G1 = ey * fy * iz
        G2 = -(ex * fx * P0 + ey * fy * P1) * iz * iz
        J[0] = -(P1 * G2 - P2 * G1)
        J[1] = -(P2 * G0 - P0 * G2)
        J[2] = -(P0 * G1 - P1 * G0)
        J[3] = -G0
        J[4] = -G1
        J[5] = -G2
        a = abs(r)
        if a <= huber:
            wt = 1.0
            cost += 0.5 * r * r
        else:
            wt = huber / a
            cost += huber * (a - 0.5 * huber)
        for j in range(6):
            wj = wt * J[j]
            g[j] += wj * r
            for k in range(j, 6):
                H[j, k] += wj * J[k]
    for j in range(6):
        for k in range(j):
            H[j, k] = H[k, j]
    return (cost / n if n else 1.0), n, on


@njit(cache=True, nogil=True)
def _prior(R, t, Rp, tp, prior, d):  # type: ignore[no-untyped-def]
    """The twist ``d = log((R, t) (Rp, tp)⁻¹)`` from the prior pose to the
    pose, and the prior's cost ``Σ prior_j d_j² / 2``."""
    Rd = R @ Rp.T
    se3_log_kernel(Rd, t - Rd @ tp, d)
    c = 0.0
    for j in range(6):
        c += 0.5 * prior[j] * d[j] * d[j]
    return c


@njit(cache=True, nogil=True)
def _total(points, R, t, Rp, tp, prior, cam, E, gx, gy, huber, margin, min_depth, H, g, d):  # type: ignore[no-untyped-def]
    """The system of the points and the prior together: ``(mean cost with
    the prior, points in view, points on an edge)``. The prior adds
    ``prior_j d_j² / 2`` to the points' summed cost (pseudo-observations;
    its Jacobian taken as the identity), so the mean is over the points."""
    cost, n, on = _system(points, R, t, cam, E, gx, gy, huber, margin, min_depth, H, g)
    pc = _prior(R, t, Rp, tp, prior, d)
    for j in range(6):
        H[j, j] += prior[j]
        g[j] += prior[j] * d[j]
    return cost + pc / max(n, 1), n, on


@njit(cache=True, nogil=True)
def align(points, R, t, Rp, tp, cam, E, gx, gy, huber, margin, min_depth, max_iter, tol, prior, info):  # type: ignore[no-untyped-def]
    """Move the camera-from-world pose ``(R, t)`` (updated in place) so the
    map ``points`` (N, 3, world, m) land on the bright pixels of the
    normalised event image ``E`` (H, W) with gradients ``gx``, ``gy``:
    Levenberg-Marquardt on the robust (Huber ``huber``) sum of
    ``(1 - E(u))²`` over the points that project inside the image less
    ``margin`` px and lie ``min_depth`` m or more in front of the camera,
    plus a prior that holds the pose near ``(Rp, tp)`` (the prediction;
    weights ``prior`` (6,) per rad² and m², twist order (ω, v)). Stops after ``max_iter``
    iterations or when a step is below ``tol`` (rad + m). ``info`` gets
    :data:`INFO`: the final mean cost, the points in view, the fraction of
    them on an edge (E >= 0.5), the iterations."""
    H = np.empty((6, 6))
    g = np.empty(6)
    d = np.empty(6)
    dR = np.empty((3, 3))
    dt = np.empty(3)
    Rb = R.copy()
    tb = t.copy()
    Hb = np.empty((6, 6))
    gb = np.empty(6)
    lam = 1e-3
    cost, n, on = _total(points, R, t, Rp, tp, prior, cam, E, gx, gy, huber, margin, min_depth, H, g, d)
    it = 0
    while it < max_iter and n >= 6:
        it += 1
        A = H.copy()
        for j in range(6):
            A[j, j] += lam * H[j, j] + 1e-12
        step = np.linalg.solve(A, -g)
        if not np.all(np.isfinite(step)):
            break
        se3_exp_kernel(step, dR, dt)
        Rb[:, :] = R
        tb[:] = t
        Hb[:, :] = H
        gb[:] = g
        R[:, :] = dR @ Rb
        t[:] = dR @ tb + dt
        c2, n2, on2 = _total(points, R, t, Rp, tp, prior, cam, E, gx, gy, huber, margin, min_depth, H, g, d)
        if c2 > cost or n2 < 6:  # worse: take it back, damp harder
            R[:, :] = Rb
            t[:] = tb
            H[:, :] = Hb
            g[:] = gb
            lam *= 10.0
            if lam > 1e4:
                break
            continue
        cost, n, on = c2, n2, on2
        lam = max(lam * 0.1, 1e-6)
        if math.sqrt(np.sum(step * step)) < tol:
            break
    info[0] = cost
    info[1] = n
    info[2] = on / n if n else 0.0
    info[3] = it


@njit(cache=True, nogil=True)
def consistent(depth, radius, rel_tol, min_count, keep):  # type: ignore[no-untyped-def]
    """``keep[r, c]`` true where the known depth (m, NaN unknown) has at
    least ``min_count`` known neighbours within ``radius`` px (a square)
    whose inverse depth is within ``rel_tol`` of its own: points on a
    surface stay, scattered depth outliers go (a radius outlier filter in
    the image)."""
    h, w = depth.shape
    for r in range(h):
        for c in range(w):
            d = depth[r, c]
            keep[r, c] = False
            if not d > 0:
                continue
            rho = 1.0 / d
            n = 0
            for rr in range(max(r - radius, 0), min(r + radius + 1, h)):
                for cc in range(max(c - radius, 0), min(c + radius + 1, w)):
                    e = depth[rr, cc]
                    if (rr != r or cc != c) and e > 0 and abs(1.0 / e - rho) <= rel_tol * rho:
                        n += 1
            keep[r, c] = n >= min_count
