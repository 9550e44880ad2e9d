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

The surface (:func:`new_surface`): int32 µs *relative* to a base time
(``base[0]``, int64), both polarities side by side (``S[row, col, k]``, so one
cache line holds a row of the window for both), and a border of ``radius``
empty pixels all around, so the (2 radius + 1)^2 window is read with fixed
loops and no bounds tests. Relative times stay below ``SPAN`` (2^30 µs, about
18 minutes): when an event would pass it, :func:`rebase` moves the base to
that event and shifts every pixel, clamping those that fell off to
``EMPTY``; a clamped pixel is older than ``SPAN > window_us`` either way, so
the results are exactly those of an int64 surface of absolute times.

The fit works on all window slots with a 0/1 weight (fresh or not, inlier or
not): every loop has a fixed length (a multiple of 32) and no
branch on the data, so it vectorises; the slots live in one scratch array.
The nine least-squares sums are sums of integers (exact in any order), so
recomputing them after a rejection round gives exactly the values an
incremental update would, and the 3x3 solve scaled by the point count works
on exact integers until its last division. Fast-math flags apply to a
numba function *inlined* into another only if the caller has them too:
callers either compile with :data:`FASTMATH` (``flow.plane_fit``) or call
the non-inlined :func:`plane_fit`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["EMPTY", "SPAN", "crossing_time", "new_surface", "rebase", "rel_time", "plane_fit_at", "plane_fit",
           "plane_scratch"]

#: int32 value of a pixel with no event (older than any window).
EMPTY = -(1 << 30)
#: relative times stay in [0, SPAN) µs; window_us must be below it.
SPAN = 1 << 30

#: rows of the scratch array (see :func:`plane_scratch`)
Z, F, U, W = 5, 6, 7, 8

#: fast-math flags of the fit: only reassociation (sums in any order: the
#: least-squares sums are sums of integers, so exact either way) and fused
#: multiply-add; no assumption about NaN/inf and no approximate division.
FASTMATH = {"reassoc", "contract", "nsz"}


def new_surface(sensor: tuple[int, int], radius: int) -> np.ndarray:
    """An empty surface of active events for fits of ``radius`` px:
    (H + 2 radius, W + 2 radius, 2) int32 µs relative to a base, index 1 = ON;
    pixel (x, y) is at ``[y + radius, x + radius]``."""
    w, h = sensor
    return np.full((h + 2 * radius, w + 2 * radius, 2), EMPTY, np.int32)


@njit(cache=True, nogil=True)
def rebase(sae, base, t):  # type: ignore[no-untyped-def]
    """Move ``base[0]`` to ``t`` (µs) and shift every pixel of ``sae`` so
    that absolute times are unchanged; pixels older than ``SPAN`` become
    ``EMPTY``."""
    shift = t - base[0]
    flat = sae.reshape(-1)
    for i in range(flat.shape[0]):
        flat[i] = max(np.int64(flat[i]) - shift, EMPTY)
    base[0] = t


@njit(cache=True, nogil=True, inline="always")
def rel_time(sae, base, t):  # type: ignore[no-untyped-def]
    """``t`` (µs) relative to the surface's base, rebasing first if needed."""
    if t - base[0] >= SPAN:
        rebase(sae, base, t)
    return t - base[0]


@njit(cache=True, nogil=True, inline="always")
def crossing_time(sae, last, burst_us, window_us, k, xi, yi, radius, t, ti):  # type: ignore[no-untyped-def]
    """The relative time (µs) to store and fit for an event of polarity ``k``
    at (xi, yi), absolute time ``t``, relative ``ti``: with ``burst_us > 0``
    an event that follows the pixel's previous event (same polarity) within
    ``burst_us`` belongs to the same edge crossing and keeps the crossing's
    first time. ``last`` (H, W) int64: each pixel's last event time + 1,
    signed by its polarity (0 = none); updated."""
    if burst_us <= 0:
        return ti
    prev = last[yi, xi]
    same = prev != 0 and (prev > 0) == (k == 1) and t - abs(prev) <= burst_us
    last[yi, xi] = t + 1 if k == 1 else -(t + 1)
    old = np.int64(sae[yi + radius, xi + radius, k])
    return old if same and ti - old <= window_us else ti


