"""Stable ordering of event timestamps (the release of a window).

Events of a window span a short range of integer µs, so a counting sort
(linear time) gives the same order as a stable comparison sort: by time,
ties in generation order.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["time_order"]


@njit(cache=True)
def _counting_order(t: np.ndarray, t_min: int, span: int) -> np.ndarray:
    count = np.zeros(span + 1, np.int64)
    for k in range(t.shape[0]):
        count[t[k] - t_min + 1] += 1
    for b in range(1, span + 1):
        count[b] += count[b - 1]
    order = np.empty(t.shape[0], np.int64)
    for k in range(t.shape[0]):
        b = t[k] - t_min
        order[count[b]] = k
        count[b] += 1
    return order


def time_order(t: np.ndarray) -> np.ndarray:
    """Indices that sort ``t`` (int64 µs) stably, as
    ``np.argsort(t, kind="stable")``."""
    if t.size == 0:
        return np.empty(0, np.int64)
    t_min, t_max = int(t.min()), int(t.max())
    span = t_max - t_min + 1
    if span > 4 * t.size + 4096:
        return np.argsort(t, kind="stable")
    return _counting_order(t, t_min, span)
