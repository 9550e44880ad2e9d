"""Kernels of ``map.high_pass`` and ``map.complementary``: per-pixel leaky
integration of events into log intensity (Scheerlinck, Barnes, Mahony,
"Continuous-time intensity estimation using event cameras", ACCV 2018).

Each pixel obeys ``dL/dt = E(t) - α (L - L_F)``: every event adds its
contrast (``+c_on`` for ON, ``-c_off`` for OFF, log-intensity units) and,
between events, ``L`` relaxes towards the base ``L_F`` with rate ``α``
(rad/s: the filter's crossover frequency). ``L_F = 0`` is the high-pass
filter; ``L_F`` = the log of the latest APS frame is the complementary
filter (high-pass on events, low-pass on frames).

State, explicit, per pixel: ``D = L - L_F`` (float32, log intensity) and
the time of its last update ``t_last`` (int64 µs; :data:`NEVER` before any).
An event at ``t`` does ``D = D exp(-α (t - t_last)) + c; t_last = t``: one
read-modify-write of two cells and one ``exp`` per event. Reading the map
at ``T`` needs every pixel decayed to ``T``: :func:`read_map` does that for
the whole image at once (vectorised), without touching the state, so the
state is a function of the events (and frames) only and never of when maps
are read. A new frame at ``t_F`` decays every pixel to ``t_F`` and moves
the base (:func:`switch_base`), keeping ``L`` continuous.

Numerics: float32 state (the maps are float32); ``α (t - t_last)`` is
formed in float32, whose 24-bit mantissa holds µs exactly up to 16.7 s
between two updates of a pixel, by when ``exp`` has long underflowed for
any useful ``α``. :data:`NEVER` (-2^62 µs) makes the first event's decay
factor exactly 0 for ``α > 0`` (and 1 for ``α = 0``, pure integration),
with no overflow in ``t - NEVER``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["NEVER", "integrate_events", "read_map", "switch_base", "new_state", "log_frame"]

#: ``t_last`` of a pixel never updated (µs).
NEVER = -(1 << 62)


@njit(cache=True, nogil=True, fastmath=True)
def integrate_events(t, x, y, p, D, t_last, alpha_per_us, c_on, c_off):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Add events ``(t µs, x, y px, p ±1)`` (time-sorted) into the state
    ``D`` (H, W) float32 and ``t_last`` (H, W) int64 µs: per event
    ``D = D exp(-alpha_per_us (t - t_last)) + (c_on if p > 0 else -c_off)``."""
    a = np.float32(alpha_per_us)
    con = np.float32(c_on)
    coff = np.float32(-c_off)
    for i in range(t.shape[0]):
        xi = np.intp(x[i])
        yi = np.intp(y[i])
        ti = t[i]
        dt = np.float32(ti - t_last[yi, xi])
        c = con if p[i] > 0 else coff
        D[yi, xi] = D[yi, xi] * np.exp(-a * dt) + c
        t_last[yi, xi] = ti


@njit(cache=True, nogil=True, fastmath=True, inline="always")
def _decay(tl, t, a):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The factor ``exp(-a (t - tl))`` (float32) of a value last updated at
    ``tl`` µs, read at ``t``; 0 for a pixel never updated."""
    if tl == NEVER:
        return np.float32(0.0)
    return np.exp(-a * np.float32(t - tl))


@njit(cache=True, nogil=True, fastmath=True)
def read_map(D, t_last, base, t, alpha_per_us, image, confidence):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The map at ``t`` µs: ``image = base + D exp(-alpha_per_us (t - t_last))``
    and ``confidence`` = that decay factor (the weight left of the pixel's
    latest update; 0 for a pixel never updated). ``base`` (H, W) float32, or
    a (0, 0) array for ``L_F = 0``. Writes ``image`` and ``confidence``
    (H, W) float32; the state is not modified."""
    a = np.float32(alpha_per_us)
    h, w = D.shape
    has_base = base.shape[0] > 0
    for j in range(h):
        for i in range(w):
            k = _decay(t_last[j, i], t, a)
            v = D[j, i] * k
            if has_base:
                v += base[j, i]
            image[j, i] = v
            confidence[j, i] = k


@njit(cache=True, nogil=True, fastmath=True)
def switch_base(D, t_last, old_base, new_base, t, alpha_per_us):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """A new frame at ``t`` µs: decay every pixel of ``D`` to ``t`` under the
    old base, then change base keeping ``L = base + D`` continuous:
    ``D += old_base - new_base``; ``t_last = t`` everywhere. ``old_base``
    (0, 0) means ``L_F = 0``."""
    a = np.float32(alpha_per_us)
    h, w = D.shape
    has_old = old_base.shape[0] > 0
    for j in range(h):
        for i in range(w):
            v = D[j, i] * _decay(t_last[j, i], t, a)
            if has_old:
                v += old_base[j, i]
            D[j, i] = v - new_base[j, i]
            t_last[j, i] = t


def new_state(sensor: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Fresh state ``(D, t_last)`` for a ``(width, height)`` sensor: zeros and
    :data:`NEVER`; 12 bytes per pixel (1.1 MB at 346x260)."""
    w, h = sensor
    return np.zeros((h, w), np.float32), np.full((h, w), NEVER, np.int64)


def log_frame(image: np.ndarray, offset: float) -> np.ndarray:
    """``log(v / full_scale + offset)`` (float32) of an APS frame ``image``
    (H, W) or (H, W, C) (channels averaged): ``full_scale`` 255 for uint8,
    65535 for uint16, 1 for floats (already linear, 1 = full scale)."""
    img = np.asarray(image)
    if img.dtype.kind not in "uif":
        raise ValueError(f"an APS frame must be numeric, got {img.dtype}")
    if img.ndim == 3:
        img = img.mean(axis=2)
    elif img.ndim != 2:
        raise ValueError(f"an APS frame must be (H, W) or (H, W, C), got shape {img.shape}")
    scale = float(np.iinfo(img.dtype).max) if img.dtype.kind in "ui" else 1.0
    lin = img.astype(np.float64) / scale
    if not np.all(np.isfinite(lin)) or lin.min() < 0:
        raise ValueError("an APS frame has negative or non-finite values")
    return np.log(lin + offset).astype(np.float32)

