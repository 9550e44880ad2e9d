"""Kernel of ``tracker.clusters``: a rectangular cluster tracker, event by event.

State (explicit arrays, see :func:`new_state`):

* ``cl`` (K, NCOL) float64, one row per live cluster (rows ``0..n-1``), the
  columns named below (positions px, velocities px/s, times µs, capture
  half sizes squared px²);
* ``ids`` (K,) int64: the public id, -1 while the cluster has never been
  visible (noise seeds many clusters that never show: they take no id);
* ``meta`` (4,) int64: live clusters ``n``, next public id, next output
  time (µs, -1 before the first event), whether velocity prediction is on.

Parameters in one float64 array ``par`` (indices below). Times are µs; the
mass of a cluster decays as ``exp(-dt / tau)``, so it is a count of recent
events and ``mass / tau`` its event rate.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["NCOL", "NPAR", "new_state", "clusters_kernel", "OUT_COLS"]

# cluster columns
X, Y, VX, VY, MASS, TLAST, VARX, VARY, XREF, YREF, TREF, TEXP, NVEL, RX, RY = range(15)
NCOL = 15
# parameters
(P_RADIUS, P_MIX, P_TAU, P_MIN_MASS, P_PRUNE, P_UPDATE, P_VEL_DT, P_VEL_TAU, P_MERGE, P_MAX_RADIUS,
 P_LN_PRUNE) = range(11)
NPAR = 11
# output columns (float64): x, y, vx, vy, width, height, mass
OUT_COLS = 7
#: Capture half size over the half width of the cluster's box: above 1, so
#: that a cluster grows to its object (events taken inside a box of half
#: width ``a`` alone give back exactly ``a``: the box could never grow).
GROW = 1.5
# counters
C_SEEDED, C_EVICTED, C_MERGED, C_PRUNED = range(4)


def new_state(max_clusters: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Empty state for at most ``max_clusters`` clusters: ``(cl, ids, meta)``."""
    meta = np.zeros(4, np.int64)
    meta[1] = 1
    meta[2] = -1
    return np.zeros((max_clusters, NCOL)), np.full(max_clusters, -1, np.int64), meta


@njit(cache=True, inline="always")
def _remove(cl: np.ndarray, ids: np.ndarray, k: int, n: int) -> int:
    """Drop cluster ``k`` (the last row moves into its place); the new count."""
    n -= 1
    if k != n:
        cl[k, :] = cl[n, :]
        ids[k] = ids[n]
    ids[n] = -1
    return n


@njit(cache=True, inline="always")
def _refresh(cl: np.ndarray, k: int, par: np.ndarray) -> None:
    """After an update: the earliest time (µs) the cluster could fall below
    the prune mass (``TEXP``: its mass is at least 1 after an event, so not
    before ``tau ln(1 / prune)``; the exact test waits until then), and the
    squared capture half sizes (px²): ``GROW`` times the half width of a
    uniform box with the cluster's variance, within ``radius .. max_radius``."""
    cl[k, TEXP] = cl[k, TLAST] + par[P_TAU] * par[P_LN_PRUNE]
    lo = par[P_RADIUS] * par[P_RADIUS]
    hi = par[P_MAX_RADIUS] * par[P_MAX_RADIUS]
    cl[k, RX] = min(hi, max(lo, 3.0 * GROW * GROW * cl[k, VARX]))
    cl[k, RY] = min(hi, max(lo, 3.0 * GROW * GROW * cl[k, VARY]))


@njit(cache=True, inline="always")
def _decay(gap: float, table: np.ndarray, tau: float) -> float:
    """``exp(-gap / tau)`` for a gap in whole µs: from the table when it is short."""
    g = int(gap)
    if g < table.shape[0]:
        return table[g]
    return math.exp(-gap / tau)


@njit(cache=True, inline="always")
def _visible_until(cl: np.ndarray, k: int, par: np.ndarray) -> float:
    """The time (µs) cluster ``k``'s decayed mass falls below the visibility mass."""
    if cl[k, MASS] < par[P_MIN_MASS]:
        return -1.0
    return cl[k, TLAST] + par[P_TAU] * math.log(cl[k, MASS] / par[P_MIN_MASS])


@njit(cache=True, inline="always")
def _row(cl: np.ndarray, k: int, t: float, par: np.ndarray, out: np.ndarray, r: int) -> None:
    out[r, 0] = cl[k, X]
    out[r, 1] = cl[k, Y]
    out[r, 2] = cl[k, VX]
    out[r, 3] = cl[k, VY]
    out[r, 4] = math.sqrt(12.0 * cl[k, VARX])
    out[r, 5] = math.sqrt(12.0 * cl[k, VARY])
    out[r, 6] = cl[k, MASS] * math.exp(-(t - cl[k, TLAST]) / par[P_TAU])


