"""Numba kernels of the representations: pure functions on arrays that
accumulate into (or render from) caller-owned state.

Layouts are channels-last, like :class:`tectum.FramePacket` images:
``(H, W)`` or ``(H, W, C)``. Per-polarity channels: 0 = OFF (p = -1),
1 = ON (p = +1).
"""

from __future__ import annotations

import numpy as np
from numba import literally, njit

__all__ = [
    "NEVER", "histogram_kernel", "signed_kernel", "count_kernel", "sae_kernel", "time_surface_kernel",
    "decay_table", "decay_kernel", "DECAY_STEP", "surface_kernel", "voxel_kernel", "last_polarity_kernel",
    "render_polarity_kernel", "windows_kernel", "WINDOWS", "HISTOGRAM", "SIGNED", "COUNT", "window_splits",
]

#: SAE value of a pixel that never fired (µs).
NEVER = np.iinfo(np.int64).min // 2


@njit(cache=True, nogil=True)
def histogram_kernel(x, y, p, out):  # type: ignore[no-untyped-def]
    """``out[y, x, p > 0] += 1`` per event; ``out`` (H, W, 2) int32."""
    for i in range(x.shape[0]):
        out[y[i], x[i], 1 if p[i] > 0 else 0] += 1


@njit(cache=True, nogil=True)
def signed_kernel(x, y, p, out):  # type: ignore[no-untyped-def]
    """``out[y, x] += p`` per event; ``out`` (H, W) int32."""
    for i in range(x.shape[0]):
        out[y[i], x[i]] += p[i]


@njit(cache=True, nogil=True)
def count_kernel(x, y, out):  # type: ignore[no-untyped-def]
    """``out[y, x] += 1`` per event; ``out`` (H, W) int32."""
    for i in range(x.shape[0]):
        out[y[i], x[i]] += 1


@njit(cache=True, nogil=True)
def sae_kernel(t, x, y, p, sae):  # type: ignore[no-untyped-def]
    """Surface of active events: ``sae[y, x, p > 0] = t`` (µs) per event;
    ``sae`` (H, W, 2) int64, :data:`NEVER` where no event came yet."""
    for i in range(t.shape[0]):
        sae[y[i], x[i], 1 if p[i] > 0 else 0] = t[i]


@njit(cache=True, nogil=True)
def time_surface_kernel(sae, t_ref, tau_us, out):  # type: ignore[no-untyped-def]
    """Exponentially decaying time surface at time ``t_ref`` (µs):
    ``out = exp(-(t_ref - sae) / tau_us)`` where the pixel fired at or
    before ``t_ref``, else 0. ``sae`` int64 and ``out`` float32, same shape."""
    s = sae.ravel()
    o = out.ravel()
    inv = 1.0 / tau_us
    for i in range(s.shape[0]):
        d = t_ref - s[i]
        o[i] = np.float32(np.exp(-d * inv)) if (s[i] != NEVER and d >= 0) else np.float32(0.0)


@njit(cache=True, nogil=True)
def voxel_kernel(t, x, y, p, t0, t1, out):  # type: ignore[no-untyped-def]
    """Voxel grid with bilinear interpolation in time: with B = out.shape[2]
    bins spanning ``[t0, t1]`` (µs, inclusive), an event at normalised time
    ``u = (B - 1) (t - t0) / (t1 - t0)`` adds ``p (1 - frac u)`` to bin
    ``floor u`` and ``p frac u`` to the next. ``out`` (H, W, B) float32."""
    b = out.shape[2]
    span = float(t1 - t0)
    scale = (b - 1) / span if span > 0 else 0.0
    for i in range(t.shape[0]):
        u = (t[i] - t0) * scale
        k = int(np.floor(u))
        if k < 0:
            k, u = 0, 0.0
        if k > b - 1:
            k, u = b - 1, float(b - 1)
        w1 = u - k
        pv = float(p[i])
        out[y[i], x[i], k] += np.float32(pv * (1.0 - w1))
        if k + 1 < b and w1 > 0.0:
            out[y[i], x[i], k + 1] += np.float32(pv * w1)


@njit(cache=True, nogil=True)
def last_polarity_kernel(x, y, p, out):  # type: ignore[no-untyped-def]
    """``out[y, x] = p`` per event (the latest polarity wins); ``out`` (H, W) int8, 0 = none."""
    for i in range(x.shape[0]):
        out[y[i], x[i]] = p[i]


