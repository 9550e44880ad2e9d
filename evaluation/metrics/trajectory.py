"""Trajectory accuracy: an estimated pose stream against ground truth, in the
field's standard terms (Sturm et al., IROS 2012, the TUM RGB-D benchmark;
Zhang and Scaramuzza, IROS 2018).

Poses are world-from-camera: positions (N, 3) m, unit quaternions (N, 4)
x, y, z, w; times int64 µs.

* :func:`associate`: each estimated pose paired with the truth at its time,
  interpolated (:func:`tectum.camera.interpolate_poses`, never
  extrapolated: estimates outside the truth's span are left out).
* :func:`umeyama`: the similarity ``(s, R, t)`` that minimises
  ``Σ ||y_i - (s R x_i + t)||²`` (Umeyama, TPAMI 1991), with or without the
  scale.
* :func:`align`: the estimate moved onto the truth by none / SE(3) / Sim(3)
  of its positions.
* :func:`ate`: absolute trajectory error, the RMSE (and mean, median, max)
  of the position differences after the alignment (m).
* :func:`rpe`: relative pose error over a fixed time ``delta_us``: for every
  pose ``i`` with a pose ``j`` at ``t_i + delta_us`` (within ``tol_us``),
  ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` of truth ``Q`` and estimate ``P``;
  translation ``|t_E|`` m and rotation ``angle(R_E)`` deg, RMSE / mean /
  median. Independent of an SE(3) alignment.
* :func:`trajectory_scores`: all of the above plus the position RMSE as a
  percentage of the truth's path length and the median rotation error
  (deg, after the alignment's rotation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from tectum.camera import interpolate_poses, quat_to_rot, rot_to_quat

from .tracking import pose_errors

__all__ = ["Associated", "associate", "umeyama", "align", "ate", "rpe", "path_length", "trajectory_scores"]

Alignment = Literal["none", "se3", "sim3"]


@dataclass(frozen=True)
class Associated:
    """Estimated poses and the truth at the same times (µs)."""

    t: np.ndarray
    p_est: np.ndarray
    q_est: np.ndarray
    p_true: np.ndarray
    q_true: np.ndarray


def associate(t_est: np.ndarray, p_est: np.ndarray, q_est: np.ndarray, t_true: np.ndarray, p_true: np.ndarray,
              q_true: np.ndarray) -> Associated:
    """Pair each estimated pose with the truth interpolated at its time;
    estimates outside the truth's time span (and non-finite ones) are left
    out. Raises ValueError when no pair remains."""
    te = np.asarray(t_est, np.int64)
    pe = np.asarray(p_est, np.float64).reshape(-1, 3)
    qe = np.asarray(q_est, np.float64).reshape(-1, 4)
    if not len(te) == len(pe) == len(qe):
        raise ValueError(f"associate: {len(te)} estimated times, {len(pe)} positions, {len(qe)} orientations")
    pt, qt, valid = interpolate_poses(te, np.asarray(t_true, np.int64), p_true, q_true)
    valid &= np.isfinite(pe).all(axis=1) & np.isfinite(qe).all(axis=1)
    if not valid.any():
        raise ValueError("associate: no estimated pose lies within the truth's time span")
    qn = qe[valid] / np.linalg.norm(qe[valid], axis=1)[:, None]
    return Associated(te[valid], pe[valid], qn, pt[valid], qt[valid])


def umeyama(x: np.ndarray, y: np.ndarray, with_scale: bool) -> tuple[float, np.ndarray, np.ndarray]:
    """``(s, R, t)`` minimising ``Σ ||y_i - (s R x_i + t)||²`` over points
    ``x``, ``y`` (N, 3): from the SVD ``U D Vᵀ`` of the cross-covariance
    ``Σ_xy = (1/N) Σ (y_i - μ_y)(x_i - μ_x)ᵀ``, ``R = U S Vᵀ`` with
    ``S = diag(1, 1, det(U) det(V))`` (a rotation, never a reflection),
    ``s = tr(D S) / σ_x²`` (1 without scale), ``t = μ_y - s R μ_x``."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"umeyama: x and y must both be (N, 3), got {x.shape} and {y.shape}")
    if len(x) < 3:
        raise ValueError(f"umeyama: needs at least 3 point pairs, got {len(x)}")
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    sigma = yc.T @ xc / len(x)
    U, D, Vt = np.linalg.svd(sigma)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    var_x = float(np.mean(np.sum(xc * xc, axis=1)))
    s = float(np.trace(np.diag(D) @ S) / var_x) if with_scale and var_x > 0 else 1.0
    return s, R, my - s * R @ mx


