"""The window of ``filter.background_activity`` with ``dt_us="auto"``: chosen
online from the stream's neighbour intervals.

Every event has a *neighbour interval*: the time (µs) since the latest of
its 8 neighbours fired. A moving edge's events have short ones (about the
time the edge takes to cross a pixel, 1 / speed); Poisson noise of ``r``
Hz/px far from the signal has exponential ones of rate ``8 r`` (mean
``1 / (8 r)``). The kernel keeps an exponentially forgotten histogram of
the intervals of pixels off the sensor's border (those have 3 or 5
neighbours: slower noise) in log-spaced bins and, every
:data:`UPDATE_EVENTS` events, sets the window to :data:`FACTOR` times the
:data:`QUANTILE` quantile of the signal's part of it. The intervals from
:data:`TAIL_US` on (no edge of the scenes it was tuned on is that slow)
fit the noise's exponential: its rate is their number over their summed
excess past :data:`TAIL_US` (memoryless; both kept exactly, not binned:
the count extrapolated back grows as exp(rate x 50 ms), 40x at 10 Hz/px,
so a rate 1.5 % off from bin centres put it 6 % short). Its expected count
in every shorter bin, times a margin, is taken out before the quantile;
with under :data:`MIN_SIGNAL` of the histogram left (no motion, or a
signal too sparse to tell from the noise) the window is the fixed
default's, :data:`DT_FALLBACK_US`. The margin is
:data:`MARGIN_SIGMAS` standard errors of that count: the fit rests on the
``n`` intervals in the tail (their effective number under the forgetting),
so the rate is off by about 1 / sqrt(n) and the count by (1 + rate x
:data:`TAIL_US`) / sqrt(n). With a fixed margin of 1.2 instead, 10 Hz/px
noise alone set windows of 15-30 ms at random moments on 64x48 and
128x96 sensors and passed up to 35-80 % of it; with this one it finds
no signal there (64x48 to 346x260, 2 and 10 Hz/px, 5 seeds each: every
window after the first 0.5 s is 6 ms). The first 0.1-0.2 s of a stream
are not judged as well: intervals are cut short by the stream's age and
none reaches the tail yet, so windows up to 50 ms pass 60-90 % of
10 Hz/px noise alone there (6 ms: 38 %). Falling to the shortest window instead of
6 ms would pass 2 % of such noise instead of 38 %, but the sparse
``low_texture`` scene of ``tectum bench filters`` in 10 Hz/px noise
(2 % of its events signal) would keep 6 % of its signal instead of 70 %.
Everything is a function of the events in order, one at a time: the same
output however the stream is split into packets.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._state import NEVER

__all__ = ["BINS", "DT_START_US", "DT_FALLBACK_US", "DT_MIN_US", "DT_MAX_US", "adaptive_state", "adaptive_kernel",
           "interval_bin", "window_from_histogram"]

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
FACTOR = 1.5
#: Standard errors of the noise's extrapolated count added to it before it is taken out.
MARGIN_SIGMAS = 3.0
#: The effective number of entries of the forgotten histogram: sum(w)^2 / sum(w^2) for weights halving every
#: :data:`HALF_LIFE_EVENTS` entries.
EFFECTIVE_ENTRIES = 2.0 * HALF_LIFE_EVENTS / math.log(2.0)
#: Below this fraction of signal in the histogram, the window is :data:`DT_FALLBACK_US`.
MIN_SIGNAL = 0.05
#: The window (µs) before the first estimate (the fixed default's).
DT_START_US = 6000
#: The window (µs) when no signal is found (the fixed default's).
DT_FALLBACK_US = 6000
#: Bounds of the window (µs).
DT_MIN_US = 300
DT_MAX_US = 50_000


def adaptive_state() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fresh estimator: the histogram (float64, :data:`BINS`); (the weight
    of the next entry, the weighted number of intervals from
    :data:`TAIL_US` on, their weighted sum of µs past it) (float64, 3); and
    (events since the last update, the window in µs, entries so far) (int64,
    3)."""
    return np.zeros(BINS, np.float64), np.array([1.0, 0.0, 0.0]), np.array([0, DT_START_US, 0], np.int64)


@njit(cache=True, nogil=True)
def interval_bin(d):  # type: ignore[no-untyped-def]
    """The histogram bin of a neighbour interval ``d`` µs (>= 0)."""
    if d < (1 << LOW_OCTAVE):
        return 0
    return min(int(math.log2(d) * PER_OCTAVE) - LOW_OCTAVE * PER_OCTAVE, BINS - 1)


