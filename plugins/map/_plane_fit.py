"""A robust plane through a semi-dense depth map, in its own camera, and the
test whether the plane explains the map (``map.emvs``'s ``surface=``).

A plane ``n · X = d`` seen by a pinhole camera has an inverse depth linear in
the normalised image coordinates: with ``X = Z (x, y, 1)``, ``x = (u - cx) /
fx``, ``y = (v - cy) / fy``, ``1 / Z = a x + b y + c`` (``(a, b, c) = n /
d``). So the fit is a linear one on (x, y, 1/Z): iteratively reweighted
least squares with Tukey's biweight (c = 4.685 robust standard deviations,
the scale re-estimated each round from the residuals' median absolute
deviation), started from the constant plane at the median inverse depth.
Residuals are in inverse depth (1/m), the unit in which the DSI's planes are
spaced (``map.emvs``'s default: uniform in inverse depth), so the test's
tolerance is a number of DSI planes.

The test (:func:`explains`): a plane explains a map when at least
``min_inliers`` of its pixels lie within ``tol`` (1/m) of it. Against free
depth (one depth per pixel, the map as it is) the plane's three parameters
are the simpler model; free depth wins wherever the plane leaves a sizeable
share of the pixels off it by more than the DSI can resolve (two surfaces,
boxes, noise). EMVS's own depth of a plane seldom passes: on its maps of
the EVO bench's textured plane 4-6 % of the pixels lie within 2 DSI planes
of the fit (the error is coherent over blobs, not pixel noise), fewer than on
its maps of a box scene (``docs/evo.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PlaneFit", "fit_plane", "plane_depth", "explains", "plane_to_world", "plane_in_view"]

#: Tukey's biweight constant, in robust standard deviations (95 % efficiency under Gaussian noise)
TUKEY_C = 4.685


@dataclass(frozen=True)
class PlaneFit:
    """A plane ``1 / Z = a x + b y + c`` (``coef`` (a, b, c), 1/m, over
    normalised coordinates) fitted to ``n`` pixels; ``residual`` their
    residuals in inverse depth (fitted less measured, 1/m, in the order of
    ``np.nonzero`` of the known pixels), ``scale`` the residuals' robust
    standard deviation (1.4826 x their median absolute value, 1/m)."""

    coef: np.ndarray
    n: int
    residual: np.ndarray
    scale: float

    def inliers(self, tol: float) -> float:
        """The share of the pixels within ``tol`` (1/m) of the plane."""
        return float(np.mean(np.abs(self.residual) < tol))


def fit_plane(depth: np.ndarray, K: np.ndarray, rounds: int = 20) -> PlaneFit | None:
    """The plane through the known pixels of ``depth`` (H, W; m, NaN or <= 0
    unknown) seen with intrinsics ``K`` (3, 3), robust to outliers (see the
    module). None with fewer than 3 known pixels or when they do not fix a
    plane (all on one line)."""
    depth = np.asarray(depth)
    K = np.asarray(K, np.float64)
    if depth.ndim != 2:
        raise ValueError(f"fit_plane: depth must be (H, W), got shape {depth.shape}")
    if K.shape != (3, 3):
        raise ValueError(f"fit_plane: K must be (3, 3), got shape {K.shape}")
    with np.errstate(invalid="ignore"):
        v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    n = len(u)
    if n < 3:
        return None
    A = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(n)], axis=1)
    if np.linalg.matrix_rank(A) < 3:
        return None
    r = 1.0 / depth[v, u].astype(np.float64)
    coef = np.array([0.0, 0.0, float(np.median(r))])
    for _ in range(rounds):
        e = A @ coef - r
        s = 1.4826 * float(np.median(np.abs(e)))
        if s <= 0:  # more than half the pixels exactly on it
            break
        z = e / (TUKEY_C * s)
        w = np.where(np.abs(z) < 1, (1 - z * z) ** 2, 0.0)
        if np.count_nonzero(w) < 3:
            break
        sw = np.sqrt(w)
        new = np.linalg.lstsq(A * sw[:, None], r * sw, rcond=None)[0]
        done = bool(np.allclose(new, coef, rtol=0, atol=1e-9))
        coef = new
        if done:
            break
    e = A @ coef - r
    return PlaneFit(np.asarray(coef, np.float64), n, e, 1.4826 * float(np.median(np.abs(e))))


def explains(fit: PlaneFit | None, tol: float, min_inliers: float) -> bool:
    """Whether the plane explains its map: at least ``min_inliers`` (0..1) of
    the pixels within ``tol`` (1/m) of it (see the module)."""
    if not tol > 0 or not 0 < min_inliers <= 1:
        raise ValueError(f"explains: need tol > 0 (1/m) and 0 < min_inliers <= 1, got {tol}, {min_inliers}")
    return fit is not None and fit.inliers(tol) >= min_inliers


def plane_depth(coef: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The depth (m, float64 (H, W)) of the plane ``coef`` (see
    :class:`PlaneFit`) at every pixel of an image of ``shape``; NaN where
    the plane is behind the camera or at infinity there."""
    h, w = shape
    x = (np.arange(w) - K[0, 2]) / K[0, 0]
    y = (np.arange(h) - K[1, 2]) / K[1, 1]
    r = coef[0] * x[None, :] + coef[1] * y[:, None] + coef[2]
    ok = r > 0
    return np.where(ok, 1.0 / np.where(ok, r, 1.0), np.nan)


def plane_to_world(coef: np.ndarray, R_wc: np.ndarray, t_wc: np.ndarray) -> tuple[np.ndarray, float]:
    """The plane ``1 / Z = a x + b y + c`` (``coef``, 1/m) of a camera at
    world-from-camera ``R_wc``, ``t_wc`` (m) as ``(n, o)`` in the world:
    points ``W`` with ``n · W = o``, ``n`` a unit normal, ``o`` (m). (In the
    camera the plane is ``coef · X = 1``: its unit normal ``coef / |coef|``
    at ``1 / |coef|`` from the centre.)"""
    m = np.asarray(coef, np.float64)
    r = float(np.linalg.norm(m))
    if not r > 0:
        raise ValueError("plane_to_world: the plane must lie in front of the camera (coef != 0)")
    n = np.asarray(R_wc, np.float64) @ (m / r)
    return n, float(n @ np.asarray(t_wc, np.float64) + 1.0 / r)


def plane_in_view(n: np.ndarray, o: float, R_wc: np.ndarray, t_wc: np.ndarray) -> np.ndarray | None:
    """The world plane ``n · W = o`` (:func:`plane_to_world`) in a camera at
    ``R_wc``, ``t_wc``: its ``coef`` (1/m) for :func:`plane_depth`; None
    when the camera centre lies on the plane (no depth anywhere)."""
    d = o - float(np.asarray(n) @ np.asarray(t_wc, np.float64))  # the signed distance from the centre, m
    if abs(d) < 1e-9:
        return None
    return (np.asarray(R_wc, np.float64).T @ np.asarray(n, np.float64)) / d
