"""Map accuracy against ground truth (the field's metrics), on the pixels
both maps define (finite in the estimate and the truth, and inside ``mask``).

* intensity: MSE, Pearson correlation and SSIM (Wang et al. 2004, Gaussian
  window σ = 1.5 px, constants for the truth's dynamic range) of log
  intensity. Event-based reconstruction knows log intensity only up to an
  offset (and the contrast up to a scale), so :func:`intensity_scores` also
  reports MSE after the least-squares affine fit ``a * est + b``.
* depth: AbsRel ``mean |d - d*| / d*`` (and its median), log RMSE, the
  threshold accuracy ``δ < 1.25`` and density, the fraction of truth pixels
  the estimate covers.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

__all__ = ["depth_scores", "intensity_scores", "pearson", "ssim"]


def _valid(est: np.ndarray, truth: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    if est.shape != truth.shape:
        raise ValueError(f"estimate {est.shape} and truth {truth.shape} differ in shape")
    ok = np.isfinite(est) & np.isfinite(truth)
    if mask is not None:
        ok &= mask.astype(bool)
    return ok


def pearson(est: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Pearson correlation on the valid pixels (NaN with fewer than 2 or a constant map)."""
    ok = _valid(est, truth, mask)
    a, b = est[ok].astype(np.float64), truth[ok].astype(np.float64)
    if a.size < 2 or a.std() == 0 or b.std() == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def ssim(est: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None, sigma: float = 1.5) -> float:
    """Mean SSIM over the valid pixels; invalid pixels are filled with the
    truth's mean before filtering (so they count as flat) and left out of the mean."""
    ok = _valid(est, truth, mask)
    if ok.sum() < 2:
        return float("nan")
    x = np.where(ok, est, est[ok].mean()).astype(np.float64)
    y = np.where(ok, truth, truth[ok].mean()).astype(np.float64)
    rng = float(truth[ok].max() - truth[ok].min()) or 1.0
    c1, c2 = (0.01 * rng) ** 2, (0.03 * rng) ** 2
    mx, my = gaussian_filter(x, sigma), gaussian_filter(y, sigma)
    vx = gaussian_filter(x * x, sigma) - mx * mx
    vy = gaussian_filter(y * y, sigma) - my * my
    cxy = gaussian_filter(x * y, sigma) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return float(s[ok].mean())


def intensity_scores(est: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> dict[str, float]:
    """``mse`` (as given), ``mse_affine`` (after the best ``a * est + b``),
    ``pearson``, ``ssim`` (of the affinely fitted estimate) and ``coverage``
    (valid fraction of the truth's finite pixels)."""
    ok = _valid(est, truth, mask)
    n_truth = int((np.isfinite(truth) & (mask.astype(bool) if mask is not None else True)).sum())
    out = {"mse": float("nan"), "mse_affine": float("nan"), "pearson": float("nan"), "ssim": float("nan"),
           "coverage": float(ok.sum() / max(n_truth, 1))}
    if ok.sum() < 2:
        return out
    a, b = est[ok].astype(np.float64), truth[ok].astype(np.float64)
    out["mse"] = float(np.mean((a - b) ** 2))
    A = np.stack([a, np.ones_like(a)], axis=1)
    coef = np.linalg.lstsq(A, b, rcond=None)[0]
    fitted = np.full(est.shape, np.nan)
    fitted[ok] = A @ coef
    out["mse_affine"] = float(np.mean((fitted[ok] - b) ** 2))
    out["pearson"] = pearson(est, truth, mask)
    out["ssim"] = ssim(fitted, truth, ok)
    return out


def depth_scores(est: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> dict[str, float]:
    """Depth (m) against true depth: ``abs_rel``, ``median_abs_rel``,
    ``log_rmse``, ``delta_1_25`` (fraction with max(d/d*, d*/d) < 1.25) over
    pixels where both are finite and positive; ``density`` = that count over
    the truth's finite positive pixels."""
    t_ok = np.isfinite(truth) & (truth > 0)
    if mask is not None:
        t_ok &= mask.astype(bool)
    ok = t_ok & np.isfinite(est) & (est > 0)
    out = {"abs_rel": float("nan"), "median_abs_rel": float("nan"), "log_rmse": float("nan"),
           "delta_1_25": float("nan"), "density": float(ok.sum() / max(int(t_ok.sum()), 1)), "n": int(ok.sum())}
    if not ok.any():
        return out
    d, g = est[ok].astype(np.float64), truth[ok].astype(np.float64)
    rel = np.abs(d - g) / g
    out.update(abs_rel=float(rel.mean()), median_abs_rel=float(np.median(rel)),
               log_rmse=float(np.sqrt(np.mean((np.log(d) - np.log(g)) ** 2))),
               delta_1_25=float(np.mean(np.maximum(d / g, g / d) < 1.25)))
    return out