@njit(cache=True, inline="always")
def _merge(cl: np.ndarray, ids: np.ndarray, k: int, n: int, t: float, par: np.ndarray, table: np.ndarray,
           counts: np.ndarray) -> tuple[int, int]:
    """Merge every cluster whose centre lies within ``merge`` times the
    larger capture half size of cluster ``k``'s (per axis) into the heavier
    of the two. Returns the new count and the surviving row of ``k``."""
    f2 = par[P_MERGE] * par[P_MERGE]
    tau = par[P_TAU]
    j = 0
    while j < n:
        dx = cl[j, X] - cl[k, X]
        dy = cl[j, Y] - cl[k, Y]
        if j == k or dx * dx > f2 * max(cl[j, RX], cl[k, RX]) or dy * dy > f2 * max(cl[j, RY], cl[k, RY]):
            j += 1
            continue
        mk = cl[k, MASS] * _decay(t - cl[k, TLAST], table, tau)
        mj = cl[j, MASS] * _decay(t - cl[j, TLAST], table, tau)
        a, b = (k, j) if mk >= mj else (j, k)  # a survives
        ma, mb = max(mk, mj), min(mk, mj)
        if ids[a] < 0 or (ids[b] >= 0 and ids[b] < ids[a]):
            ids[a] = ids[b]  # the older public id lives on
        w = mb / (ma + mb)
        for col in (X, Y, VX, VY, VARX, VARY):
            cl[a, col] += w * (cl[b, col] - cl[a, col])
        cl[a, MASS] = ma + mb
        cl[a, TLAST] = t
        _refresh(cl, a, par)
        counts[C_MERGED] += 1
        last = n - 1
        n = _remove(cl, ids, b, n)
        if a == last:  # the survivor moved into b's row
            a = b
        k = a
        j = 0
    return n, k


@njit(cache=True)
def _emit_grid(cl: np.ndarray, ids: np.ndarray, n: int, T: float, par: np.ndarray, out_t: np.ndarray,
               out_id: np.ndarray, out: np.ndarray, r: int) -> tuple[int, float]:
    """Rows of the clusters visible at ``T``; returns the new row count and
    the last time (µs) any cluster with an id stays visible without events."""
    horizon = -1.0
    for k in range(n):
        if ids[k] < 0:
            continue
        until = _visible_until(cl, k, par)
        horizon = max(horizon, until)
        if until >= T:
            out_t[r] = np.int64(T)
            out_id[r] = ids[k]
            _row(cl, k, T, par, out, r)
            r += 1
    return r, horizon


