"""Numba kernels of the representations: pure functions on arrays that
accumulate into (or render from) caller-owned state.

Layouts are channels-last, like :class:`tectum.FramePacket` images:
``(H, W)`` or ``(H, W, C)``. Per-polarity channels: 0 = OFF (p = -1),
1 = ON (p = +1).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "NEVER", "histogram_kernel", "signed_kernel", "count_kernel", "sae_kernel",
    "time_surface_kernel", "decay_kernel", "surface_kernel", "voxel_kernel", "last_polarity_kernel",
    "render_polarity_kernel",
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


@njit(cache=True, nogil=True)
def decay_kernel(t, x, y, p, v, base, tau_us, rebase_after):  # type: ignore[no-untyped-def]
    """Time-surface state in factored form: ``v[y, x, p > 0] = exp((t -
    base) / tau_us)`` per event, so that the surface at any ``t_ref`` is
    ``v * exp(-(t_ref - base) / tau_us)`` (:func:`surface_kernel`).
    ``v`` (H, W, 2) float64 (0 = never fired), ``base`` int64[1] (µs). When
    an event comes more than ``rebase_after`` µs after ``base``, ``v`` is
    rescaled to that event's time first (keeps ``v`` finite; depends only
    on timestamps, so it is batch invariant). One exp per distinct timestamp
    (runs of equal ones share it) instead of one per pixel per frame."""
    inv = 1.0 / tau_us
    b = base[0]
    t_prev = b - 1  # exp of the previous timestamp, reused for runs of equal ones
    e = 0.0
    for i in range(t.shape[0]):
        ti = t[i]
        if ti != t_prev:
            if ti - b > rebase_after:
                f = np.exp(-(ti - b) * inv)
                vv = v.ravel()
                for j in range(vv.shape[0]):
                    vv[j] *= f
                b = ti
            e = np.exp((ti - b) * inv)
            t_prev = ti
        v[y[i], x[i], 1 if p[i] > 0 else 0] = e
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