@njit(cache=True, nogil=True)
def render_polarity_kernel(last, on, off, background, out):  # type: ignore[no-untyped-def]
    """RGB image of a polarity map: ``on``/``off``/``background`` colours
    (uint8[3]) where ``last`` (H, W) int8 is > 0, < 0, 0. ``out`` (H, W, 3) uint8."""
    h, w = last.shape
    for r in range(h):
        for c in range(w):
            v = last[r, c]
            col = on if v > 0 else (off if v < 0 else background)
            out[r, c, 0] = col[0]
            out[r, c, 1] = col[1]
            out[r, c, 2] = col[2]


#: :func:`decay_kernel` splits ``t - base`` (µs) in a multiple of this and a
#: rest below it: one exp per multiple, a table for the rest
DECAY_STEP = 64


@njit(cache=True, nogil=True)
def decay_table(tau_us):  # type: ignore[no-untyped-def]
    """``exp(j / tau_us)`` for ``j < DECAY_STEP`` (µs): :func:`decay_kernel`'s table."""
    out = np.empty(DECAY_STEP)
    inv = 1.0 / tau_us
    for j in range(DECAY_STEP):
        out[j] = np.exp(j * inv)
    return out


@njit(cache=True, nogil=True)
def decay_kernel(t, x, y, p, v, base, tau_us, rebase_after, table):  # type: ignore[no-untyped-def]
    """Time-surface state in factored form: ``v[y, x, p > 0] = exp((t -
    base) / tau_us)`` per event, so that the surface at any ``t_ref`` is
    ``v * exp(-(t_ref - base) / tau_us)`` (:func:`surface_kernel`).
    ``v`` (H, W, 2) float32 or float64 (0 = never fired; at most e^40
    times the value at ``base``), ``base`` int64[1] (µs). When
    an event comes more than ``rebase_after`` µs after ``base``, ``v`` is
    rescaled to that event's time first (keeps ``v`` finite; depends only
    on timestamps, so it is batch invariant).

    ``table``: :func:`decay_table` of ``tau_us``. With ``d = t - base =
    k DECAY_STEP + j``, the exp is ``exp(k DECAY_STEP / tau_us) table[j]``:
    one exp per DECAY_STEP µs that has events (the product is within
    1e-14 relative of the direct exp, so within one float32 ulp of it, and
    it depends only on ``d``: batch invariant) instead of one per distinct
    timestamp (4,600 of 50,000 events a 10 ms window at 5 Mev/s), and no
    branch on each new timestamp (mispredicted once per run of equal
    ones). ``v`` C-contiguous."""
    inv = 1.0 / tau_us
    b = base[0]
    lo = hi = 0  # e_k is the exp of lo = k DECAY_STEP, for d in [lo, hi) (empty: none yet)
    e_k = 0.0
    vf = v.reshape(-1)
    w = np.uint64(v.shape[1])
    for i in range(t.shape[0]):
        d = t[i] - b
        if lo <= d < hi:  # the usual case, one test (no branch on each new timestamp)
            e = e_k * table[d - lo]
        else:
            if d > rebase_after:
                f = np.exp(-d * inv)
                for j in range(vf.shape[0]):
                    vf[j] *= f
                b = t[i]
                d = 0
            if d < 0:  # before the base (not in a stream in order): directly, and again next time
                e = np.exp(d * inv)
                lo = hi = 0
            else:
                lo = d - d % DECAY_STEP
                hi = min(lo + DECAY_STEP, rebase_after + 1)  # never past a rebase
                e_k = np.exp(lo * inv)
                e = e_k * table[d - lo]
        # flat and unsigned: no negative-index checks
        vf[(np.uint64(y[i]) * w + np.uint64(x[i])) * np.uint64(2) + np.uint64(p[i] > 0)] = e
    base[0] = b


@njit(cache=True, nogil=True)
def surface_kernel(v, base, t_ref, tau_us, out):  # type: ignore[no-untyped-def]
    """The time surface at ``t_ref`` (µs) from :func:`decay_kernel`'s state:
    ``out = v * exp(-(t_ref - base) / tau_us)`` as float32 (same shape as ``v``)."""
    c = np.exp(-(t_ref - base[0]) / tau_us)
    vv = v.ravel()
    o = out.ravel()
    for j in range(vv.shape[0]):
        o[j] = np.float32(vv[j] * c)


@njit(cache=True, nogil=True)
def window_splits(t, first, step, out):  # type: ignore[no-untyped-def]
    """``out[k]``: how many of the sorted times ``t`` (µs) are at or before
    ``first + k step`` (``t.searchsorted(first + k step, "right")``), for
    every ``k < len(out)``. All the searches advance together, one level at
    a time, without a branch: the loads of a level are independent, so
    their cache misses overlap (a packet's times are cold: the kernels
    read only x, y, p; numpy's searches, one after another, wait for each
    miss in turn: ~16 a window)."""
    n, m = t.shape[0], out.shape[0]
    for k in range(m):
        out[k] = 0
    span = n
    while span > 1:  # the answer of k is in [out[k], out[k] + span]
        half = span // 2
        for k in range(m):
            b = out[k]
            out[k] = b + half * np.int64(t[b + half - 1] <= first + k * step)
        span -= half
    if n:
        for k in range(m):
            b = out[k]
            out[k] = b + np.int64(t[b] <= first + k * step)


