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
  the median absolute residual of all points to that first fit (scaled to
  a standard deviation), never below ``floor_us``, so wrongly dropped points
  can come back.

Either way the event itself must lie on the plane it reports (within the
threshold), so a noise event next to an edge does not borrow its flow.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["plane_fit_at", "plane_scratch"]


@njit(cache=True, nogil=True)
def plane_scratch(radius):  # type: ignore[no-untyped-def]
    """Scratch arrays for :func:`plane_fit_at` (px, py, pt, use, scratch, acc)."""
    m = (2 * radius + 1) ** 2
    return (np.empty(m), np.empty(m), np.empty(m), np.empty(m, np.bool_), np.empty(m), np.zeros(9))


@njit(cache=True, nogil=True, inline="always")
def _acc(acc, X, Y, Z, s):  # type: ignore[no-untyped-def]
    """Add (s = 1) or remove (s = -1) a point from the least-squares sums.
    Points are integers (px, px, µs), so the sums stay exact."""
    acc[0] += s
    acc[1] += s * X
    acc[2] += s * Y
    acc[3] += s * X * X
    acc[4] += s * X * Y
    acc[5] += s * Y * Y
    acc[6] += s * Z
    acc[7] += s * X * Z
    acc[8] += s * Y * Z


@njit(cache=True, nogil=True, inline="always")
def _solve(acc):  # type: ignore[no-untyped-def]
    """Least-squares plane ``t = a x + b y + c`` from the sums; (a, b, c, ok),
    not ok when the points do not span a plane (fewer than 3, or on a line)."""
    s1 = acc[0]
    if s1 < 3.0:
        return 0.0, 0.0, 0.0, False
    mx, my, mt = acc[1] / s1, acc[2] / s1, acc[6] / s1
    cxx = acc[3] - acc[1] * mx
    cxy = acc[4] - acc[1] * my
    cyy = acc[5] - acc[2] * my
    cxt = acc[7] - acc[1] * mt
    cyt = acc[8] - acc[2] * mt
    det = cxx * cyy - cxy * cxy
    if det <= 1e-6 * s1 * s1:
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


@njit(cache=True, nogil=True)
def plane_fit_at(sae, k, xi, yi, ti, radius, window_us, n_iter, reject_us, robust, robust_k, floor_us,
                 min_points, px, py, pt, use, scratch, acc):  # type: ignore[no-untyped-def]
    """Fit the plane around event (xi, yi, ti) on ``sae[k]`` (see the module
    docstring); scratch arrays from :func:`plane_scratch`.

    Returns ``(a, b, n_inliers, rms, ok)``: ``a, b`` the gradient in µs/px,
    ``rms`` the inliers' residual RMS in µs.
    """
    _, h, w = sae.shape
    for q in range(9):
        acc[q] = 0.0
    n = 0
    for dy in range(-radius, radius + 1):
        yy = yi + dy
        if yy < 0 or yy >= h:
            continue
        for dx in range(-radius, radius + 1):
            xx = xi + dx
            if xx < 0 or xx >= w:
                continue
            age = ti - sae[k, yy, xx]
            if age <= window_us:
                X, Y, Z = float(dx), float(dy), -float(age)
                px[n] = X
                py[n] = Y
                pt[n] = Z
                use[n] = True
                _acc(acc, X, Y, Z, 1.0)
                n += 1
    if n < min_points:
        return 0.0, 0.0, n, 0.0, False
    thr = reject_us
    if robust:
        # start from the youngest points: the edge being fitted is the most
        # recent thing around the event
        for j in range(n):
            scratch[j] = -pt[j]
        cut = 2.0 * _median(scratch, n) + floor_us
        for j in range(n):
            if -pt[j] > cut:
                use[j] = False
                _acc(acc, px[j], py[j], pt[j], -1.0)
    a, b, c, ok = _solve(acc)
    if not ok:
        return 0.0, 0.0, 0, 0.0, False
    if robust:
        # scale from the residuals of the youngest points to the first fit
        ss = 0.0
        for j in range(n):
            if use[j]:
                r = pt[j] - (a * px[j] + b * py[j] + c)
                ss += r * r
        thr = max(robust_k * np.sqrt(ss / acc[0]), floor_us)
    for _ in range(n_iter):
        changed = False
        for j in range(n):
            keep = abs(pt[j] - (a * px[j] + b * py[j] + c)) <= thr
            if keep != use[j]:
                changed = True
                use[j] = keep
                _acc(acc, px[j], py[j], pt[j], 1.0 if keep else -1.0)
        if not changed:
            break
        a, b, c, ok = _solve(acc)
        if not ok:
            return 0.0, 0.0, 0, 0.0, False
    # the event itself (dx = dy = 0, age 0) must lie on the plane it reports
    if abs(c) > thr:
        return a, b, 0, 0.0, False
    m = acc[0]
    if m < min_points:
        return a, b, int(m), 0.0, False
    ss = 0.0
    for j in range(n):
        if use[j]:
            r = pt[j] - (a * px[j] + b * py[j] + c)
            ss += r * r
    return a, b, int(m), np.sqrt(ss / m), True
