"""Camera trajectories: pose, velocity and angular velocity at any time.

Conventions: camera frame x right, y down, z forward (optical axis). A pose
is world-from-camera: a world point is ``X_w = R @ X_c + p``. The world
frame's y axis points down, so gravity is ``+9.81`` m/s² along world y.

A ``motion`` spec (all optional, SI units):

``position`` [3] m, ``velocity`` [3] m/s,
``position_amplitude`` [3] m, ``position_freq_hz`` [3] Hz, ``position_phase`` [3] rad:
    ``p(t) = position + velocity t + A sin(2 pi f t + phase)``.
``orientation`` [3] rad (rotation vector, world-from-camera at t = 0),
``angular_velocity`` [3] rad/s (camera frame),
``rotation_amplitude`` [3] rad, ``rotation_freq_hz`` [3] Hz:
    ``R(t) = R0 Exp(angular_velocity t + A sin(2 pi f t))``.

The camera-frame angular velocity is ``vee(R^T dR/dt)``, computed from the
exact rotations by a symmetric difference (exact for a constant rate).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

__all__ = ["Trajectory", "GRAVITY", "pose_kernel"]

GRAVITY = np.array([0.0, 9.81, 0.0])
_DELTA_S = 1e-4


def _vec(spec: Mapping[str, Any], key: str, default: float = 0.0) -> np.ndarray:
    v = spec.get(key, default)
    a = np.broadcast_to(np.asarray(v, np.float64), (3,)).copy()
    return a


@njit(cache=True)
def pose_kernel(params: np.ndarray, t_s: float, R: np.ndarray, p: np.ndarray) -> None:
    """World-from-camera ``R`` (3x3) and position ``p`` (m) at ``t_s`` (s),
    written in place, from :attr:`Trajectory.params` (p0, v0, pa, pf, pph,
    R0 row-major, w0, ra, rf): ``R = R0 Exp(rv)`` by Rodrigues' formula."""
    two_pi = 2.0 * math.pi
    rv0 = params[24] * t_s + params[27] * math.sin(two_pi * params[30] * t_s)
    rv1 = params[25] * t_s + params[28] * math.sin(two_pi * params[31] * t_s)
    rv2 = params[26] * t_s + params[29] * math.sin(two_pi * params[32] * t_s)
    for j in range(3):
        p[j] = params[j] + params[3 + j] * t_s + params[6 + j] * math.sin(two_pi * params[9 + j] * t_s + params[12 + j])
    th2 = rv0 * rv0 + rv1 * rv1 + rv2 * rv2
    if th2 < 1e-16:  # series: sin(th)/th = 1 - th²/6, (1 - cos th)/th² = 1/2 - th²/24
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / th2
    # E = I + a K + b K², K = [rv]x
    E = np.empty((3, 3))
    E[0, 0] = 1.0 - b * (rv1 * rv1 + rv2 * rv2)
    E[1, 1] = 1.0 - b * (rv0 * rv0 + rv2 * rv2)
    E[2, 2] = 1.0 - b * (rv0 * rv0 + rv1 * rv1)
    E[0, 1] = -a * rv2 + b * rv0 * rv1
    E[1, 0] = a * rv2 + b * rv0 * rv1
    E[0, 2] = a * rv1 + b * rv0 * rv2
    E[2, 0] = -a * rv1 + b * rv0 * rv2
    E[1, 2] = -a * rv0 + b * rv1 * rv2
    E[2, 1] = a * rv0 + b * rv1 * rv2
    for r in range(3):
        for c in range(3):
            R[r, c] = params[15 + 3 * r] * E[0, c] + params[16 + 3 * r] * E[1, c] + params[17 + 3 * r] * E[2, c]


