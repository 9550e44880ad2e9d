"""Blinking pixels: ON→OFF transition maps, blobs and their centroids, still views.

A pixel that sees a dot blinking at period ``T`` µs gives a burst of ON
events when the dot lights and a burst of OFF events ``duty·T`` later when it
goes dark. As rpg_dvs_ros's calibration does, a *transition* is counted when
a pixel's first OFF event comes between ``(1 - tol)·duty·T`` and
``(1 + tol)·duty·T`` after the first ON event of its burst (first to first:
timestamp jitter spreads both bursts alike, where last ON to first OFF
would shorten the gap by about twice the jitter); a pixel blinks when it
makes a transition in at least ``min_fraction`` of the periods of a window.
Shot noise (an ON then an OFF within that gap, a few Hz per pixel) and mains
flicker (one ON→OFF cycle per 10 or 20 ms, against one per ``T``) stay far
below that fraction unless ``T`` is itself the flicker period.

A dot's image is the connected set of its blinking pixels (4-neighbours,
so the squares of a blinking checkerboard stay apart); its centre is the
centroid of the pixels weighted by their ON events at transitions (more at
the dot's core than at its partly covered rim, and symmetric about the
centre, so the weights add sub-pixel accuracy without a bias).

Views: the recording is cut in windows of ``window_periods`` periods;
consecutive windows whose blobs match within ``still_px`` (or, when a blob
split or merged, whose blinking pixels overlap by 90 %) are one still
view; the windows at a view's two ends (where the board may have
started or stopped moving) are left out, then each view's transitions are
counted again over its whole span.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from tectum import EventPacket

__all__ = ["transition_kernel", "transition_map", "Blobs", "blobs", "still_spans", "blink_period_kernel",
           "dominant_period"]


@njit(cache=True)
def transition_kernel(t, x, y, p, width, lo_us, hi_us, last_on, burst, transitions, weight):  # type: ignore[no-untyped-def]
    """Count ON→OFF transitions per pixel (flat ``y * width + x``).

    ``last_on`` (int64, -1: none) the time of the first ON event of each
    pixel's current burst (the ON events since its last OFF event) and
    ``burst`` (int32) their number: state kept across calls. A pixel's first
    OFF event ``lo_us <= dt <= hi_us`` after its burst's first ON event
    adds 1 to ``transitions`` and the burst's ON events to ``weight``."""
    for i in range(t.shape[0]):
        k = np.int64(y[i]) * width + x[i]
        if p[i] > 0:
            if burst[k] == 0:
                last_on[k] = t[i]
            burst[k] += 1
        else:
            if last_on[k] >= 0:
                dt = t[i] - last_on[k]
                if lo_us <= dt <= hi_us:
                    transitions[k] += 1
                    weight[k] += burst[k]
            last_on[k] = -1
            burst[k] = 0


def transition_map(events: EventPacket, period_us: float, duty: float = 0.5,
                   tol: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """``(transitions, weight)`` (H, W) of ``events``: ON→OFF transitions
    per pixel at ``period_us`` µs and ``duty`` (see the module docstring)
    and the ON events in them."""
    w, h = events.sensor
    on = duty * period_us
    last_on = np.full(w * h, -1, np.int64)
    burst = np.zeros(w * h, np.int32)
    trans = np.zeros(w * h, np.int32)
    weight = np.zeros(w * h, np.int64)
    transition_kernel(events.t, events.x, events.y, events.p, w,
                      (1 - tol) * on, (1 + tol) * on, last_on, burst, trans, weight)
    return trans.reshape(h, w), weight.reshape(h, w)


@dataclass(frozen=True)
class Blobs:
    """Blinking blobs of one window or view: centroids ``xy`` (N, 2) px,
    ``pixels`` (N,) blinking pixels per blob, ``mass`` (N,) ON events."""

    xy: np.ndarray
    pixels: np.ndarray
    mass: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)