@njit(cache=True, nogil=True)
def plane_scratch(radius):  # type: ignore[no-untyped-def]
    """Scratch for :func:`plane_fit_at`: one (9, slots) float64 array (one
    array, not a tuple of them, so the per-event code holds no references
    to count), one column per window slot (row by row). Rows: the constant
    offsets dx, dy (px) and their products dx^2, dx dy, dy^2; per fit the
    relative times z (µs, 0 where not fresh), the fresh weight f, the inlier
    weight u (0/1) and a work row. The slots are padded with zero-weight
    slots to a multiple of 32, the block the compiler's vector loops take at
    once (a 25-slot loop would otherwise run in the scalar remainder)."""
    d = 2 * radius + 1
    m = d * d
    scr = np.zeros((9, (m + 31) // 32 * 32))
    for j in range(m):
        dx, dy = float(j % d - radius), float(j // d - radius)
        scr[0, j], scr[1, j], scr[2, j], scr[3, j], scr[4, j] = dx, dy, dx * dx, dx * dy, dy * dy
    return scr


@njit(cache=True, nogil=True, inline="always")
def _solve(sums):  # type: ignore[no-untyped-def]
    """Least-squares plane ``t = a x + b y + c`` from the nine sums (closed
    form, centred 2x2 system scaled by the point count ``s0``); (a, b, c,
    ok), not ok when the points do not span a plane (fewer than 3, or on a
    line). The sums are integers, so every product here is an exact integer
    (for windows up to 7x7 and seconds long), and each of a, b, c comes out
    of a single correctly rounded division: no chain of two divisions."""
    s0, sx, sy, sxx, sxy, syy, sz, sxz, syz = sums
    if s0 < 3.0:
        return 0.0, 0.0, 0.0, False
    cxx = s0 * sxx - sx * sx
    cxy = s0 * sxy - sx * sy
    cyy = s0 * syy - sy * sy
    cxt = s0 * sxz - sx * sz
    cyt = s0 * syz - sy * sz
    det = cxx * cyy - cxy * cxy
    if det <= 1e-6 * (s0 * s0) * (s0 * s0):
        return 0.0, 0.0, 0.0, False
    na = cyy * cxt - cxy * cyt
    nb = cxx * cyt - cxy * cxt
    return na / det, nb / det, (sz * det - na * sx - nb * sy) / (s0 * det), True


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


@njit(cache=True, nogil=True, fastmath=FASTMATH, inline="always")
def _sums(scr, mp):  # type: ignore[no-untyped-def]
    """The nine least-squares sums over the first ``mp`` slots, weighted by
    the inlier row (0/1)."""
    s0 = sx = sy = sxx = sxy = syy = sz = sxz = syz = 0.0
    for j in range(mp):
        w = scr[U, j]
        wz = w * scr[Z, j]
        s0 += w
        sx += w * scr[0, j]
        sy += w * scr[1, j]
        sxx += w * scr[2, j]
        sxy += w * scr[3, j]
        syy += w * scr[4, j]
        sz += wz
        sxz += wz * scr[0, j]
        syz += wz * scr[1, j]
    return s0, sx, sy, sxx, sxy, syy, sz, sxz, syz


@njit(cache=True, nogil=True, fastmath=FASTMATH, inline="always")
def _gather(sae, k, xi, yi, ti, radius, window_us, scr):  # type: ignore[no-untyped-def]
    """Window of (xi, yi) (sensor coordinates) on polarity ``k`` of the
    padded surface into ``scr``: row Z = relative time of fresh slots
    (age <= window_us), 0 elsewhere, row F = 1 for fresh slots; returns how
    many are fresh."""
    d = 2 * radius + 1
    n = 0.0
    for r in range(d):
        for c in range(d):
            age = ti - np.int64(sae[yi + r, xi + c, k])
            fr = 1.0 if age <= window_us else 0.0
            scr[Z, r * d + c] = -float(age) * fr
            scr[F, r * d + c] = fr
            n += fr
    return n


@njit(cache=True, nogil=True, fastmath=FASTMATH, inline="always")
def _round(scr, mp, a, b, c, thr):  # type: ignore[no-untyped-def]
    """One rejection round: keeps in row U the fresh slots within ``thr`` of
    the plane (a, b, c); returns (how many changed side, residual sum of
    squares of the kept slots). The refit's sums are a second pass, only
    needed when something changed."""
    changed = ss = 0.0
    for j in range(mp):
        zj = scr[Z, j]
        r = zj - (a * scr[0, j] + b * scr[1, j] + c)
        w = scr[F, j] if abs(r) <= thr else 0.0
        ss += w * (r * r)
        changed += abs(w - scr[U, j])
        scr[U, j] = w
    return changed, ss


@njit(cache=True, nogil=True, fastmath=FASTMATH, inline="always")
def _rss(scr, mp, a, b, c):  # type: ignore[no-untyped-def]
    """Residual sum of squares to the plane (a, b, c) of the inlier slots."""
    ss = 0.0
    for j in range(mp):
        r = scr[Z, j] - (a * scr[0, j] + b * scr[1, j] + c)
        ss += scr[U, j] * (r * r)
    return ss


@njit(cache=True, nogil=True, fastmath=FASTMATH, inline="always")
def plane_fit_at(sae, k, xi, yi, ti, radius, window_us, n_iter, reject_us, robust, robust_k, floor_us,  # type: ignore[no-untyped-def]
                 min_points, scr):
    """Fit the plane around event (xi, yi) (sensor px) at relative time
    ``ti`` (µs) on polarity ``k`` of the surface ``sae`` (see
    :func:`new_surface` and the module docstring); ``scr`` the scratch array
    from :func:`plane_scratch`.

    Returns ``(a, b, n_inliers, rms, ok)``: ``a, b`` the gradient in µs/px,
    ``rms`` the inliers' residual RMS in µs.
    """
    return _fit(sae, k, xi, yi, ti, radius, scr.shape[1], window_us, n_iter, reject_us, robust, robust_k,
                floor_us, min_points, scr)


@njit(cache=True, nogil=True, fastmath=FASTMATH, inline="always")
def _fit(sae, k, xi, yi, ti, radius, mp, window_us, n_iter, reject_us, robust, robust_k, floor_us, min_points,  # type: ignore[no-untyped-def]
         scr):
    """:func:`plane_fit_at` with the slot count ``mp`` (padded) given."""
    n = _gather(sae, k, xi, yi, ti, radius, window_us, scr)
    if n < min_points:
        return 0.0, 0.0, int(n), 0.0, False
    thr = reject_us
    if robust:
        # start from the youngest points: the edge being fitted is the most
        # recent thing around the event
        work = scr[W]
        nf = 0
        for j in range(mp):
            work[nf] = -scr[Z, j]
            nf += scr[F, j] > 0.0
        cut = -(2.0 * _median(work, nf) + floor_us)
        for j in range(mp):
            scr[U, j] = scr[F, j] if scr[Z, j] >= cut else 0.0
    else:
        for j in range(mp):
            scr[U, j] = scr[F, j]
    sums = _sums(scr, mp)
    a, b, c, ok = _solve(sums)
    if not ok:
        return 0.0, 0.0, 0, 0.0, False
    if robust:
        # scale from the residuals of the youngest points to the first fit
        ss = _rss(scr, mp, a, b, c)
        thr = max(robust_k * np.sqrt(ss / sums[0]), floor_us)
    have_ss = False
    ss = 0.0
    for _ in range(n_iter):
        changed, ss = _round(scr, mp, a, b, c, thr)
        if changed == 0.0:
            have_ss = True  # nothing moved: ss is the inliers' residual sum
            break
        sums = _sums(scr, mp)
        a, b, c, ok = _solve(sums)
        if not ok:
            return 0.0, 0.0, 0, 0.0, False
    # the event itself (dx = dy = 0, age 0) must lie on the plane it reports
    if abs(c) > thr:
        return a, b, 0, 0.0, False
    cnt = sums[0]
    if cnt < min_points:
        return a, b, int(cnt), 0.0, False
    if not have_ss:
        ss = _rss(scr, mp, a, b, c)
    return a, b, int(cnt), np.sqrt(ss / cnt), True


@njit(cache=True, nogil=True, fastmath=FASTMATH)
def plane_fit(sae, k, xi, yi, ti, radius, window_us, n_iter, reject_us, robust, robust_k, floor_us, min_points,  # type: ignore[no-untyped-def]
              scr):
    """:func:`plane_fit_at` as a function of its own, for kernels compiled
    without the fast-math flags (inlined there, the fit's loops would not
    vectorise)."""
    return plane_fit_at(sae, k, xi, yi, ti, radius, window_us, n_iter, reject_us, robust, robust_k, floor_us,
                        min_points, scr)
