"""Local plane fits on the surface of active events (shared by ``flow.plane_fit``
and ``lifetime.plane_fit``).

Around an event at (x, y, t) the pixels of the same polarity that fired in
the last ``window_us`` give points (dx, dy, T - t). A plane
``T - t = a dx + b dy + c`` is fitted by least squares; ``(a, b)`` is the
time-surface gradient in µs/px and the normal flow is ``(a, b) / (a^2 + b^2)``.

Two ways to reject outliers:

* Benosman et al. (TNNLS 2014): refit after dropping points farther than a
  fixed ``reject_us`` from the plane, until nothing changes.
* robust: the first fit uses only the youngest points (age at most twice
  the median age plus ``floor_us``: the edge being fitted is the most recent
  thing around the event, an earlier edge still inside the window is much
  older); then the rejection threshold follows the data: ``robust_k`` times
  the residual RMS of those points to that first fit, never below
  ``floor_us``, so wrongly dropped points can come back.

Either way the event itself must lie on the plane it reports (within the
threshold), so a noise event next to an edge does not borrow its flow.

Speed (this runs once per event; a plain rewrite of the loops, same
results to rounding): the neighbourhood is gathered without branches on the
data (every pixel is written, only fresh ones advance the write index and
count in the sums), the nine least-squares sums live in registers and are
updated only for the points that change side (they are sums of integers, so
exact in any order), the 3x3 normal equations are solved in closed form
(centred 2x2 system), and the residual sum of squares of the final inliers
is collected by the pass that finds nothing left to change.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["plane_fit_at", "plane_scratch"]


#: fast-math flags of the fit: only reassociation (sums in any order: the
#: least-squares sums are sums of integers, so exact either way) and fused
#: multiply-add; no assumption about NaN/inf and no approximate division.
FASTMATH = {"reassoc", "contract", "nsz"}


@njit(cache=True, nogil=True)
def plane_scratch(radius):  # type: ignore[no-untyped-def]
    """Scratch for :func:`plane_fit_at`, room for every pixel of the
    (2 radius + 1)^2 neighbourhood: the fresh points' offsets px, py (px)
    and times pt (µs, relative), their inlier flags, and a work array."""
    m = (2 * radius + 1) ** 2
    return np.empty(m), np.empty(m), np.empty(m), np.empty(m, np.bool_), np.empty(m)


@njit(cache=True, nogil=True, inline="always")
def _solve(sums):  # type: ignore[no-untyped-def]
    """Least-squares plane ``t = a x + b y + c`` from the nine sums (closed
    form, centred 2x2 system); (a, b, c, ok), not ok when the points do not
    span a plane (fewer than 3, or on a line)."""
    s0, sx, sy, sxx, sxy, syy, sz, sxz, syz = sums
    if s0 < 3.0:
        return 0.0, 0.0, 0.0, False
    mx, my, mt = sx / s0, sy / s0, sz / s0
    cxx = sxx - sx * mx
    cxy = sxy - sx * my
    cyy = syy - sy * my
    cxt = sxz - sx * mt
    cyt = syz - sy * mt
    det = cxx * cyy - cxy * cxy
    if det <= 1e-6 * s0 * s0:
        return 0.0, 0.0, 0.0, False
    a = (cyy * cxt - cxy * cyt) / det
    b = (cxx * cyt - cxy * cxt) / det
    return a, b, mt - a * mx - b * my, True


@njit(cache=True, nogil=True, inline="always")
def _median(v, m):  # type: ignore[no-untyped-def]
    """The lower median of ``v[:m]`` by quickselect (reorders ``v``)."""
    k = (m - 1) // 2
    lo, hi = 0, m - 1
    while lo < hi:
        pivot = v[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while v[i] < pivot:
                i += 1
            while v[j] > pivot:
                j -= 1
            if i <= j:
                v[i], v[j] = v[j], v[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return v[k]


@njit(cache=True, nogil=True, inline="always", fastmath=FASTMATH)
def _toggle(sums, s, X, Y, Z):  # type: ignore[no-untyped-def]
    """``sums`` (nine least-squares sums) with the point (X, Y, Z) added
    ``s`` times (s = 1 add, -1 remove, 0 nothing)."""
    s0, sx, sy, sxx, sxy, syy, sz, sxz, syz = sums
    return (s0 + s, sx + s * X, sy + s * Y, sxx + s * X * X, sxy + s * X * Y, syy + s * Y * Y, sz + s * Z,
            sxz + s * X * Z, syz + s * Y * Z)


@njit(cache=True, nogil=True, inline="always", fastmath=FASTMATH)
def _gather(sae, k, xi, yi, ti, radius, window_us, px, py, pt):  # type: ignore[no-untyped-def]
    """The fresh neighbours (age <= ``window_us``) of (xi, yi) as points
    (dx, dy, -age) packed into ``px, py, pt``; returns (how many, their nine
    least-squares sums). Branch-free inside: every pixel is written, only
    fresh ones advance the write index and count in the sums."""
    _, h, w = sae.shape
    # the part of the neighbourhood inside the sensor (offsets, px)
    y0, y1 = max(-radius, -yi), min(radius, h - 1 - yi)
    x0, x1 = max(-radius, -xi), min(radius, w - 1 - xi)
    n = 0
    s0 = sx = sy = sxx = sxy = syy = sz = sxz = syz = 0.0
    for dy in range(y0, y1 + 1):
        Y = float(dy)
        for dx in range(x0, x1 + 1):
            age = ti - sae[k, yi + dy, xi + dx]
            f = age <= window_us
            X = float(dx)
            Z = -float(age) if f else 0.0
            px[n] = X
            py[n] = Y
            pt[n] = Z
            n += f
            u = 1.0 if f else 0.0
            s0 += u
            sx += u * X
            sy += u * Y
            sxx += u * X * X
            sxy += u * X * Y
            syy += u * Y * Y
            sz += Z
            sxz += X * Z
            syz += Y * Z
    return n, (s0, sx, sy, sxx, sxy, syy, sz, sxz, syz)


@njit(cache=True, nogil=True, fastmath=FASTMATH, inline="always")
def plane_fit_at(sae, k, xi, yi, ti, radius, window_us, n_iter, reject_us, robust, robust_k, floor_us,
                 min_points, scr):  # type: ignore[no-untyped-def]
    """Fit the plane around event (xi, yi, ti) on ``sae[k]`` (see the module
    docstring); ``scr`` the scratch tuple from :func:`plane_scratch`.

    Returns ``(a, b, n_inliers, rms, ok)``: ``a, b`` the gradient in µs/px,
    ``rms`` the inliers' residual RMS in µs.
    """
    px, py, pt, use, work = scr
    n, sums = _gather(sae, k, xi, yi, ti, radius, window_us, px, py, pt)
    if n < min_points:
        return 0.0, 0.0, n, 0.0, False
    thr = reject_us
    if robust:
        # start from the youngest points: the edge being fitted is the most
        # recent thing around the event
        for j in range(n):
            work[j] = -pt[j]
        cut = -(2.0 * _median(work, n) + floor_us)
        for j in range(n):
            keep = pt[j] >= cut
            use[j] = keep
            sums = _toggle(sums, 0.0 if keep else -1.0, px[j], py[j], pt[j])
    else:
        for j in range(n):
            use[j] = True
    a, b, c, ok = _solve(sums)
    if not ok:
        return 0.0, 0.0, 0, 0.0, False
    if robust:
        # scale from the residuals of the youngest points to the first fit
        ss = 0.0
        for j in range(n):
            r = pt[j] - (a * px[j] + b * py[j] + c)
            ss += r * r if use[j] else 0.0
        thr = max(robust_k * np.sqrt(ss / sums[0]), floor_us)
    have_ss = False
    ss = 0.0
    for _ in range(n_iter):
        changed = False
        ss = 0.0
        for j in range(n):
            r = pt[j] - (a * px[j] + b * py[j] + c)
            keep = abs(r) <= thr
            ss += r * r if keep else 0.0
            if keep != use[j]:  # rare: only then touch the sums
                changed = True
                use[j] = keep
                sums = _toggle(sums, 1.0 if keep else -1.0, px[j], py[j], pt[j])
        if not changed:
            have_ss = True  # nothing moved: ss is the inliers' residual sum
            break
        a, b, c, ok = _solve(sums)
        if not ok:
            return 0.0, 0.0, 0, 0.0, False
    # the event itself (dx = dy = 0, age 0) must lie on the plane it reports
    if abs(c) > thr:
        return a, b, 0, 0.0, False
    m = sums[0]
    if m < min_points:
        return a, b, int(m), 0.0, False
    if not have_ss:
        ss = 0.0
        for j in range(n):
            r = pt[j] - (a * px[j] + b * py[j] + c)
            ss += r * r if use[j] else 0.0
    return a, b, int(m), np.sqrt(ss / m), True