def blobs(transitions: np.ndarray, weight: np.ndarray, periods: float, min_fraction: float = 0.5,
          min_pixels: int = 2, max_pixels: int = 2000) -> Blobs:
    """The blobs of pixels that blink in at least ``min_fraction`` of
    ``periods`` (4-connected; ``min_pixels`` to ``max_pixels`` pixels) and
    their weighted centroids."""
    from scipy import ndimage

    mask = transitions >= max(1.0, min_fraction * periods)
    labels, n = ndimage.label(mask)
    if n == 0:
        return Blobs(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0))
    idx = np.arange(1, n + 1)
    wgt = np.where(mask, weight, 0).astype(np.float64)
    mass = ndimage.sum_labels(wgt, labels, idx)
    npx = ndimage.sum_labels(mask, labels, idx).astype(np.int64)
    vv, uu = np.indices(mask.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        cx = ndimage.sum_labels(wgt * uu, labels, idx) / mass
        cy = ndimage.sum_labels(wgt * vv, labels, idx) / mass
    keep = (npx >= min_pixels) & (npx <= max_pixels) & (mass > 0)
    return Blobs(np.column_stack([cx, cy])[keep], npx[keep], mass[keep])


def _matches(a: Blobs, b: Blobs, still_px: float) -> bool:
    """True when the blobs of two windows are the same (each of ``b``
    within ``still_px`` of one of ``a``, same count)."""
    if len(a) == 0 or len(a) != len(b):
        return False
    d = np.linalg.norm(a.xy[None, :, :] - b.xy[:, None, :], axis=2)
    return bool(np.all(d.min(axis=1) <= still_px))


def _same(a: tuple[Blobs, np.ndarray], b: tuple[Blobs, np.ndarray], still_px: float, overlap: float) -> bool:
    """True when two windows (blobs, blinking mask) show the pattern at the
    same place: the same blobs (:func:`_matches`); or, when a blob split
    or merged between them (timestamp jitter, the touching squares of a
    checkerboard), masks overlapping by ``overlap`` (intersection over
    union)."""
    if len(a[0]) == len(b[0]):
        return _matches(a[0], b[0], still_px)
    union = int(np.count_nonzero(a[1] | b[1]))
    return union > 0 and int(np.count_nonzero(a[1] & b[1])) >= overlap * union


def still_spans(events: EventPacket, period_us: float, *, duty: float = 0.5, tol: float = 0.25,
                window_periods: int = 5, min_fraction: float = 0.5, still_px: float = 0.5,
                min_windows: int = 2, overlap: float = 0.9) -> list[tuple[int, int]]:
    """Spans ``[t0, t1)`` µs where the blinking pattern holds still: runs of
    windows of ``window_periods`` periods showing the pattern at the same
    place (:func:`_same`), less the run's first and last window, at least
    ``min_windows`` windows long."""
    if len(events) == 0:
        return []
    win = int(round(window_periods * period_us))
    t0, t1 = int(events.t[0]), int(events.t[-1]) + 1
    edges = np.arange(t0, t1 + win, win)
    found: list[tuple[Blobs, np.ndarray]] = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        tr, wt = transition_map(events.slice_time(int(a), int(b)), period_us, duty, tol)
        found.append((blobs(tr, wt, window_periods, min_fraction), tr >= max(1.0, min_fraction * window_periods)))
    spans: list[tuple[int, int]] = []
    k = 0
    while k < len(found):
        j = k
        while j + 1 < len(found) and _same(found[j], found[j + 1], still_px, overlap):
            j += 1
        first, last = k + 1, j - 1  # drop the run's two end windows
        if j > k and last - first + 1 >= min_windows:
            spans.append((int(edges[first]), int(edges[last + 1])))
        k = j + 1
    return spans


@njit(cache=True)
def blink_period_kernel(t, x, y, p, width, last_start, off_seen, hist, sums, bin_log):  # type: ignore[no-untyped-def]
    """Histogram of the intervals between the starts of a pixel's ON bursts
    (a burst starts at the first ON event after an OFF event, so however
    long jitter makes a burst): ``hist[b] += 1`` and ``sums[b] += dt`` for
    ``b = int(log(dt) / bin_log)``. ``last_start`` (int64, -1: none) and
    ``off_seen`` (bool) per pixel."""
    nb = hist.shape[0]
    for i in range(t.shape[0]):
        k = np.int64(y[i]) * width + x[i]
        if p[i] <= 0:
            off_seen[k] = True
            continue
        if last_start[k] >= 0 and not off_seen[k]:
            continue  # inside a burst
        if last_start[k] >= 0:
            dt = t[i] - last_start[k]
            if dt > 0:
                b = int(np.log(dt) / bin_log)
                if b < nb:
                    hist[b] += 1
                    sums[b] += dt
        last_start[k] = t[i]
        off_seen[k] = False


def dominant_period(events: EventPacket) -> float:
    """The most common interval between the starts of a pixel's ON bursts,
    µs (0 when there is none): the blink period of a recording of a
    blinking pattern (the mean interval in the fullest bin of a histogram
    of 2% wide bins and its two neighbours)."""
    w, h = events.sensor
    bin_log = np.log(1.02)
    hist = np.zeros(int(np.log(1e7) / bin_log) + 1, np.int64)
    sums = np.zeros(len(hist))
    last = np.full(w * h, -1, np.int64)
    blink_period_kernel(events.t, events.x, events.y, events.p, w, last, np.zeros(w * h, np.bool_), hist, sums,
                        bin_log)
    if hist.sum() == 0:
        return 0.0
    b = int(np.argmax(hist))
    near = slice(max(b - 1, 0), b + 2)
    return float(sums[near].sum() / hist[near].sum())