@njit(cache=True, nogil=True)
def clusters_kernel(t, x, y, start, watermark, cl, ids, meta, par, table, counts, out_t, out_id, out):  # type: ignore[no-untyped-def]
    """Process events ``start..`` (times ``t`` µs, pixels ``x``, ``y``) and
    then the output times before ``watermark`` (µs), updating the state in
    place, until done or until the output ``out_t, out_id, out`` could
    overflow. ``table[g] = exp(-g / tau)`` for gaps of ``g`` whole µs.

    Each event: clusters whose mass has decayed below the prune mass are
    dropped (looked for only once the event's time passes the earliest
    time any cluster could fall that low); the event joins the nearest live
    cluster (L-inf distance) whose capture box holds it (half sizes ``GROW sqrt(3 var)`` per axis,
    within ``radius .. max_radius`` px), else seeds a new one (when all
    ``K`` rows are taken, the never-visible cluster that took its last
    event longest ago is evicted; with none, the event is left out). The
    joined cluster's mass decays to ``t`` and gains 1; its centre moves by
    its velocity over the gap (prediction on) and then by ``mix`` of the way
    to the event; its variances per axis mix the same way; every
    ``vel_dt`` µs its velocity mixes towards the centre's displacement rate
    by ``dt / (dt + vel_tau)`` (the first sample sets it), and then (and when it is seeded) it merges
    with clusters whose centre lies within ``merge`` times the larger of the
    two capture boxes (so merges wait at most ``vel_dt`` µs of the cluster's
    events, and cost one pass per sample instead of one per event). A
    cluster becomes visible (and takes the next public id) when its mass
    reaches ``min_mass``.

    Output: with ``update`` > 0, at every multiple ``T`` of ``update`` µs
    (from the first event on) the state after all events at or before
    ``T``: one row per visible cluster (decayed mass >= ``min_mass``); with
    ``update`` = 0, one row per event that lands in a visible cluster, at the
    event's time. Returns ``(rows written, next event index, done)``: when
    not done the output was full; the caller resumes from that index with a
    fresh output (the state is consistent at every return).
    """
    K = cl.shape[0]
    cap = out_t.shape[0]
    radius = par[P_RADIUS]
    mix = par[P_MIX]
    tau = par[P_TAU]
    prune = par[P_PRUNE]
    update = par[P_UPDATE]
    predict = meta[3] != 0
    n = int(meta[0])
    r = 0
    i = start
    N = t.shape[0]
    min_texp = np.inf  # no cluster can be pruned before this time (µs)
    for k in range(n):
        min_texp = min(min_texp, cl[k, TEXP])
    while True:
        ti = float(t[i]) if i < N else float(watermark)  # outputs are due before this time
        if update > 0.0:
            if meta[2] < 0 and i < N:
                meta[2] = np.int64(math.ceil(ti / update) * update)
            while 0 <= meta[2] < ti:
                if r + K > cap:
                    meta[0] = n
                    return r, i, False
                T = float(meta[2])
                r, horizon = _emit_grid(cl, ids, n, T, par, out_t, out_id, out, r)
                nxt = T + update
                if horizon < nxt:  # nothing visible until the next event: on to its grid time
                    if i >= N:
                        meta[2] = -1  # (set when it comes)
                        break
                    nxt = max(nxt, math.ceil(ti / update) * update)
                meta[2] = np.int64(nxt)
        if i >= N:
            meta[0] = n
            return r, N, True
        if update == 0.0 and r + 1 > cap:
            meta[0] = n
            return r, i, False
        ex = float(x[i])
        ey = float(y[i])
        if ti > min_texp:  # some cluster may have decayed below the prune mass
            k = 0
            min_texp = np.inf
            while k < n:
                if cl[k, TEXP] < ti:
                    m = cl[k, MASS] * _decay(ti - cl[k, TLAST], table, tau)
                    if m < prune:
                        n = _remove(cl, ids, k, n)
                        counts[C_PRUNED] += 1
                        continue
                    cl[k, TEXP] = cl[k, TLAST] + tau * math.log(cl[k, MASS] / prune)  # the exact time
                min_texp = min(min_texp, cl[k, TEXP])
                k += 1
        best = -1
        bd = np.inf
        for k in range(n):
            ax = abs(ex - cl[k, X])
            ay = abs(ey - cl[k, Y])
            d = max(ax, ay)
            if d < bd and ax * ax <= cl[k, RX] and ay * ay <= cl[k, RY]:
                bd = d
                best = k
        if best < 0:
            if n == K:
                victim = -1
                for k in range(n):
                    if ids[k] < 0 and (victim < 0 or cl[k, TLAST] < cl[victim, TLAST]):
                        victim = k
                if victim < 0:
                    i += 1
                    continue
                n = _remove(cl, ids, victim, n)
                counts[C_EVICTED] += 1
            for col in range(NCOL):
                cl[n, col] = 0.0
            cl[n, X] = ex
            cl[n, Y] = ey
            cl[n, XREF] = ex
            cl[n, YREF] = ey
            cl[n, TREF] = ti
            cl[n, VARX] = radius * radius / (3.0 * GROW * GROW)
            cl[n, VARY] = cl[n, VARX]
            cl[n, MASS] = 1.0
            cl[n, TLAST] = ti
            ids[n] = -1
            best = n
            n += 1
            counts[C_SEEDED] += 1
        else:
            c = best
            gap = ti - cl[c, TLAST]
            cl[c, MASS] = cl[c, MASS] * _decay(gap, table, tau) + 1.0
            if predict:
                cl[c, X] += cl[c, VX] * gap * 1e-6
                cl[c, Y] += cl[c, VY] * gap * 1e-6
            dx = ex - cl[c, X]
            dy = ey - cl[c, Y]
            cl[c, X] += mix * dx
            cl[c, Y] += mix * dy
            cl[c, VARX] += mix * (dx * dx - cl[c, VARX])
            cl[c, VARY] += mix * (dy * dy - cl[c, VARY])
            cl[c, TLAST] = ti
            dt = ti - cl[c, TREF]
            if dt >= par[P_VEL_DT]:
                ivx = (cl[c, X] - cl[c, XREF]) / (dt * 1e-6)
                ivy = (cl[c, Y] - cl[c, YREF]) / (dt * 1e-6)
                if cl[c, NVEL] == 0.0:
                    cl[c, VX] = ivx
                    cl[c, VY] = ivy
                else:
                    a = dt / (dt + par[P_VEL_TAU])
                    cl[c, VX] += a * (ivx - cl[c, VX])
                    cl[c, VY] += a * (ivy - cl[c, VY])
                cl[c, NVEL] += 1.0
                cl[c, XREF] = cl[c, X]
                cl[c, YREF] = cl[c, Y]
                cl[c, TREF] = ti
        _refresh(cl, best, par)
        min_texp = min(min_texp, cl[best, TEXP])
        if cl[best, TREF] == ti:  # a velocity sample (or a seed): time to look for clusters to merge with
            n, best = _merge(cl, ids, best, n, ti, par, table, counts)
        if ids[best] < 0 and cl[best, MASS] >= par[P_MIN_MASS]:
            ids[best] = meta[1]
            meta[1] += 1
        if update == 0.0 and ids[best] >= 0:
            out_t[r] = t[i]
            out_id[r] = ids[best]
            _row(cl, best, ti, par, out, r)
            r += 1
        i += 1
