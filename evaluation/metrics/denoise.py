"""Denoising accuracy on labelled events: signal kept, noise passed, ROC AUC.

Works on any packet with a ``noise`` column (1 = noise, 0 = signal), such as
the ``pattern:`` source's or the simulator's output.
"""

from __future__ import annotations

from collections.abc import Sequence
from math import comb, exp

import numpy as np

from tectum import EventPacket

__all__ = ["denoise_rates", "noise_passed_by_label", "roc_auc", "binomial_pass"]


def _labels(packet: EventPacket, keep: np.ndarray, t_from: int | None) -> tuple[np.ndarray, np.ndarray]:
    if "noise" not in packet.columns:
        raise ValueError("packet has no 'noise' column (0 = signal, > 0 = noise)")
    label = np.asarray(packet.columns["noise"])
    keep = np.asarray(keep, bool)
    if keep.shape != label.shape:
        raise ValueError(f"keep has {keep.shape[0]} decisions for {label.shape[0]} events")
    if t_from is not None:
        scored = packet.t >= t_from
        label, keep = label[scored], keep[scored]
    return label, keep


def denoise_rates(packet: EventPacket, keep: np.ndarray, *, t_from: int | None = None) -> tuple[float, float]:
    """``(signal kept, noise passed)`` fractions for the decision ``keep``
    (bool, one per event of ``packet``, which needs a ``noise`` column:
    0 signal, any other value noise, e.g. the simulator's 1 shot, 2 hot
    pixel, 3 leak). With ``t_from`` (µs) only events at or after it are
    scored (a warm-up for the filter's history). A class with no events
    gives NaN."""
    label, keep = _labels(packet, keep, t_from)
    noise = label.astype(bool)
    n_noise, n_sig = int(noise.sum()), int((~noise).sum())
    tpr = float(keep[~noise].sum() / n_sig) if n_sig else float("nan")
    fpr = float(keep[noise].sum() / n_noise) if n_noise else float("nan")
    return tpr, fpr


def noise_passed_by_label(packet: EventPacket, keep: np.ndarray, *, t_from: int | None = None) -> dict[int, float]:
    """Fraction passed of each noise label present (``{label: fraction}``,
    labels > 0 of the ``noise`` column), scored as :func:`denoise_rates`."""
    label, keep = _labels(packet, keep, t_from)
    return {int(v): float(keep[label == v].mean()) for v in np.unique(label) if v > 0}


def roc_auc(points: Sequence[tuple[float, float]]) -> float:
    """Area under the ROC curve through ``(signal kept, noise passed)``
    points of one parameter sweep, closed by (0, 0) and (1, 1) and made
    monotone (upper hull of the points met so far), by the trapezoid rule.
    Points with a NaN rate (a class with no events) are left out."""
    pts = sorted({(0.0, 0.0), (1.0, 1.0), *((float(f), float(t)) for t, f in points if t == t and f == f)})
    fpr = np.array([p[0] for p in pts])
    tpr = np.maximum.accumulate(np.array([p[1] for p in pts]))
    return float(np.sum((fpr[1:] - fpr[:-1]) * (tpr[1:] + tpr[:-1]) / 2.0))


def binomial_pass(rate_hz: float, dt_us: float, k: int, n: int = 8) -> float:
    """``P[Binomial(n, 1 - exp(-rate dt)) >= k]``: the fraction of Poisson
    noise (``rate_hz`` per pixel) a k-of-n neighbour filter passes."""
    q = 1.0 - exp(-rate_hz * dt_us * 1e-6)
    return float(sum(comb(n, j) * q**j * (1 - q) ** (n - j) for j in range(k, n + 1)))
