"""A built-in moving pattern: bars sweeping across the sensor, plus noise.

``pattern:`` (or ``pattern:bars``) opens it. Bars of ``bar_px`` pixels repeat
every ``period_px`` pixels and move along x at ``speed`` px/s: each leading
edge makes ON events, each trailing edge OFF events, at the exact crossing
time plus a small per-pixel jitter. Background noise at ``noise_hz`` per
pixel is added as a Poisson process and marked in the ``noise`` column
(1 = noise, 0 = signal), with the true flow in ``vx``/``vy`` (px/s, NaN for
noise). Deterministic for a given ``seed``; generated in windows of
``window_us`` so memory stays flat however long the run.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from tectum import EventPacket, Source

__all__ = ["PatternSource", "moving_bars"]


def moving_bars(
    t0: int, t1: int, *, sensor: tuple[int, int], speed: float, period_px: int, bar_px: int,
    noise_hz: float, jitter_us: float, rng: np.random.Generator,
) -> EventPacket:
    """Events of the moving bars in ``[t0, t1)`` µs, sorted by time."""
    w, h = sensor
    ts, xs, ps = [], [], []
    if speed > 0:
        for offset, pol in ((0.0, 1), (float(bar_px), -1)):
            # column c is crossed when speed * t == c + offset + m * period
            cols = np.arange(w, dtype=np.float64)
            m0 = np.ceil((speed * t0 / 1e6 - cols - offset) / period_px)
            m1 = np.ceil((speed * t1 / 1e6 - cols - offset) / period_px)
            counts = (m1 - m0).astype(np.int64)
            if counts.sum() == 0:
                continue
            col = np.repeat(np.arange(w), counts)
            first = np.repeat(m0, counts)
            k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
            tc = (col + offset + (first + k) * period_px) / speed * 1e6
            ts.append(tc)
            xs.append(col)
            ps.append(np.full(col.shape, pol, np.int8))
    if ts:
        tc = np.concatenate(ts)
        col = np.concatenate(xs)
        pc = np.concatenate(ps)
        t = np.repeat(tc, h) + rng.normal(0.0, jitter_us, tc.size * h) if jitter_us else np.repeat(tc, h)
        x = np.repeat(col, h)
        y = np.tile(np.arange(h), tc.size)
        p = np.repeat(pc, h)
        keep = (t >= t0) & (t < t1)
        t, x, y, p = np.floor(t[keep]).astype(np.int64), x[keep], y[keep], p[keep]
    else:
        t = np.empty(0, np.int64)
        x = y = np.empty(0, np.int64)
        p = np.empty(0, np.int8)
    n_noise = rng.poisson(noise_hz * w * h * (t1 - t0) / 1e6) if noise_hz > 0 else 0
    tn = rng.integers(t0, t1, n_noise)
    xn = rng.integers(0, w, n_noise)
    yn = rng.integers(0, h, n_noise)
    pn = np.where(rng.random(n_noise) < 0.5, 1, -1).astype(np.int8)
    t = np.concatenate([t, tn])
    order = np.argsort(t, kind="stable")
    noise = np.concatenate([np.zeros(len(x), np.uint8), np.ones(n_noise, np.uint8)])[order]
    vx = np.where(noise == 1, np.nan, speed).astype(np.float32)
    vy = np.where(noise == 1, np.nan, 0.0).astype(np.float32)
    return EventPacket(
        t[order],
        np.concatenate([x, xn]).astype(np.uint16)[order],
        np.concatenate([y, yn]).astype(np.uint16)[order],
        np.concatenate([p, pn]).astype(np.int8)[order],
        sensor=sensor, t_start=t0, t_end=t1, columns={"noise": noise, "vx": vx, "vy": vy},
    )


class PatternSource(Source):
    """Moving bars with labelled noise (see the module docstring).

    Parameters (units): ``sensor`` "WxH" pixels; ``duration_us`` µs;
    ``speed`` px/s; ``period_px``, ``bar_px`` pixels; ``noise_hz`` events per
    pixel per second; ``jitter_us`` µs (standard deviation); ``window_us``
    µs per generated packet; ``seed``.
    """

    name = "pattern"
    schemes = ("pattern",)

    def __init__(self, url: str = "pattern:", sensor: str = "346x260", duration_us: int = 1_000_000,
                 speed: float = 200.0, period_px: int = 24, bar_px: int = 8, noise_hz: float = 1.0,
                 jitter_us: float = 50.0, window_us: int = 10_000, seed: int = 0) -> None:
        kind = url.split(":", 1)[1] if ":" in url else ""
        if kind not in ("", "bars"):
            raise ValueError(f"unknown pattern {kind!r}; known: bars")
        w, h = (int(v) for v in sensor.lower().split("x"))
        if duration_us <= 0 or window_us <= 0 or period_px <= 0 or not 0 < bar_px < period_px:
            raise ValueError("need duration_us > 0, window_us > 0 and 0 < bar_px < period_px")
        if speed < 0 or noise_hz < 0 or jitter_us < 0:
            raise ValueError("speed, noise_hz and jitter_us must be >= 0")
        self.sensor = (w, h)
        self.duration_us, self.window_us = duration_us, window_us
        self.kw = dict(speed=speed, period_px=period_px, bar_px=bar_px, noise_hz=noise_hz, jitter_us=jitter_us)
        self.seed = seed

    def packets(self) -> Iterator[EventPacket]:
        rng = np.random.default_rng(self.seed)
        # jittered events can leave their window: generate with a margin, keep in order
        for t0 in range(0, self.duration_us, self.window_us):
            t1 = min(t0 + self.window_us, self.duration_us)
            yield moving_bars(t0, t1, sensor=self.sensor, rng=rng, **self.kw)  # type: ignore[arg-type]
