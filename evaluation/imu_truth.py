"""Flow ground truth from a gyro under pure rotation (the protocol of
Rueckauer & Delbruck, 2016), and the scores used against it.

Under pure camera rotation the flow at every pixel follows from the angular
velocity and the intrinsics alone (:func:`tectum.evaluation.metrics.rotational_flow`).
The gyro (rad/s, IMU frame) is interpolated at each event's time and
mapped to the camera frame by ``axes`` (a 3x3 matrix, camera = axes @ imu).

On a real recording the direction of the true intensity gradient is not
known, so a *normal*-flow estimate ``n`` is scored by the true full flow
``V`` projected on its own direction: the sign agreement (``V . n > 0``) and
the speed ratio ``|n| / (V . n/|n|)``, only where the estimated normal is
within 60° of ``V`` (elsewhere the projection is small and the ratio
meaningless). Full-flow estimates are scored by AEE/AAE against ``V``.
"""

from __future__ import annotations

import numpy as np

from tectum import EventPacket, ImuPacket

from .metrics import flow_errors, rotational_flow

__all__ = ["G", "full_flow_vs_rotation", "read_events_and_imu", "gyro_flow", "imu_full_scale_factor",
           "normal_flow_vs_rotation"]

G = 9.80665


def read_events_and_imu(path: str) -> tuple[EventPacket, ImuPacket]:
    """All events and IMU samples of a recording (any format tectum reads)."""
    from tectum import concat
    from tectum.sources.files import open_file

    src = open_file(str(path))
    try:
        pk = list(src.packets())
    finally:
        src.close()
    ev = concat([p for p in pk if isinstance(p, EventPacket)])
    imu = concat([p for p in pk if isinstance(p, ImuPacket)])
    return ev, imu


def imu_full_scale_factor(imu: ImuPacket) -> float:
    """Factor (a power of two) by which the accelerometer and gyro of ``imu``
    are off, judged by gravity: the median |accel| of a hand-held or slowly
    moving camera is about 1 g. A reader that assumes the wrong full-scale
    range (e.g. ±4 g / ±500 °/s when the device was set to ±8 g / ±1000 °/s)
    gives readings off by the same power of two for both sensors."""
    a = float(np.median(np.linalg.norm(imu.accel, axis=1)))
    if not a > 0:
        return 1.0
    return float(2.0 ** np.round(np.log2(G / a)))


def gyro_flow(events: EventPacket, imu: ImuPacket, focal_px: float, cx: float, cy: float,
              axes: np.ndarray | None = None, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The rotational flow (px/s) at each event from the gyro (``scale``
    times the readings, rad/s) interpolated at the event times."""
    m = np.eye(3) if axes is None else np.asarray(axes, np.float64)
    g = np.asarray(imu.gyro, np.float64) * scale
    w = np.stack([np.interp(events.t, imu.t, g[:, i]) for i in range(3)], axis=1) @ m.T
    return rotational_flow(events.x, events.y, w, focal_px, cx, cy)


def normal_flow_vs_rotation(vx: np.ndarray, vy: np.ndarray, valid: np.ndarray, tx: np.ndarray,
                            ty: np.ndarray, min_speed: float = 5.0) -> dict[str, float]:
    """Normal-flow estimate against the true full flow (see the module
    docstring). Events whose true speed is under ``min_speed`` px/s (near the
    rotation centre) are left out. Returns ``sign_agree`` (fraction with
    ``V . n > 0``), ``median_ratio`` and ``median_rel_pct`` (of ``|n|`` to the
    projection, where the angle is under 60°), ``density``, ``n_scored``."""
    ok = np.asarray(valid, bool) & (np.hypot(tx, ty) >= min_speed)
    ex, ey = np.asarray(vx, np.float64)[ok], np.asarray(vy, np.float64)[ok]
    Tx, Ty = np.asarray(tx, np.float64)[ok], np.asarray(ty, np.float64)[ok]
    n = np.hypot(ex, ey)
    proj = (Tx * ex + Ty * ey) / n
    cos = proj / np.hypot(Tx, Ty)
    near = cos > 0.5
    ratio = n[near] / proj[near]
    nan = float("nan")
    return {
        "sign_agree": float((cos > 0).mean()) if n.size else nan,
        "median_ratio": float(np.median(ratio)) if ratio.size else nan,
        "median_rel_pct": float(np.median(np.abs(ratio - 1)) * 100) if ratio.size else nan,
        "density": float(ok.sum() / max((np.hypot(tx, ty) >= min_speed).sum(), 1)),
        "n_scored": int(near.sum()),
    }


def full_flow_vs_rotation(vx: np.ndarray, vy: np.ndarray, valid: np.ndarray, tx: np.ndarray,
                          ty: np.ndarray, min_speed: float = 5.0) -> dict[str, float]:
    """Full-flow estimate against the true full flow: AEE, AAE, density."""
    slow = ~(np.hypot(tx, ty) >= min_speed)
    return flow_errors(vx, vy, valid, tx, ty, slow.astype(np.uint8))
