"""Event-to-template ICP (Kueng, Mueggler, Gallego, Scaramuzza, "Low-latency
visual odometry using event-based feature tracks", IROS 2016): numba kernel.

A feature's model is the set of edge pixels (Canny on the detection frame)
within its patch, as offsets (px) from the feature's position in the frame.
Its latest events are points; iterative closest point moves the feature so
that the events (as offsets from the feature's current position) lie on
the model: each event is paired with its nearest model point, pairs farther
than ``max_dist`` px are outliers, and the feature moves by the inliers'
mean offset (the least-squares translation), a few times over. The quality
is the inlier fraction times ``1 - mean inlier distance / max_dist``.
Nearest neighbours by brute force: models hold at most a few hundred
points and a window a few hundred events.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["icp_align"]


@njit(cache=True)
def icp_align(ex: np.ndarray, ey: np.ndarray, n: int, model: np.ndarray, nm: int, half: int, xy: np.ndarray,
              max_dist: float, iters: int) -> float:
    """Align the first ``n`` events (``ex``, ``ey`` px) to the ``nm`` model
    offsets ``model`` (nm, 2) px, moving the feature position ``xy`` (2,)
    px in place; events farther than ``half`` px from it (in x or y) are not
    used. Returns the quality in [0, 1] (0: no event or no model point)."""
    if nm == 0:
        return 0.0
    md2 = max_dist * max_dist
    quality = 0.0
    for _ in range(iters):
        sx = 0.0
        sy = 0.0
        sd = 0.0
        used = 0
        inl = 0
        for e in range(n):
            dx = ex[e] - xy[0]
            dy = ey[e] - xy[1]
            if abs(dx) > half or abs(dy) > half:
                continue
            used += 1
            best = 1e18
            bj = 0
            for j in range(nm):
                a = dx - model[j, 0]
                b = dy - model[j, 1]
                d2 = a * a + b * b
                if d2 < best:
                    best = d2
                    bj = j
            if best <= md2:
                inl += 1
                sx += dx - model[bj, 0]
                sy += dy - model[bj, 1]
                sd += math.sqrt(best)
        if used == 0 or inl == 0:
            return 0.0
        quality = inl / used * max(0.0, 1.0 - sd / inl / max_dist)
        mx = sx / inl
        my = sy / inl
        xy[0] += mx
        xy[1] += my
        if mx * mx + my * my < 1e-6:
            break
    return quality
