"""DAVIS extras: APS frames with exposure (motion blur) and an IMU, both
from the true scene and trajectory.

``davis`` scene keys (all optional):

``aps_rate_hz`` (0 = no frames), ``exposure_us`` (default 5000),
``aps_gain`` (digital numbers per unit linear intensity, default 255),
``aps_noise`` (read-noise std in DN, default 0), ``imu_rate_hz`` (0 = no IMU),
``gyro_noise`` (rad/s std per sample), ``accel_noise`` (m/s² std per
sample), ``gyro_bias`` [3] rad/s, ``accel_bias`` [3] m/s².

An APS frame is the mean of the linear intensity over its exposure, sampled
at enough instants that the image moves at most half a pixel between two of
them (so fast motion blurs), times ``aps_gain``, plus read noise, rounded
and clipped to 0..255 (uint8). Its timestamp is the middle of the exposure.
The IMU gives the camera-frame angular velocity and specific force
``R^T (a - g)`` (gravity ``g`` along world +y, 9.81 m/s²), plus noise and bias.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .motion import GRAVITY, Trajectory

__all__ = ["DavisConfig", "aps_frame", "imu_samples"]


@dataclass(frozen=True)
class DavisConfig:
    aps_rate_hz: float = 0.0
    exposure_us: float = 5000.0
    aps_gain: float = 255.0
    aps_noise: float = 0.0
    imu_rate_hz: float = 0.0
    gyro_noise: float = 0.0
    accel_noise: float = 0.0
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any] | None) -> DavisConfig:
        spec = dict(spec or {})
        known = set(cls.__dataclass_fields__)
        bad = set(spec) - known
        if bad:
            raise ValueError(f"unknown davis keys {sorted(bad)}; known: {sorted(known)}")
        for k in ("gyro_bias", "accel_bias"):
            if k in spec:
                spec[k] = tuple(float(v) for v in spec[k])
        return cls(**spec)


def aps_frame(render: Callable[[float], np.ndarray], max_flow: Callable[[float], float], t_start_us: float,
              cfg: DavisConfig, rng: np.random.Generator) -> np.ndarray:
    """One APS frame (uint8, H x W) exposed over ``[t_start, t_start + exposure)`` µs.

    ``render(t_us)`` gives the linear intensity image; ``max_flow(t_us)`` a
    bound on the image speed (px/s) that sets the number of sub-samples."""
    e = cfg.exposure_us
    speed = max(max_flow(t_start_us), max_flow(t_start_us + 0.5 * e), max_flow(t_start_us + e))
    n = int(min(64, max(2, np.ceil(speed * e * 1e-6 / 0.5))))
    acc = None
    for k in range(n):
        img = render(t_start_us + (k + 0.5) * e / n)
        acc = img.copy() if acc is None else acc + img
    assert acc is not None
    dn = acc / n * cfg.aps_gain
    noise = rng.standard_normal(dn.shape)  # drawn even at zero noise: same stream for any setting
    dn = dn + cfg.aps_noise * noise
    return np.clip(np.rint(dn), 0, 255).astype(np.uint8)


def imu_samples(traj: Trajectory, t_us: np.ndarray, cfg: DavisConfig,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``(accel m/s², gyro rad/s)``, each (N, 3), camera frame, at ``t_us``."""
    t = np.asarray(t_us, np.float64) * 1e-6
    if t.size == 0:
        return np.empty((0, 3)), np.empty((0, 3))
    gyro = traj.angular_velocity(t).reshape(-1, 3)
    R = traj.rotation(t).as_matrix().reshape(-1, 3, 3)
    f_world = traj.acceleration(t).reshape(-1, 3) - GRAVITY
    accel = np.einsum("nji,nj->ni", R, f_world)
    z = rng.standard_normal((t.size, 6))
    gyro = gyro + np.asarray(cfg.gyro_bias) + cfg.gyro_noise * z[:, :3]
    accel = accel + np.asarray(cfg.accel_bias) + cfg.accel_noise * z[:, 3:]
    return accel, gyro
