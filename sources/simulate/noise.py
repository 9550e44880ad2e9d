"""Sensor non-idealities: the model's parameters, its presets, and the
labelled noise events.

Noise events are independent of the signal path and never touch a pixel's
``L_ref``; each carries a ``noise`` label: 1 background-activity shot noise,
2 hot pixel, 3 leak. Signal events have ``noise = 0``.

* **Shot noise**: a Poisson process per pixel with rate
  ``shot_noise_hz * (1 + dark_gain * (1 - clip(I, 0, 1)))`` where ``I`` is the
  pixel's linear intensity (1 = full scale): brighter is quieter. Polarity
  ±1 with equal odds.
* **Hot pixels**: a fixed random ``hot_fraction`` of pixels fire ON events as
  a Poisson process of ``hot_hz``.
* **Leak**: every pixel fires periodic ON events at ``leak_hz`` (per-pixel
  rate spread ``leak_spread`` relative std, random phase).
* **Timestamp jitter**: every event is delayed by ``|N(0, jitter_us)|``,
  truncated at 4 standard deviations.

Candidates are drawn in fixed 10 ms blocks of absolute time, each from its
own seeded generator, so the stream does not depend on how the run is cut
into windows or steps.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["SensorModel", "PRESETS", "sensor_model", "start_references", "NoiseSource", "SHOT", "HOT", "LEAK"]

SHOT, HOT, LEAK = 1, 2, 3
BLOCK_US = 10_000


@dataclass(frozen=True)
class SensorModel:
    """DVS pixel parameters (log-intensity units, µs, Hz per pixel)."""

    c_on: float = 0.2            #: ON threshold (log intensity)
    c_off: float = 0.2           #: OFF threshold (log intensity)
    sigma_c: float = 0.0         #: per-pixel threshold spread, std (log units)
    refractory_us: float = 0.0   #: reset hold after each event (µs)
    shot_noise_hz: float = 0.0   #: background activity at full intensity (Hz/pixel)
    dark_gain: float = 0.0       #: extra shot noise in the dark (rate x (1 + gain) at I = 0)
    hot_fraction: float = 0.0    #: fraction of hot pixels
    hot_hz: float = 0.0          #: hot-pixel event rate (Hz)
    leak_hz: float = 0.0         #: leak event rate (Hz/pixel)
    leak_spread: float = 0.0     #: relative std of the per-pixel leak rate
    lowpass_hz: float = 0.0      #: photoreceptor cut-off at full intensity (Hz; 0 = off)
    lowpass_min_hz: float = 5.0  #: cut-off floor in the dark (Hz)
    jitter_us: float = 0.0       #: timestamp jitter, std of the delay (µs)
    eps: float = 1e-3            #: L = log(I + eps)
    ref_spread: float = 0.0      #: spread of the references at t = 0, fraction of the thresholds (see start_references)

    def replace(self, **kw: Any) -> SensorModel:
        known = {f.name for f in dataclasses.fields(self)}
        bad = set(kw) - known
        if bad:
            raise ValueError(f"unknown sensor-model parameters {sorted(bad)}; known: {sorted(known)}")
        return dataclasses.replace(self, **{k: float(v) for k, v in kw.items()})

    def jitter_margin_us(self) -> int:
        """The largest delay jitter can add (µs)."""
        return int(math.ceil(4.0 * self.jitter_us))


#: ``ideal``: every non-ideality off. ``realistic``: figures typical of a
#: DAVIS346 in office light (threshold spread 0.03 as in v2e's model, about
#: 0.1-1 Hz/pixel background activity, 0.1 % hot pixels, slow leak, a few
#: hundred Hz photoreceptor bandwidth). ``noisy``: the same sensor in low light.
PRESETS: dict[str, SensorModel] = {
    "ideal": SensorModel(),
    "realistic": SensorModel(sigma_c=0.03, refractory_us=100.0, shot_noise_hz=0.2, dark_gain=4.0,
                             hot_fraction=0.001, hot_hz=20.0, leak_hz=0.1, leak_spread=0.1,
                             lowpass_hz=300.0, jitter_us=10.0),
    "noisy": SensorModel(sigma_c=0.04, refractory_us=200.0, shot_noise_hz=1.0, dark_gain=5.0,
                         hot_fraction=0.002, hot_hz=50.0, leak_hz=0.5, leak_spread=0.2,
                         lowpass_hz=100.0, jitter_us=50.0),
}


def sensor_model(preset: str | SensorModel = "ideal", **overrides: Any) -> SensorModel:
    """A preset by name (``ideal``, ``realistic``, ``noisy``) with overrides."""
    if isinstance(preset, SensorModel):
        base = preset
    else:
        try:
            base = PRESETS[preset]
        except KeyError:
            raise ValueError(f"unknown preset {preset!r}; known: {', '.join(PRESETS)}") from None
    return base.replace(**overrides) if overrides else base


def thresholds(model: SensorModel, npix: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel ``(C_on, C_off)`` with the model's spread (at least 0.01)."""
    if model.sigma_c <= 0:
        return np.full(npix, model.c_on), np.full(npix, model.c_off)
    rng = np.random.default_rng([seed & 0x7FFFFFFF, 101])
    c_on = np.maximum(model.c_on + model.sigma_c * rng.standard_normal(npix), 0.01)
    c_off = np.maximum(model.c_off + model.sigma_c * rng.standard_normal(npix), 0.01)
    return c_on, c_off