class Trajectory:
    """A smooth 6-DoF camera trajectory from a ``motion`` spec (see module doc)."""

    def __init__(self, spec: Mapping[str, Any] | None = None) -> None:
        spec = dict(spec or {})
        known = {"position", "velocity", "position_amplitude", "position_freq_hz", "position_phase",
                 "orientation", "angular_velocity", "rotation_amplitude", "rotation_freq_hz"}
        unknown = set(spec) - known
        if unknown:
            raise ValueError(f"unknown motion keys {sorted(unknown)}; known: {sorted(known)}")
        self.p0 = _vec(spec, "position")
        self.v0 = _vec(spec, "velocity")
        self.pa = _vec(spec, "position_amplitude")
        self.pf = _vec(spec, "position_freq_hz")
        self.pph = _vec(spec, "position_phase")
        self.R0 = Rotation.from_rotvec(_vec(spec, "orientation"))
        self.w0 = _vec(spec, "angular_velocity")
        self.ra = _vec(spec, "rotation_amplitude")
        self.rf = _vec(spec, "rotation_freq_hz")
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        #: the parameters as one array for :func:`pose_kernel`
        self.params = np.concatenate([self.p0, self.v0, self.pa, self.pf, self.pph, self.R0.as_matrix().ravel(),
                                      self.w0, self.ra, self.rf])
        self.static = not (self.v0.any() or self.pa.any() or self.w0.any() or self.ra.any())

    # -- positions -------------------------------------------------------
    def position(self, t_s: np.ndarray | float) -> np.ndarray:
        """Position(s) in m at time(s) ``t_s`` (s): shape (..., 3)."""
        t = np.asarray(t_s, np.float64)[..., None]
        return self.p0 + self.v0 * t + self.pa * np.sin(2 * np.pi * self.pf * t + self.pph)

    def velocity(self, t_s: np.ndarray | float) -> np.ndarray:
        """World-frame velocity in m/s."""
        t = np.asarray(t_s, np.float64)[..., None]
        w = 2 * np.pi * self.pf
        return self.v0 + self.pa * w * np.cos(w * t + self.pph)

    def acceleration(self, t_s: np.ndarray | float) -> np.ndarray:
        """World-frame acceleration in m/s²."""
        t = np.asarray(t_s, np.float64)[..., None]
        w = 2 * np.pi * self.pf
        return -self.pa * w * w * np.sin(w * t + self.pph)

    # -- rotations -------------------------------------------------------
    def rotation(self, t_s: np.ndarray | float) -> Rotation:
        """World-from-camera rotation(s) at time(s) ``t_s`` (s)."""
        t = np.asarray(t_s, np.float64)[..., None]
        rv = self.w0 * t + self.ra * np.sin(2 * np.pi * self.rf * t)
        return self.R0 * Rotation.from_rotvec(rv.reshape(-1, 3) if rv.ndim > 1 else rv)

    def matrix(self, t_s: float) -> np.ndarray:
        """The 3x3 world-from-camera rotation matrix at ``t_s`` (s)."""
        return np.ascontiguousarray(self.rotation(float(t_s)).as_matrix())

    def angular_velocity(self, t_s: np.ndarray | float) -> np.ndarray:
        """Camera-frame angular velocity in rad/s: shape (..., 3)."""
        t = np.atleast_1d(np.asarray(t_s, np.float64))
        ra = self.rotation(t - _DELTA_S)
        rb = self.rotation(t + _DELTA_S)
        w = (ra.inv() * rb).as_rotvec() / (2 * _DELTA_S)
        return w.reshape(np.shape(t_s) + (3,))

    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``(R, p)``: world-from-camera rotation matrix and position (m)
        (by :func:`pose_kernel`, as the renderer's sub-steps). The last few
        poses are remembered (a step asks for the same times several times)."""
        t = float(t_s)
        if self.static:
            t = 0.0
        hit = self._cache.get(t)
        if hit is None:
            hit = (np.empty((3, 3)), np.empty(3))
            pose_kernel(self.params, t, hit[0], hit[1])
            if len(self._cache) >= 16:
                self._cache.pop(next(iter(self._cache)))
            self._cache[t] = hit
        return hit
