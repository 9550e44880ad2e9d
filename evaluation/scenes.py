"""Analytic scenes with exact flow: straight edges translating at constant velocity.

Used by the flow tests and ``tectum bench flow`` (accuracy, failure maps)
where the full simulator is not needed. A scene is a set of families of
parallel straight edges; family ``k`` has unit normal ``n_k`` (angle given in
degrees) and edges every ``spacing_px`` pixels along ``n_k``. The whole pattern
translates at ``(vx, vy)`` px/s, so a pixel centre ``q`` lies on edge ``j`` at
time ``t = (n_k . q - d_j) / (n_k . v)``.

Each edge is a ramp of ``blur_px`` pixels with a log-contrast drawn uniformly
in ``contrast``; a pixel emits one event each time its log intensity crosses
a multiple of ``threshold`` (with a random reference level per crossing), so
low thresholds give several events per edge and high thresholds drop faint
edges. Timestamps get Gaussian jitter (``jitter_us``) and uniform background
noise at ``noise_hz`` per pixel is added and labelled.

Truth columns (px/s, µs): ``vx``/``vy`` full flow, ``nvx``/``nvy`` the
normal flow of the edge that made the event, ``lifetime`` = 1e6 / |normal
speed|, ``noise`` (1 = noise); NaN truth for noise events.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from tectum import EventPacket

__all__ = ["translating_edges"]


def translating_edges(
    sensor: tuple[int, int] = (64, 64),
    duration_us: int = 200_000,
    vx: float = 200.0,
    vy: float = 0.0,
    *,
    angles_deg: Sequence[float] = (0.0,),
    spacing_px: float = 12.0,
    irregular: float = 0.3,
    contrast: tuple[float, float] = (0.3, 0.8),
    threshold: float = 0.25,
    blur_px: float = 1.0,
    jitter_us: float = 0.0,
    noise_hz: float = 0.0,
    seed: int = 0,
) -> EventPacket:
    """Events of families of straight edges translating at ``(vx, vy)`` px/s.

    ``angles_deg``: direction of each family's edge normal (0 = edges along
    y, moving along x when ``vx > 0``). ``spacing_px``: mean distance between
    parallel edges (texture density = 1/spacing); ``irregular``: random shift
    of each edge as a fraction of the spacing. Returns one packet over
    ``[0, duration_us)`` with the truth columns of the module docstring.
    """
    w, h = sensor
    rng = np.random.default_rng(seed)
    v = np.array([vx, vy], np.float64)
    yy, xx = np.mgrid[0:h, 0:w]
    qx, qy = xx.ravel().astype(np.float64), yy.ravel().astype(np.float64)
    T = duration_us * 1e-6
    parts: list[tuple[np.ndarray, ...]] = []
    for ang in angles_deg:
        n = np.array([np.cos(np.radians(ang)), np.sin(np.radians(ang))])
        nv = float(n @ v)
        if abs(nv) < 1e-9:
            continue  # edges parallel to the motion never cross a pixel
        proj = n[0] * qx + n[1] * qy
        lo = proj.min() - max(nv * T, 0.0) - blur_px
        hi = proj.max() - min(nv * T, 0.0) + blur_px
        d = np.arange(lo - spacing_px, hi + spacing_px, spacing_px)
        d = d + rng.uniform(-irregular, irregular, d.size) * spacing_px * 0.5
        sign = np.where(np.arange(d.size) % 2 == 0, 1, -1)
        mag = rng.uniform(contrast[0], contrast[1], d.size)
        ramp_us = blur_px / abs(nv) * 1e6
        for dj, sj, cj in zip(d, sign, mag):
            tc = (proj - dj) / nv * 1e6  # centre crossing time of every pixel, µs
            near = np.flatnonzero((tc > -ramp_us) & (tc < duration_us + ramp_us))
            if near.size == 0:
                continue
            # threshold crossings at levels (k + u) * threshold inside [0, contrast)
            u = rng.random(near.size)
            count = np.floor(cj / threshold - u).astype(np.int64) + 1
            count = np.maximum(count, 0)
            pix = np.repeat(near, count)
            k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
            level = (k + np.repeat(u, count)) * threshold / cj  # 0..1 along the ramp
            t = np.repeat(tc[near], count) + (level - 0.5) * ramp_us
            pol = sj if nv > 0 else -sj
            parts.append((t, pix, np.full(t.size, pol, np.int8), np.full(t.size, n[0] * nv),
                          np.full(t.size, n[1] * nv)))
    if parts:
        t = np.concatenate([q[0] for q in parts])
        pix = np.concatenate([q[1] for q in parts])
        p = np.concatenate([q[2] for q in parts])
        nvx = np.concatenate([q[3] for q in parts])
        nvy = np.concatenate([q[4] for q in parts])
    else:
        t = np.empty(0)
        pix = np.empty(0, np.int64)
        p = np.empty(0, np.int8)
        nvx = nvy = np.empty(0)
    if jitter_us > 0:
        t = t + rng.normal(0.0, jitter_us, t.size)
    t = np.floor(t)
    keep = (t >= 0) & (t < duration_us)
    t, pix, p, nvx, nvy = t[keep].astype(np.int64), pix[keep], p[keep], nvx[keep], nvy[keep]
    n_noise = int(rng.poisson(noise_hz * w * h * T)) if noise_hz > 0 else 0
    t = np.concatenate([t, rng.integers(0, duration_us, n_noise)])
    pix = np.concatenate([pix, rng.integers(0, w * h, n_noise)])
    p = np.concatenate([p, np.where(rng.random(n_noise) < 0.5, 1, -1).astype(np.int8)])
    nan = np.full(n_noise, np.nan)
    nvx, nvy = np.concatenate([nvx, nan]), np.concatenate([nvy, nan])
    noise = np.concatenate([np.zeros(keep.sum(), np.uint8), np.ones(n_noise, np.uint8)])
    order = np.argsort(t, kind="stable")
    speed2 = nvx ** 2 + nvy ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        life = 1e6 / np.sqrt(speed2)
    full_x = np.where(noise == 1, np.nan, vx)
    full_y = np.where(noise == 1, np.nan, vy)
    cols = {"vx": full_x, "vy": full_y, "nvx": nvx, "nvy": nvy, "lifetime": life, "noise": noise}
    return EventPacket(
        t[order], (pix[order] % w).astype(np.uint16), (pix[order] // w).astype(np.uint16), p[order],
        sensor=(w, h), t_start=0, t_end=duration_us,
        columns={k: (c[order].astype(np.float32) if c.dtype.kind == "f" else c[order]) for k, c in cols.items()},
    )