#: The lower edges (µs) of the bins, and the upper edge of the last.
_EDGES = 2.0 ** ((np.arange(BINS + 1) + LOW_OCTAVE * PER_OCTAVE) / PER_OCTAVE)
#: The bin of :data:`TAIL_US`: the bins before it are the signal's candidates.
_TAIL_BIN = int(math.log2(TAIL_US) * PER_OCTAVE) - LOW_OCTAVE * PER_OCTAVE


@njit(cache=True, nogil=True)
def window_from_histogram(hist, count, excess, entries, signal):  # type: ignore[no-untyped-def]
    """The window (µs) from a histogram of neighbour intervals (``entries``
    of them so far) and, of those from :data:`TAIL_US` on, their (weighted)
    ``count`` and summed ``excess`` (µs) past it (see the module's
    docstring): the noise's exponential fitted on these and taken out of
    the shorter bins (what is left goes to ``signal``, float64, one per bin
    before :data:`TAIL_US`'s), then :data:`FACTOR` times the upper edge of
    the bin holding the :data:`QUANTILE` quantile of what is left, within
    [:data:`DT_MIN_US`, :data:`DT_MAX_US`]."""
    total = 0.0
    for b in range(BINS):
        total += hist[b]
    if total <= 0.0:
        return DT_START_US
    rate, noise = 0.0, 0.0  # noise: events/µs, and its expected number in the histogram
    if count > 0.0 and excess > 0.0:
        rate = count / excess
        n = max(count / total * min(entries, EFFECTIVE_ENTRIES), 1.0)  # effective intervals in the tail
        margin = 1.0 + MARGIN_SIGMAS * (1.0 + rate * TAIL_US) / math.sqrt(n)
        noise = min(margin * count * math.exp(min(rate * TAIL_US, 50.0)), total)
    left = 0.0
    below = 1.0  # the noise's share up to the bin's lower edge: exp(-rate x 0) for the first
    for b in range(_TAIL_BIN):
        upto = math.exp(-rate * min(_EDGES[b + 1], TAIL_US))
        signal[b] = max(hist[b] - noise * (below - upto), 0.0)
        below = upto
        left += signal[b]
    if left < MIN_SIGNAL * total:
        return DT_FALLBACK_US
    acc = 0.0
    b = 0
    for b in range(_TAIL_BIN):
        acc += signal[b]
        if acc >= QUANTILE * left:
            break
    return min(max(int(FACTOR * _EDGES[b + 1]), DT_MIN_US), DT_MAX_US)


@njit(cache=True, nogil=True)
def adaptive_kernel(t, x, y, last, hist, weight, state, keep):  # type: ignore[no-untyped-def]
    """Background activity with the adaptive window: keep event ``i`` when
    its neighbour interval (µs since the latest of its 8 neighbours fired)
    is at most the window ``state[1]`` µs; every event refreshes its pixel
    in ``last`` (a ``(1, H + 2, W + 2)`` int64 padded map of each pixel's
    latest time, :data:`NEVER` if none) and, off the sensor's border and
    unless no neighbour ever fired, adds its interval to ``hist`` (and, from
    :data:`TAIL_US` on, to ``weight[1]`` and its excess to ``weight[2]``)
    with weight ``weight[0]`` (growing by 2^(1 / :data:`HALF_LIFE_EVENTS`)
    an entry: older entries count for less; all rescaled when it passes
    1e100). Every :data:`UPDATE_EVENTS` events (``state[0]`` counts them)
    the window is recomputed (:func:`window_from_histogram`). Writes
    ``keep``; returns how many kept."""
    m = last[0]
    x_end, y_end = last.shape[2] - 2, last.shape[1] - 2  # padded columns / rows of the sensor's far border
    grow = 2.0 ** (1.0 / HALF_LIFE_EVENTS)
    w, tail_count, tail_excess = weight[0], weight[1], weight[2]
    count, dt, entries = state[0], state[1], state[2]
    signal = np.empty(_TAIL_BIN)  # window_from_histogram's scratch
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
        if latest > NEVER and 1 < xx < x_end and 1 < yy < y_end:
            hist[interval_bin(d)] += w
            entries += 1
            if d >= TAIL_US:
                tail_count += w
                tail_excess += w * (d - TAIL_US)
            w *= grow
            if w > 1e100:
                hist /= w
                tail_count /= w
                tail_excess /= w
                w = 1.0
        count += 1
        if count == UPDATE_EVENTS:
            count = 0
            dt = window_from_histogram(hist, tail_count, tail_excess, entries, signal)
    weight[0] = w
    weight[1] = tail_count
    weight[2] = tail_excess
    state[0] = count
    state[1] = dt
    state[2] = entries
    return n