#: :func:`windows_kernel` modes: per-polarity histogram (2 channels), signed sum, count
HISTOGRAM, SIGNED, COUNT = 0, 1, 2


# ``mode`` is a compile-time constant (:func:`numba.literally`) in the
# loops below: each case compiles to its own plain loop with constant
# strides (with the case a runtime value the uint8 count ran 2.5x slower),
# and only the cases used are compiled.
@njit(cache=True, nogil=True, inline="always")
def _at(mode, w, x, y, pe):  # type: ignore[no-untyped-def]
    """An event's flat index (unsigned: no negative-index check): channel
    ``p > 0`` of an (H, W, 2) image for :data:`HISTOGRAM`, else the pixel."""
    i = np.uint64(y) * w + np.uint64(x)
    if mode == HISTOGRAM:
        return i * np.uint64(2) + np.uint64(pe > 0)
    return i


@njit(cache=True, nogil=True, inline="always")
def _step(mode, old, pe, vmin, vmax, free):  # type: ignore[no-untyped-def]
    """A pixel's new value: ``+p`` (:data:`SIGNED`) or ``+1``, within
    ``[vmin, vmax]`` (a count stops at ``vmax``: a compare, not a clip)
    unless ``free`` (no limit can be reached: :func:`_unbounded`; loops
    test it once, not per event: LLVM makes a loop of each case)."""
    if free:
        return old + pe if mode == SIGNED else old + 1
    if mode == SIGNED:
        return min(max(old + pe, vmin), vmax)
    return old + np.int64(old < vmax)


@njit(cache=True, nogil=True, inline="always")
def _unbounded(mode, vmin, vmax, most):  # type: ignore[no-untyped-def]
    """No pixel of an image that starts within ``[-most, most]`` (``[0,
    most]`` for a count) can reach a limit however ``most`` more events fall
    on it (an int32 image, always): the events go in without the compare
    (~25 % of an event's cost: histogram, 10 k events a window, loaded)."""
    return most <= (min(vmax, -vmin) if mode == SIGNED else vmax)


@njit(cache=True, nogil=True)
def _fill(mode, width, vmin, vmax, x, y, p, img, free):  # type: ignore[no-untyped-def]
    """Events into the flat image ``img`` (see :func:`windows_kernel`);
    ``free``: no limit can be reached (:func:`_unbounded`)."""
    literally(mode)
    w = np.uint64(width)
    for e in range(x.shape[0]):
        pe = np.int64(p[e])
        i = _at(mode, w, x[e], y[e], pe)
        img[i] = _step(mode, np.int64(img[i]), pe, vmin, vmax, free)


@njit(cache=True, nogil=True)
def _fill_marked(mode, width, vmin, vmax, x, y, p, img, marks, free):  # type: ignore[no-untyped-def]
    """:func:`_fill` that also writes each event's index into ``marks``
    (as long as ``x``; one store per event, no test)."""
    literally(mode)
    w = np.uint64(width)
    for e in range(x.shape[0]):
        pe = np.int64(p[e])
        i = _at(mode, w, x[e], y[e], pe)
        marks[e] = i
        img[i] = _step(mode, np.int64(img[i]), pe, vmin, vmax, free)


@njit(cache=True, nogil=True)
def _add_events(mode, width, vmin, vmax, x, y, p, img, touched, n):  # type: ignore[no-untyped-def]
    """Events into the flat image ``img`` (see :func:`_fill`), recording the
    indices that leave zero in ``touched[n:]``; returns the new count
    (``n < 0``: no record; -1 too when ``touched`` fills up). Indices are
    unsigned and the loops run over whole arrays (slices): a signed index
    costs a negative-index check per access."""
    literally(mode)
    if n < 0:
        _fill(mode, width, vmin, vmax, x, y, p, img, False)
        return n
    w = np.uint64(width)
    cap = touched.shape[0]
    for e in range(x.shape[0]):
        pe = np.int64(p[e])
        i = _at(mode, w, x[e], y[e], pe)
        old = np.int64(img[i])
        if old == 0:
            if n == cap:  # the list is full: the rest without it
                _fill(mode, width, vmin, vmax, x[e:], y[e:], p[e:], img, False)
                return -1
            touched[n] = i
            n += 1
        img[i] = _step(mode, old, pe, vmin, vmax, False)
    return n


