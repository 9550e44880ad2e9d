"""Flow and lifetime accuracy against ground truth (the field's metrics).

* AEE: average endpoint error ``|v - v_true|`` in px/s over the events given a
  valid flow, and relative: the mean of ``|v - v_true| / |v_true|`` in %.
* median relative error (%), robust to the few gross errors.
* AAE: average angle between estimated and true 2-D flow vectors, degrees.
* density: fraction of signal (non-noise) events given a valid flow;
  ``noise_valid``: fraction of noise events given one (should be small).
* lifetime: relative error of the estimated lifetime to ``1e6/|normal speed|``.

Normal-flow methods are scored against the *normal component* of the truth
(the ``nvx``/``nvy`` columns of :mod:`tectum.plugins.flow.scenes`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["flow_errors", "lifetime_errors"]


def flow_errors(vx: np.ndarray, vy: np.ndarray, valid: np.ndarray, true_vx: np.ndarray, true_vy: np.ndarray,
                noise: np.ndarray | None = None) -> dict[str, float]:
    """Accuracy of a flow estimate; arrays are per event, truth NaN where unknown
    (noise events). Returns ``aee`` (px/s), ``rel_aee_pct``, ``median_rel_pct``,
    ``aae_deg``, ``density``, ``noise_valid``, ``n_scored``."""
    valid = np.asarray(valid, bool)
    tx, ty = np.asarray(true_vx, np.float64), np.asarray(true_vy, np.float64)
    has_truth = np.isfinite(tx) & np.isfinite(ty)
    is_noise = ~has_truth if noise is None else np.asarray(noise) == 1
    signal = ~is_noise & has_truth
    m = valid & signal
    ex, ey = np.asarray(vx, np.float64)[m], np.asarray(vy, np.float64)[m]
    tx, ty = tx[m], ty[m]
    err = np.hypot(ex - tx, ey - ty)
    tnorm = np.hypot(tx, ty)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = err / tnorm
        cosang = (ex * tx + ey * ty) / (np.hypot(ex, ey) * tnorm)
    ang = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
    nan = float("nan")
    return {
        "aee": float(err.mean()) if err.size else nan,
        "rel_aee_pct": float(np.nanmean(rel) * 100) if err.size else nan,
        "median_rel_pct": float(np.nanmedian(rel) * 100) if err.size else nan,
        "aae_deg": float(np.nanmean(ang)) if err.size else nan,
        "density": float(m.sum() / max(signal.sum(), 1)),
        "noise_valid": float((valid & is_noise).sum() / max(is_noise.sum(), 1)) if is_noise.any() else 0.0,
        "n_scored": int(m.sum()),
    }


def lifetime_errors(lifetime: np.ndarray, true_lifetime: np.ndarray, noise: np.ndarray | None = None) -> dict[str, float]:
    """Relative error of lifetimes (µs) to the truth ``1e6/|normal speed|``;
    NaN estimates are invalid. Returns ``mean_rel_pct``, ``median_rel_pct``,
    ``density``, ``noise_valid``."""
    est = np.asarray(lifetime, np.float64)
    tru = np.asarray(true_lifetime, np.float64)
    valid = np.isfinite(est)
    has_truth = np.isfinite(tru)
    is_noise = ~has_truth if noise is None else np.asarray(noise) == 1
    signal = ~is_noise & has_truth
    m = valid & signal
    rel = np.abs(est[m] - tru[m]) / tru[m]
    nan = float("nan")
    return {
        "mean_rel_pct": float(rel.mean() * 100) if rel.size else nan,
        "median_rel_pct": float(np.median(rel) * 100) if rel.size else nan,
        "density": float(m.sum() / max(signal.sum(), 1)),
        "noise_valid": float((valid & is_noise).sum() / max(is_noise.sum(), 1)) if is_noise.any() else 0.0,
    }
