"""Kernels of ``tracker.led_markers``: per-pixel transition intervals, their
frequency bands, and blob positions per marker.

A pixel seeing a blinking LED fires a burst of ON events as the LED turns on
and a burst of OFF events as it turns off. The first event of a burst, an
event whose polarity differs from the pixel's previous event, is a
*transition*; the time from one ON transition to the next (or OFF to OFF)
is one period of the light: an *observation* of frequency ``1e6 /
interval`` Hz at that pixel (Censi et al., IROS 2013, used the same
intervals). Observations inside a marker's band (interval limits in µs,
``band_lo <= dt <= band_hi``) go to that marker's ring buffer; those in a
rejected band (mains flicker) and those in no band are counted.

State (explicit arrays): ``pix`` (H, W, 3) int64 per pixel: last polarity,
last ON transition, last OFF transition (µs, -1 none); ``ring_t`` (M, C)
int64 and ``ring_xy`` (M, C, 2) float64: the last ``C`` observations per
marker, ``ring_n`` (M,) how many were ever written (the write position is
``ring_n % C``); ``meta`` (1,) int64: the next output time (µs, -1 before the
first event).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["transitions_kernel", "blob_estimate", "led_kernel", "C_FLICKER", "C_UNMATCHED", "C_OBSERVED"]

C_OBSERVED, C_FLICKER, C_UNMATCHED = range(3)


@njit(cache=True, inline="always")
def _observe(pix, t, x, y, p):  # type: ignore[no-untyped-def]
    """The pixel's update for one event; the interval (µs) of the period it
    closes, or -1 when the event is no transition or the first one."""
    cell = pix[y, x]
    dt = np.int64(-1)
    if cell[0] != p:
        k = 1 if p > 0 else 2
        if cell[k] >= 0:
            dt = t - cell[k]
        cell[k] = t
        cell[0] = p
    return dt


@njit(cache=True)
def transitions_kernel(t, x, y, p, pix, out_dt):  # type: ignore[no-untyped-def]
    """Per event, the interval (µs) since the pixel's previous transition of
    the same polarity when the event is a transition, else -1 (``out_dt``);
    updates ``pix``. (The observation step of :func:`led_kernel` alone.)"""
    for i in range(t.shape[0]):
        out_dt[i] = _observe(pix, t[i], np.intp(x[i]), np.intp(y[i]), p[i])


@njit(cache=True)
def blob_estimate(ring_t, ring_xy, n_written, T, window, blob_px, work):  # type: ignore[no-untyped-def]
    """A marker's position at ``T`` µs from its observations in ``(T -
    window, T]``: the per-axis median, then the mean of the observations
    within ``blob_px`` (L-inf) of it. Returns ``(x, y, kept)`` (NaN, NaN, 0
    when none is kept). The ring holds observations in time order (oldest
    overwritten), so it is walked back from the newest until the window's
    start. ``work`` (C, 2) is scratch space."""
    C = ring_t.shape[0]
    m = min(n_written, C)
    k = 0
    for back in range(m):
        j = (n_written - 1 - back) % C
        tj = ring_t[j]
        if tj <= T - window:
            break
        if tj <= T:
            work[k, 0] = ring_xy[j, 0]
            work[k, 1] = ring_xy[j, 1]
            k += 1
    if k == 0:
        return np.nan, np.nan, 0
    mx = np.median(work[:k, 0])
    my = np.median(work[:k, 1])
    sx = 0.0
    sy = 0.0
    kept = 0
    for j in range(k):
        if abs(work[j, 0] - mx) <= blob_px and abs(work[j, 1] - my) <= blob_px:
            sx += work[j, 0]
            sy += work[j, 1]
            kept += 1
    if kept == 0:  # the per-axis median can fall between two groups of observations
        return np.nan, np.nan, 0
    return sx / kept, sy / kept, kept


@njit(cache=True, nogil=True)
def led_kernel(t, x, y, p, start, watermark, pix, bands, rejects,  # type: ignore[no-untyped-def]
               ring_t, ring_xy, ring_n, meta, par, counts, work, out_tm, out_xyq):
    """Events ``start..`` then the output times before ``watermark`` (µs).

    ``bands`` (M, 2) and ``rejects`` (R, 2): the markers' and the rejected
    lights' interval limits, µs. ``par`` = (update µs, window µs, blob_px,
    min_hits). At every multiple ``T`` of ``update`` µs (from the first event
    on), once the events up to ``T`` are in: one row per marker with at least
    ``min_hits`` observations kept by :func:`blob_estimate` (``out_tm`` = T
    and the marker's index, ``out_xyq`` = x, y px and the kept count). Output times with no
    observation in any marker's window are skipped at once (a gap in the
    stream costs nothing). Returns ``(rows, next event
    index, done)``; not done when the output could overflow (the caller
    resumes from that index with a fresh output)."""
    M = bands.shape[0]
    C = ring_t.shape[1]
    cap = out_tm.shape[0]
    update = par[0]
    window = par[1]
    blob_px = par[2]
    min_hits = par[3]
    r = 0
    N = t.shape[0]
    i = start
    while True:
        ti = t[i] if i < N else np.int64(watermark)
        if i < N and meta[0] < 0:
            meta[0] = np.int64(math.ceil(ti / update) * update)
        # outputs due before this event (or at the watermark: times < watermark)
        while meta[0] >= 0 and (meta[0] < ti if i < N else meta[0] < watermark):
            if r + M > cap:
                return r, i, False
            T = meta[0]
            latest = np.int64(-1)
            for m in range(M):
                if ring_n[m] > 0:
                    latest = max(latest, ring_t[m, (ring_n[m] - 1) % C])
            if latest <= T - window:  # no observation in any window until the next one
                if i < N:
                    meta[0] = max(T + np.int64(update), np.int64(math.ceil(ti / update) * update))
                    continue
                meta[0] = -1
                break
            for m in range(M):
                ex, ey, kept = blob_estimate(ring_t[m], ring_xy[m], ring_n[m], T, window, blob_px, work)
                if kept >= min_hits:
                    out_tm[r, 0] = T
                    out_tm[r, 1] = m
                    out_xyq[r, 0] = ex
                    out_xyq[r, 1] = ey
                    out_xyq[r, 2] = kept
                    r += 1
            meta[0] = T + np.int64(update)
        if i >= N:
            return r, N, True
        xi = np.intp(x[i])
        yi = np.intp(y[i])
        dt = _observe(pix, ti, xi, yi, p[i])
        if dt > 0:
            hit = -1
            for m in range(M):
                if bands[m, 0] <= dt <= bands[m, 1]:
                    hit = m
                    break
            if hit >= 0:
                w = ring_n[hit] % C
                ring_t[hit, w] = ti
                ring_xy[hit, w, 0] = xi
                ring_xy[hit, w, 1] = yi
                ring_n[hit] += 1
                counts[C_OBSERVED] += 1
            else:
                flick = False
                for j in range(rejects.shape[0]):
                    if rejects[j, 0] <= dt <= rejects[j, 1]:
                        flick = True
                if flick:
                    counts[C_FLICKER] += 1
                else:
                    counts[C_UNMATCHED] += 1
        i += 1