@njit(cache=True, nogil=True)
def _windows(mode, width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks,  # type: ignore[no-untyped-def]
             n_marks):
    """:func:`windows_kernel` for one ``mode``, a compile-time constant
    (the entry point takes it at run time: :func:`numba.literally` there
    would cost a dispatch of milliseconds a call)."""
    literally(mode)
    n_win = splits.shape[0]
    s_size = frames.shape[0] // n_marks.shape[0] if n_win else 0
    cap = marks.shape[1]
    lo = 0
    for k in range(n_win):
        # each frame zeroed (where its last use wrote, if a recycled block) just
        # before it is filled: one frame's memory at a time in the cache
        f = frames[k * s_size:(k + 1) * s_size]
        m = n_marks[k]
        if m < 0:
            f[:] = 0
        else:
            for j in range(m):
                f[marks[k, j]] = 0
        first = 0  # indices frame 0 took from the state
        if k == 0:
            first = n_touched[0]
            for j in range(first if first >= 0 else s_size):
                i = touched[j] if first >= 0 else j
                if state[i] != 0:  # a signed sum may list a pixel twice (it went back to zero)
                    f[i] = state[i]
                    state[i] = 0
            if 0 <= first <= cap:
                for j in range(first):
                    marks[0, j] = touched[j]
            n_touched[0] = 0
        hi = splits[k]
        # the frame starts at zero, frame 0 at what the state holds (its ``held`` events at most)
        free = _unbounded(mode, vmin, vmax, (held if k == 0 else 0) + hi - lo)
        if 0 <= first and first + hi - lo <= cap:
            _fill_marked(mode, width, vmin, vmax, x[lo:hi], y[lo:hi], p[lo:hi], f, marks[k, first:], free)
            n_marks[k] = first + hi - lo
        else:
            _fill(mode, width, vmin, vmax, x[lo:hi], y[lo:hi], p[lo:hi], f, free)
            n_marks[k] = -1
        lo = hi
    n_touched[0] = _add_events(mode, width, vmin, vmax, x[lo:], y[lo:], p[lo:], state, touched, n_touched[0])


def windows_kernel(mode, width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks,  # type: ignore[no-untyped-def]
                   n_marks):
    """One packet's events into consecutive windows of a per-window image.

    ``mode`` (:data:`HISTOGRAM`: ``+1`` at ``(y W + x) 2 + (p > 0)``;
    :data:`SIGNED`: ``+p`` at ``y W + x``; :data:`COUNT`: ``+1`` there),
    ``width`` W (px), values saturate at ``vmin`` and ``vmax`` (``held``:
    at most how many events ``state`` holds, so how far from zero its
    values are: windows that cannot reach a limit skip the compares).
    ``state``
    (S,) is the flat image of the window in progress, non-zero only at
    ``touched[:n_touched[0]]`` (-1: anywhere), or empty (and ``touched``)
    while it holds nothing and no event stays in it; ``frames`` (N S,) the
    flat images of the ``N = len(splits)`` windows this packet completes
    (S is ``frames``' size over ``len(n_marks)``). Window
    ``k`` gets events ``[splits[k - 1], splits[k])`` (window 0 also what
    ``state`` held; ``state`` is zeroed where it was touched); events from
    ``splits[-1]`` on go into ``state``.

    Frames may come from a recycled block: frame ``k`` is non-zero only at
    ``marks[k, :n_marks[k]]`` (-1: anywhere; ``marks`` (N, C) uint32) and
    is zeroed there first. On return ``n_marks[k]`` says where frame ``k``
    was written: its indices in ``marks[k]`` when they fit (one per event
    and per state pixel, not distinct), else -1.

    One compiled function per mode (:data:`WINDOWS` ``[mode]``, what the
    operators call): a dtype compiles only the case it is used with."""
    WINDOWS[mode](width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks, n_marks)


@njit(cache=True, nogil=True)
def _windows_histogram(width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks,  # type: ignore[no-untyped-def]
                       n_marks):
    _windows(HISTOGRAM, width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks, n_marks)


@njit(cache=True, nogil=True)
def _windows_signed(width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks,  # type: ignore[no-untyped-def]
                    n_marks):
    _windows(SIGNED, width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks, n_marks)


@njit(cache=True, nogil=True)
def _windows_count(width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks,  # type: ignore[no-untyped-def]
                   n_marks):
    _windows(COUNT, width, vmin, vmax, held, x, y, p, splits, state, touched, n_touched, frames, marks, n_marks)


#: :func:`windows_kernel` of each mode, without its ``mode`` argument
WINDOWS = {HISTOGRAM: _windows_histogram, SIGNED: _windows_signed, COUNT: _windows_count}