def align(a: Associated, mode: Alignment = "se3") -> tuple[Associated, float]:
    """The estimate moved by the similarity that best maps its positions
    onto the truth's (``"none"``: unchanged; ``"se3"``: rotation and
    translation; ``"sim3"``: and scale), and the scale found (1 unless
    sim3). Orientations turn with the rotation."""
    if mode == "none":
        return a, 1.0
    if mode not in ("se3", "sim3"):
        raise ValueError(f"align: mode must be 'none', 'se3' or 'sim3', got {mode!r}")
    s, R, t = umeyama(a.p_est, a.p_true, with_scale=mode == "sim3")
    p = s * a.p_est @ R.T + t
    q = rot_to_quat(R[None] @ quat_to_rot(a.q_est))
    return Associated(a.t, p, q, a.p_true, a.q_true), s


def ate(a: Associated, mode: Alignment = "se3") -> dict[str, float]:
    """Absolute trajectory error after :func:`align`: ``rmse``, ``mean``,
    ``median``, ``max`` of the position differences (m), and ``scale``."""
    b, s = align(a, mode)
    e = np.linalg.norm(b.p_est - b.p_true, axis=1)
    return {"rmse": float(np.sqrt(np.mean(e * e))), "mean": float(e.mean()), "median": float(np.median(e)),
            "max": float(e.max()), "scale": s}


def _se3(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    T = np.zeros((len(p), 4, 4))
    T[:, :3, :3] = quat_to_rot(q).reshape(-1, 3, 3)
    T[:, :3, 3] = p
    T[:, 3, 3] = 1.0
    return T


def rpe(a: Associated, delta_us: int, tol_us: int | None = None) -> dict[str, float]:
    """Relative pose error over ``delta_us`` (see the module): ``pairs``,
    ``trans_rmse``, ``trans_mean``, ``trans_median`` (m), ``rot_rmse``,
    ``rot_mean``, ``rot_median`` (deg). The partner of pose ``i`` is the
    first pose at or after ``t_i + delta_us``, kept when within ``tol_us``
    of it (default a tenth of ``delta_us``); NaN scores when none is."""
    if delta_us <= 0:
        raise ValueError(f"rpe: delta_us must be positive, got {delta_us}")
    tol = delta_us // 10 if tol_us is None else tol_us
    j = np.searchsorted(a.t, a.t + delta_us)
    ok = j < len(a.t)
    ok[ok] &= a.t[j[ok]] - (a.t[ok] + delta_us) <= tol
    i, j = np.flatnonzero(ok), j[ok]
    nan = float("nan")
    if not len(i):
        return {"pairs": 0.0, "trans_rmse": nan, "trans_mean": nan, "trans_median": nan,
                "rot_rmse": nan, "rot_mean": nan, "rot_median": nan}
    P, Q = _se3(a.p_est, a.q_est), _se3(a.p_true, a.q_true)
    rel_p = np.linalg.inv(P[i]) @ P[j]
    rel_q = np.linalg.inv(Q[i]) @ Q[j]
    E = np.linalg.inv(rel_q) @ rel_p
    te = np.linalg.norm(E[:, :3, 3], axis=1)
    cos = np.clip((np.trace(E[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    re = np.degrees(np.arccos(cos))
    return {"pairs": float(len(i)), "trans_rmse": float(np.sqrt(np.mean(te * te))), "trans_mean": float(te.mean()),
            "trans_median": float(np.median(te)), "rot_rmse": float(np.sqrt(np.mean(re * re))),
            "rot_mean": float(re.mean()), "rot_median": float(np.median(re))}


def path_length(p: np.ndarray) -> float:
    """Length (m) of the polyline through the positions ``p`` (N, 3)."""
    p = np.asarray(p, np.float64)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def trajectory_scores(t_est: np.ndarray, p_est: np.ndarray, q_est: np.ndarray, t_true: np.ndarray,
                      p_true: np.ndarray, q_true: np.ndarray, mode: Alignment = "se3",
                      delta_us: int = 100_000) -> dict[str, float]:
    """One row of scores: ``poses`` associated, ``path_m`` (the truth's path
    over them), ``ate_m`` (RMSE after ``mode``), ``pos_pct`` (``ate_m`` as a
    % of ``path_m``), ``rot_median_deg`` / ``rot_max_deg`` (angle of
    ``q_true⁻¹ q_est`` after the alignment's rotation), ``rpe_t_m`` /
    ``rpe_r_deg`` (RMSE over ``delta_us``), ``scale``."""
    a = associate(t_est, p_est, q_est, t_true, p_true, q_true)
    b, s = align(a, mode) if len(a.t) >= 3 else (a, 1.0)
    e = np.linalg.norm(b.p_est - b.p_true, axis=1)
    rmse = float(np.sqrt(np.mean(e * e)))
    path = path_length(a.p_true)
    _, rot = pose_errors(b.p_est, b.q_est, b.p_true, b.q_true)
    r = rpe(a, delta_us)
    return {"poses": float(len(a.t)), "path_m": path, "ate_m": rmse,
            "pos_pct": 100.0 * rmse / path if path > 0 else float("nan"),
            "rot_median_deg": float(np.median(rot)), "rot_max_deg": float(rot.max()),
            "rpe_t_m": r["trans_rmse"], "rpe_r_deg": r["rot_rmse"], "scale": s}
