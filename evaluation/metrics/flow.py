"""Flow and lifetime accuracy against ground truth (the field's metrics).

* AEE: average endpoint error ``|v - v_true|`` in px/s over the events given a
  valid flow, and relative: the mean of ``|v - v_true| / |v_true|`` in %.
* median relative error (%), robust to the few gross errors.
* AAE: average angle between estimated and true 2-D flow vectors, degrees.
* density: fraction of signal (non-noise) events given a valid flow;
  ``noise_valid``: fraction of noise events given one (should be small).
* lifetime: relative error of the estimated lifetime to ``1e6/|normal speed|``.

Normal-flow methods are scored against the *normal component* of the truth
(the ``nvx``/``nvy`` columns of :mod:`tectum.evaluation.scenes`). On the
simulator, which gives per event the full flow ``vx``/``vy`` and the
``lifetime`` (= 1e6 / |normal speed| along its log-intensity gradient) but
not the gradient direction, :func:`simulator_normal_truth` rebuilds the
normal truth: the true normal speed ``1e6 / lifetime`` along the true
gradient direction, taken from the simulator's dense truth frames (the
Sobel gradient of the log intensity at the event's pixel in the nearest
frame, oriented along the motion). Projecting the truth on the *estimated*
direction instead is wrong: a bad direction shrinks the truth towards 0 and
the relative error explodes.
"""

from __future__ import annotations

import numpy as np

from tectum import EventPacket

__all__ = ["flow_errors", "lifetime_errors", "rotational_flow", "simulator_normal_truth"]


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


def lifetime_errors(lifetime: np.ndarray, true_lifetime: np.ndarray,
                    noise: np.ndarray | None = None) -> dict[str, float]:
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


def simulator_normal_truth(events: EventPacket, frame_t: np.ndarray, frame_intensity: np.ndarray,
                           eps: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """True normal flow (px/s) per simulated event: speed ``1e6 / lifetime``
    along the unit gradient of ``log(I + eps)`` of the truth frame nearest in
    time (Sobel at the event's pixel, borders replicated), signed so that it
    points along the true motion ``(vx, vy)``. NaN where there is no truth
    (noise events, no motion, flat intensity).

    ``events``: an EventPacket with the simulator's ``vx``, ``vy``,
    ``lifetime`` columns; ``frame_t`` (N,) µs and ``frame_intensity`` (N, H, W)
    from ``simulate(..., truth_fps=...)`` (the finer in time, the closer the
    frame's gradient is to the one at the event)."""
    t = events.t
    k = np.clip(np.searchsorted(frame_t, t), 1, len(frame_t) - 1)
    k = np.where(np.abs(frame_t[k - 1] - t) <= np.abs(frame_t[k] - t), k - 1, k)
    L = np.log(np.asarray(frame_intensity, np.float64) + eps)
    _, h, w = L.shape
    x, y = events.x.astype(np.int64), events.y.astype(np.int64)
    gx = np.zeros(len(t))
    gy = np.zeros(len(t))
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            wgt = 2.0 if dx == 0 or dy == 0 else 1.0
            v = L[k, np.clip(y + dy, 0, h - 1), np.clip(x + dx, 0, w - 1)]
            gx += dx * wgt * v
            gy += dy * wgt * v
    g = np.hypot(gx, gy)
    vx = np.asarray(events["vx"], np.float64)
    vy = np.asarray(events["vy"], np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        nx, ny = gx / g, gy / g
        sign = np.sign(vx * nx + vy * ny)
        speed = 1e6 / np.asarray(events["lifetime"], np.float64)
    ok = (g > 1e-9) & np.isfinite(speed) & (speed > 0) & (sign != 0)
    nvx = np.where(ok, sign * speed * nx, np.nan)
    nvy = np.where(ok, sign * speed * ny, np.nan)
    return nvx, nvy


def rotational_flow(x: np.ndarray, y: np.ndarray, omega: np.ndarray, focal_px: float, cx: float,
                    cy: float) -> tuple[np.ndarray, np.ndarray]:
    """Image flow (px/s) of a static scene seen by a camera rotating at
    ``omega`` (N, 3) rad/s in the camera frame (x right, y down, z forward
    along the optical axis), pinhole with focal length ``focal_px`` and
    principal point (cx, cy) px: ``u' = f (xy wx - (1 + x^2) wy + y wz)``,
    ``v' = f ((1 + y^2) wx - xy wy - x wz)`` with x, y normalised
    coordinates. Depth does not enter: the ground truth of Rueckauer &
    Delbruck (2016) from a gyro under pure rotation."""
    xb = (np.asarray(x, np.float64) - cx) / focal_px
    yb = (np.asarray(y, np.float64) - cy) / focal_px
    w = np.asarray(omega, np.float64)
    u = focal_px * (xb * yb * w[:, 0] - (1 + xb * xb) * w[:, 1] + yb * w[:, 2])
    v = focal_px * ((1 + yb * yb) * w[:, 0] - xb * yb * w[:, 1] - xb * w[:, 2])
    return u, v
