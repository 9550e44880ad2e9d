"""The per-event loop of ``tracker.features``: events into the patches of
the live features, and an alignment (EKLT or ICP) whenever a patch has
collected enough new events. One numba kernel; its state is a handful of
arrays the operator owns (see :class:`FeatureState`'s columns below).

Each live feature keeps a ring of its latest events (those within its patch
plus a pixel, when they come) and a target window ``n_e`` (EKLT's choice:
the events it fires while moving about 1 px, :func:`._eklt.event_target`,
clipped to ``[min_events, capacity]``). Once the ring holds ``n_e`` events
and ``update_fraction * n_e`` of them are new since the last alignment, the
feature is aligned on its latest ``n_e`` events and one track row is
written, stamped at the event that completed the window. An alignment
places the feature where it was in the *middle* of its window (the events
are spread over the ~1 px it moved): the row extrapolates that position to
the row's time with the feature's velocity (the motion between the middles
of successive windows, smoothed; ``x, y`` in the state stay the middle's). The state depends
only on the events in order (never on how they were cut into packets).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._eklt import eklt_align, event_target, observed_patch
from ._icp import icp_align

__all__ = ["COLUMNS", "PARAMS", "track_events"]

#: Columns of the per-feature float state ``trk`` (T, len(COLUMNS)).
COLUMNS = ("x", "y", "theta", "phi", "quality", "xref", "yref", "alive", "n_e", "ox", "oy", "t_mid", "vx", "vy",
           "alignments")
X, Y, TH, PHI, Q, XR, YR, ALIVE, NE, OX, OY, TM, VX, VY, NA = range(len(COLUMNS))
#: Entries of the parameter vector ``prm``.
PARAMS = ("half", "contrast", "min_events", "update_fraction", "min_quality", "width", "height", "rotation",
          "max_iter", "method", "max_dist", "border")
(P_HALF, P_C, P_MIN, P_UPD, P_QMIN, P_W, P_H, P_ROT, P_ITER, P_METHOD, P_DIST, P_BORDER) = range(len(PARAMS))
#: ``prm[P_METHOD]``
EKLT, ICP = 0, 1
#: Entries of the counters ``stats``.
STATS = ("updates", "lost_residual", "lost_border")


@njit(cache=True)
def _window(ring: np.ndarray, cnt: np.ndarray, k: int, n: int, ex: np.ndarray, ey: np.ndarray,
            ep: np.ndarray) -> float:
    """The latest ``n`` events of feature ``k``'s ring, oldest first; returns
    the time of the middle one (µs)."""
    cap = ring.shape[1]
    head = cnt[k, 1]
    for a in range(n):
        s = (head - n + a) % cap
        ex[a] = ring[k, s, 0]
        ey[a] = ring[k, s, 1]
        ep[a] = ring[k, s, 2]
    return float(ring[k, (head - n + n // 2) % cap, 3])


@njit(cache=True)
def _align(k: int, trk: np.ndarray, ring: np.ndarray, cnt: np.ndarray, tg: np.ndarray, mdl: np.ndarray,
           nmdl: np.ndarray, prm: np.ndarray, ex: np.ndarray, ey: np.ndarray, ep: np.ndarray,
           obs: np.ndarray) -> float:
    """Align feature ``k`` on its latest ``n_e`` events; returns the moved
    distance (px). Updates x, y, θ, φ, quality, n_e, the window's middle
    time and the velocity."""
    half = int(prm[P_HALF])
    n = int(trk[k, NE])
    t_mid = _window(ring, cnt, k, n, ex, ey, ep)
    x0 = trk[k, X]
    y0 = trk[k, Y]
    S = tg.shape[2]
    a = (S - (2 * half + 1)) // 2
    if int(prm[P_METHOD]) == EKLT:
        cx = int(math.floor(x0 + 0.5))
        cy = int(math.floor(y0 + 0.5))
        inside = observed_patch(ex, ey, ep, n, cx, cy, half, obs)
        rot = prm[P_ROT] > 0
        q = np.empty(4 if rot else 3)
        q[0] = x0
        q[1] = y0
        if rot:
            q[2] = trk[k, TH]
        fresh = math.isnan(trk[k, PHI])
        q[q.shape[0] - 1] = 0.0 if fresh else trk[k, PHI]
        if inside == 0:
            trk[k, Q] = 0.0
            return 0.0
        cost = eklt_align(obs, tg[k], trk[k, OX], trk[k, OY], trk[k, XR], trk[k, YR], cx, cy, half,
                          q, rot, fresh, int(prm[P_ITER]))
        trk[k, X] = q[0]
        trk[k, Y] = q[1]
        if rot:
            trk[k, TH] = q[2]
        phi = q[q.shape[0] - 1] % (2.0 * math.pi)
        trk[k, PHI] = phi
        trk[k, Q] = 1.0 - 0.5 * cost
        target = event_target(tg[k, 0, a:S - a, a:S - a], tg[k, 1, a:S - a, a:S - a], phi, prm[P_C])
    else:
        xy = np.array([x0, y0])
        trk[k, Q] = icp_align(ex, ey, n, mdl[k], int(nmdl[k]), half, xy, prm[P_DIST], int(prm[P_ITER]))
        trk[k, X] = xy[0]
        trk[k, Y] = xy[1]
        target = trk[k, NE]
    trk[k, NE] = min(max(target, prm[P_MIN]), ring.shape[1])
    dt = t_mid - trk[k, TM]
    trk[k, NA] += 1
    if dt > 0:
        mix = 1.0 if trk[k, NA] == 1 else 0.5  # smoothing of the velocity over successive windows
        trk[k, VX] = (1 - mix) * trk[k, VX] + mix * (trk[k, X] - x0) / dt
        trk[k, VY] = (1 - mix) * trk[k, VY] + mix * (trk[k, Y] - y0) / dt
        trk[k, TM] = t_mid
    return math.sqrt((trk[k, X] - x0) ** 2 + (trk[k, Y] - y0) ** 2)


@njit(cache=True)
def track_events(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, start: int, trk: np.ndarray,
                 ids: np.ndarray, ring: np.ndarray, cnt: np.ndarray, tg: np.ndarray, mdl: np.ndarray,
                 nmdl: np.ndarray, prm: np.ndarray, stats: np.ndarray, out_i: np.ndarray,
                 out_v: np.ndarray) -> tuple[int, int]:
    """Feed events ``start:`` (``t`` µs, ``x``, ``y`` px, ``p`` ±1) to the
    features; write one row per alignment into ``out_i`` (rows of t µs,
    id) and ``out_v`` (rows of x, y px, quality). ``ring`` (T, capacity,
    4) holds each feature's latest events (x, y, p, t), ``cnt`` (T, 3)
    their number, the ring's head and the events since the last
    alignment. Stops before an event when fewer than T rows are left;
    returns (rows written, next event)."""
    T = trk.shape[0]
    cap = ring.shape[1]
    half = int(prm[P_HALF])
    reach = half + 1.0
    P = 2 * half + 1
    ex = np.empty(cap)
    ey = np.empty(cap)
    ep = np.empty(cap)
    obs = np.empty(P * P)
    border = prm[P_BORDER]
    w = prm[P_W]
    h = prm[P_H]
    rows = 0
    n_ev = t.shape[0]
    e = start
    while e < n_ev:
        if out_i.shape[0] - rows < T:
            break
        xe = float(x[e])
        ye = float(y[e])
        for k in range(T):
            if trk[k, ALIVE] == 0.0:
                continue
            if abs(xe - trk[k, X]) > reach or abs(ye - trk[k, Y]) > reach:
                continue
            s = cnt[k, 1]
            ring[k, s, 0] = x[e]
            ring[k, s, 1] = y[e]
            ring[k, s, 2] = p[e]
            ring[k, s, 3] = t[e]
            cnt[k, 1] = (s + 1) % cap
            cnt[k, 0] = min(cnt[k, 0] + 1, cap)
            cnt[k, 2] += 1
            n_e = trk[k, NE]
            if cnt[k, 0] < n_e or cnt[k, 2] < max(1.0, prm[P_UPD] * n_e):
                continue
            cnt[k, 2] = 0
            moved = _align(k, trk, ring, cnt, tg, mdl, nmdl, prm, ex, ey, ep, obs)
            stats[0] += 1
            if trk[k, Q] < prm[P_QMIN] or moved > half:
                trk[k, ALIVE] = 0.0
                stats[1] += 1
                continue
            if not (border <= trk[k, X] <= w - 1 - border and border <= trk[k, Y] <= h - 1 - border):
                trk[k, ALIVE] = 0.0
                stats[2] += 1
                continue
            out_i[rows, 0] = t[e]
            out_i[rows, 1] = ids[k]
            ahead = t[e] - trk[k, TM]
            out_v[rows, 0] = trk[k, X] + trk[k, VX] * ahead
            out_v[rows, 1] = trk[k, Y] + trk[k, VY] * ahead
            out_v[rows, 2] = trk[k, Q]
            rows += 1
        e += 1
    return rows, e