def start_references(L: np.ndarray, c_on: np.ndarray, c_off: np.ndarray, spread: float, seed: int) -> np.ndarray:
    """Each pixel's reference log level at t = 0 for log intensities ``L``.

    ``spread = 0``: ``L`` itself, every pixel reset at t = 0 (a sensor
    switched on then). With equal thresholds the references then stay on the
    lattice ``L(0) + k C``, so wherever the scene comes back to its t = 0
    image (a periodic motion after a whole period) every pixel with one net
    event sits exactly on a threshold and they all fire at once.
    ``spread = 1``: ``L - d``, ``d`` uniform in ``(-C_off, C_on)`` per pixel
    (a sensor running before the recording: no pixel past a threshold, none
    in step with another); values between scale ``d``.
    """
    if not 0.0 <= spread <= 1.0:
        raise ValueError(f"sensor model: ref_spread must be in [0, 1], got {spread}")
    if spread == 0.0:
        return L.copy()
    u = np.random.default_rng([seed & 0x7FFFFFFF, 107]).random(L.shape[0])
    return L - spread * (u * (c_on + c_off) - c_off)


class NoiseSource:
    """Labelled noise candidates for a ``w x h`` sensor, taken step by step.

    :meth:`take` returns the candidates with ``t0 < t <= t1`` (µs, float);
    shot-noise candidates carry a uniform draw ``u`` and are kept when
    ``u * rate_max < rate(I)`` (thinning by the intensity at that step).
    """

    def __init__(self, model: SensorModel, sensor: tuple[int, int], seed: int) -> None:
        self.m = model
        self.npix = sensor[0] * sensor[1]
        self.seed = seed & 0x7FFFFFFF
        rng = np.random.default_rng([self.seed, 102])
        nhot = int(round(model.hot_fraction * self.npix)) if model.hot_hz > 0 else 0
        self.hot = np.sort(rng.choice(self.npix, nhot, replace=False)) if nhot else np.empty(0, np.int64)
        if model.leak_hz > 0:
            self.leak_rate = np.maximum(model.leak_hz * (1 + model.leak_spread * rng.standard_normal(self.npix)),
                                        model.leak_hz * 0.05)
            self.leak_phase = rng.random(self.npix)
        self.rate_max = model.shot_noise_hz * (1.0 + model.dark_gain)
        self.enabled = self.rate_max > 0 or nhot > 0 or model.leak_hz > 0
        self._block = -1
        self._buf: tuple[np.ndarray, ...] = _empty()
        self._pos = 0

    def shot_rate(self, intensity: np.ndarray) -> np.ndarray:
        """Shot-noise rate (Hz) at linear intensities ``intensity``."""
        return self.m.shot_noise_hz * (1.0 + self.m.dark_gain * (1.0 - np.clip(intensity, 0.0, 1.0)))

    def _make_block(self, b: int) -> tuple[np.ndarray, ...]:
        b0, b1 = b * BLOCK_US, (b + 1) * BLOCK_US
        rng = np.random.default_rng([self.seed, 103, b])
        span_s = BLOCK_US * 1e-6
        parts = []
        if self.rate_max > 0:
            n = rng.poisson(self.rate_max * self.npix * span_s)
            parts.append((rng.uniform(b0, b1, n), rng.integers(0, self.npix, n),
                          np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8), rng.random(n),
                          np.full(n, SHOT, np.uint8)))
        if self.hot.size:
            n = rng.poisson(self.m.hot_hz * self.hot.size * span_s)
            parts.append((rng.uniform(b0, b1, n), self.hot[rng.integers(0, self.hot.size, n)],
                          np.ones(n, np.int8), np.full(n, -1.0), np.full(n, HOT, np.uint8)))
        if self.m.leak_hz > 0:
            r, ph = self.leak_rate, self.leak_phase
            k0 = np.ceil(b0 * 1e-6 * r - ph)
            k1 = np.ceil(b1 * 1e-6 * r - ph)
            cnt = (k1 - k0).astype(np.int64)
            idx = np.repeat(np.arange(self.npix), cnt)
            k = np.repeat(k0, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
            t = (k + ph[idx]) / r[idx] * 1e6
            parts.append((t, idx, np.ones(idx.size, np.int8), np.full(idx.size, -1.0),
                          np.full(idx.size, LEAK, np.uint8)))
        if not parts:
            return _empty()
        cols = [np.concatenate([p[i] for p in parts]) for i in range(5)]
        order = np.argsort(cols[0], kind="stable")
        return tuple(c[order] for c in cols)

    def take(self, t0: float, t1: float) -> tuple[np.ndarray, ...]:
        """Candidates ``(t µs, pixel, p, u, label)`` with ``t0 < t <= t1``."""
        if not self.enabled:
            return _empty()
        out = []
        while True:
            b = int(t0 // BLOCK_US) if self._block < 0 else self._block
            if b != self._block:
                self._block, self._buf, self._pos = b, self._make_block(b), 0
            t = self._buf[0]
            i = self._pos + int(np.searchsorted(t[self._pos:], t0, side="right"))
            j = i + int(np.searchsorted(t[i:], t1, side="right"))
            out.append(tuple(c[i:j] for c in self._buf))
            self._pos = j
            if t1 < (b + 1) * BLOCK_US:
                break
            self._block, self._buf, self._pos = b + 1, self._make_block(b + 1), 0
        if len(out) == 1:
            return out[0]
        return tuple(np.concatenate([o[k] for o in out]) for k in range(5))


def _empty() -> tuple[np.ndarray, ...]:
    return (np.empty(0), np.empty(0, np.int64), np.empty(0, np.int8), np.empty(0), np.empty(0, np.uint8))
