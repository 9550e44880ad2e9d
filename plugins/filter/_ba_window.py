"""The window of ``filter.background_activity`` with ``dt_us="auto"``: chosen
online from the stream's neighbour intervals.

Every event has a *neighbour interval*: the time (µs) since the latest of
its 8 neighbours fired. A moving edge's events have short ones (about the
time the edge takes to cross a pixel, 1 / speed); Poisson noise of ``r``
Hz/px far from the signal has exponential ones of rate ``8 r`` (mean
``1 / (8 r)``). The kernel keeps an exponentially forgotten histogram of
these intervals (log-spaced bins) and, every :data:`UPDATE_EVENTS` events,
sets the window to :data:`FACTOR` times the :data:`QUANTILE` quantile of the
signal's part of it: the intervals past :data:`TAIL_US` (no edge of the
scenes it was tuned on is that slow) fit the noise's exponential (its rate
from their mean excess, memoryless), whose expected count, times
:data:`NOISE_MARGIN`, is taken out of every shorter bin before the
quantile. With too little left (a scene without motion: under
:data:`MIN_SIGNAL` of the events) the window falls to :data:`DT_MIN_US`.
The margin covers what one exponential misses (border pixels have fewer
neighbours, so slower noise; bins' chance excesses): without it a 346x260
sensor's 10 Hz/px noise alone set a 30 ms window that passed 90 % of it.
Everything is a function of the events in order, one at a time: the same
output however the stream is split into packets.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._state import NEVER

__all__ = ["BINS", "DT_START_US", "DT_MIN_US", "DT_MAX_US", "adaptive_state", "adaptive_kernel", "interval_bin",
           "window_from_histogram"]

#: Histogram bins per octave of neighbour interval.
PER_OCTAVE = 8
#: The first bin starts at 2^LOW_OCTAVE µs (16 µs; shorter intervals fall in it).
LOW_OCTAVE = 4
#: Bins: 16 µs .. 2^25 µs (33 s; longer intervals fall in the last).
BINS = PER_OCTAVE * 21
#: The histogram forgets with this half-life, in events (neighbour intervals).
HALF_LIFE_EVENTS = 1 << 16
#: The window is recomputed every this many events.
UPDATE_EVENTS = 256
#: Intervals from this long (µs) on count as noise: they fit its exponential.
TAIL_US = 50_000
#: The quantile of the signal's intervals the window is set from ...
QUANTILE = 0.9
#: ... times this factor.
FACTOR = 1.4
#: The noise's expected count per bin is taken out times this.
NOISE_MARGIN = 1.5
#: Below this fraction of signal in the histogram, the window is :data:`DT_MIN_US`.
MIN_SIGNAL = 0.05
#: The window (µs) before the first estimate (the fixed default's).
DT_START_US = 6000
#: Bounds of the window (µs).
DT_MIN_US = 300
DT_MAX_US = 50_000


def adaptive_state() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fresh estimator: the histogram (float64, :data:`BINS`), the weight
    of the next entry (float64, 1), and (events since the last update, the
    window in µs) (int64, 2)."""
    return np.zeros(BINS, np.float64), np.ones(1, np.float64), np.array([0, DT_START_US], np.int64)


@njit(cache=True, nogil=True)
def interval_bin(d):  # type: ignore[no-untyped-def]
    """The histogram bin of a neighbour interval ``d`` µs (>= 0)."""
    if d < (1 << LOW_OCTAVE):
        return 0
    return min(int(math.log2(d) * PER_OCTAVE) - LOW_OCTAVE * PER_OCTAVE, BINS - 1)


@njit(cache=True, nogil=True)
def _edge(b):  # type: ignore[no-untyped-def]
    """The lower edge (µs) of bin ``b``."""
    return 2.0 ** ((b + LOW_OCTAVE * PER_OCTAVE) / PER_OCTAVE)


@njit(cache=True, nogil=True)
def window_from_histogram(hist):  # type: ignore[no-untyped-def]
    """The window (µs) from a histogram of neighbour intervals (see the
    module's docstring): noise fitted on the bins from :data:`TAIL_US` on
    and taken out of the shorter ones, then :data:`FACTOR` times the upper
    edge of the bin holding the :data:`QUANTILE` quantile of what is left,
    within [:data:`DT_MIN_US`, :data:`DT_MAX_US`]."""
    tail = interval_bin(TAIL_US)
    start = _edge(tail)
    total, count, excess = 0.0, 0.0, 0.0
    for b in range(BINS):
        total += hist[b]
        if b >= tail:
            count += hist[b]
            excess += hist[b] * (math.sqrt(_edge(b) * _edge(b + 1)) - start)
    if total <= 0.0:
        return DT_START_US
    rate, noise = 0.0, 0.0  # noise: events/µs, and its expected number in the histogram
    if count > 0.0 and excess > 0.0:
        rate = count / excess
        noise = min(NOISE_MARGIN * count * math.exp(min(rate * start, 50.0)), total)
    signal = np.empty(tail)
    left = 0.0
    for b in range(tail):
        lo = 0.0 if b == 0 else _edge(b)
        expected = noise * (math.exp(-rate * lo) - math.exp(-rate * _edge(b + 1)))
        signal[b] = max(hist[b] - expected, 0.0)
        left += signal[b]
    if left < MIN_SIGNAL * total:
        return DT_MIN_US
    acc = 0.0
    b = 0
    for b in range(tail):
        acc += signal[b]
        if acc >= QUANTILE * left:
            break
    return min(max(int(FACTOR * _edge(b + 1)), DT_MIN_US), DT_MAX_US)


@njit(cache=True, nogil=True)
def adaptive_kernel(t, x, y, last, hist, weight, state, keep):  # type: ignore[no-untyped-def]
    """Background activity with the adaptive window: keep event ``i`` when
    its neighbour interval (µs since the latest of its 8 neighbours fired)
    is at most the window ``state[1]`` µs; every event refreshes its pixel
    in ``last`` (a ``(1, H + 2, W + 2)`` int64 padded map of each pixel's
    latest time, :data:`NEVER` if none) and, unless no neighbour ever fired,
    adds its interval to ``hist`` with weight ``weight[0]`` (growing by
    2^(1 / :data:`HALF_LIFE_EVENTS`) an entry: older entries count for
    less; all rescaled when it passes 1e100). Every :data:`UPDATE_EVENTS`
    events (``state[0]`` counts them) the window is recomputed
    (:func:`window_from_histogram`). Writes ``keep``; returns how many kept."""
    m = last[0]
    grow = 2.0 ** (1.0 / HALF_LIFE_EVENTS)
    w = weight[0]
    count, dt = state[0], state[1]
    n = 0
    for i in range(t.shape[0]):
        ti = t[i]
        xx = np.intp(x[i]) + 1
        yy = np.intp(y[i]) + 1
        latest = max(m[yy - 1, xx - 1], m[yy - 1, xx], m[yy - 1, xx + 1], m[yy, xx - 1], m[yy, xx + 1],
                     m[yy + 1, xx - 1], m[yy + 1, xx], m[yy + 1, xx + 1])
        d = ti - latest
        ok = d <= dt
        keep[i] = ok
        n += ok
        m[yy, xx] = ti
        if latest > NEVER:
            hist[interval_bin(d)] += w
            w *= grow
            if w > 1e100:
                hist /= w
                w = 1.0
        count += 1
        if count == UPDATE_EVENTS:
            count = 0
            dt = window_from_histogram(hist)
    weight[0] = w
    state[0] = count
    state[1] = dt
    return n
