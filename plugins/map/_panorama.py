"""The equirectangular panorama of ``map.poisson_mosaic`` and its event kernel.

Convention (shared by everything that compares with the mosaic): a
panorama ``width`` W px wide is ``H = W / 2`` px high; a world ray
``d = (X, Y, Z)`` (y down, z forward, world = the camera frame at the first
pose) has azimuth ``atan2(X, Z)`` and elevation ``asin(Y / |d|)``, mapped
linearly onto the continuous coordinates

    u = (azimuth + π) W / (2π),   v = (elevation + π/2) H / π,

so pixel ``(row i, column j)`` covers ``[j, j + 1) x [i, i + 1)`` and its
centre looks along azimuth ``-π + (j + ½) 2π/W``, elevation
``-π/2 + (i + ½) π/H``. One pixel spans ``2π / W`` rad both ways. Azimuth
wraps: column ``W`` is column 0.

The gradient estimator (see :func:`map_events`): each event at a sensor
pixel, with that pixel's previous event, is one linear measurement of the
log-intensity gradient ``g`` (per panorama pixel) along the pixel's
displacement ``Δm`` on the panorama between the two events:
``g · Δm = ±C`` (the log intensity seen by the pixel changed by one
contrast step). Per panorama pixel the kernel accumulates the measurements'
information ``Σ Δm Δmᵀ`` and ``Σ Δm z``; :func:`solve_gradients` turns it
into the gradient, the Kalman filter's estimate in information form.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from tectum.camera import quat_slerp_kernel, quat_to_rot_kernel

__all__ = ["pano_shape", "pano_angles", "pano_rays", "pano_coords", "map_events", "pixel_gradients", "solve_gradients",
           "INFO_FIELDS"]

#: Columns of the per-pixel information array (H, W, 6): Σ du², Σ du dv,
#: Σ dv², Σ du z, Σ dv z (z = ±C, log units; du, dv panorama px) and the
#: number of measurements.
INFO_FIELDS = ("a_uu", "a_uv", "a_vv", "b_u", "b_v", "n")


def pano_shape(width: int) -> tuple[int, int]:
    """(height, width) of a panorama ``width`` px wide (even, >= 4)."""
    if width < 4 or width % 2:
        raise ValueError(f"pano_width must be even and >= 4, got {width}")
    return width // 2, width


def pano_angles(width: int) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (W,) and elevation (H,) of the pixel centres, rad."""
    h, w = pano_shape(width)
    az = -math.pi + (np.arange(w) + 0.5) * (2 * math.pi / w)
    el = -math.pi / 2 + (np.arange(h) + 0.5) * (math.pi / h)
    return az, el


def pano_rays(width: int) -> np.ndarray:
    """Unit world rays (H, W, 3) through the pixel centres."""
    az, el = pano_angles(width)
    ce = np.cos(el)[:, None]
    return np.stack([ce * np.sin(az)[None, :], np.broadcast_to(np.sin(el)[:, None], (len(el), len(az))),
                     ce * np.cos(az)[None, :]], axis=-1)


@njit(cache=True, nogil=True, inline="always")
def _uv(X: float, Y: float, Z: float, w: int, h: int) -> tuple[float, float]:
    n = math.sqrt(X * X + Y * Y + Z * Z)
    u = (math.atan2(X, Z) + math.pi) * (w / (2.0 * math.pi))
    v = (math.asin(min(1.0, max(-1.0, Y / n))) + 0.5 * math.pi) * (h / math.pi)
    return u, v


@njit(cache=True, nogil=True)
def _coords_many(d, w, h, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    for i in range(d.shape[0]):
        out[i, 0], out[i, 1] = _uv(d[i, 0], d[i, 1], d[i, 2], w, h)


def pano_coords(rays: np.ndarray, width: int) -> np.ndarray:
    """Continuous panorama coordinates ``(u, v)`` (N, 2) of world rays (N, 3)
    (any length > 0): the pixel is ``(floor(v), floor(u) mod W)``."""
    h, w = pano_shape(width)
    d = np.ascontiguousarray(rays, np.float64).reshape(-1, 3)
    if not np.isfinite(d).all() or (np.linalg.norm(d, axis=1) == 0).any():
        raise ValueError("pano_coords: rays must be finite and non-zero")
    out = np.empty((len(d), 2))
    _coords_many(d, w, h, out)
    return out


@njit(cache=True, nogil=True)
def map_events(t, x, y, p, pose_t, pose_q, rays, contrast, max_disp, pix_t, pix_uv, info):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Map events into the panorama and accumulate gradient measurements.

    ``t`` int64 µs sorted, all within ``[pose_t[0], pose_t[-1]]``; ``x``,
    ``y`` sensor pixels; ``p`` ±1. ``pose_t`` (m,) µs strictly increasing
    with ``pose_q`` (m, 4) world-from-camera orientations (x, y, z, w),
    slerped per event. ``rays`` (h, w, 3) undistorted camera rays per
    sensor pixel. ``contrast`` = (C_on, C_off), log units. State, updated:
    ``pix_t`` (h, w) int64 time of each sensor pixel's last event (-1:
    none) and ``pix_uv`` (h, w, 2) where its ray then met the panorama;
    ``info`` (H, W, 6), see :data:`INFO_FIELDS`.

    Each event after the first at its sensor pixel whose panorama
    displacement ``Δm`` since that event is non-zero and at most
    ``max_disp`` px adds ``Δm Δmᵀ`` and ``Δm z`` (``z = +C_on`` or
    ``-C_off``) at the panorama pixel of the displacement's midpoint, where
    the finite difference ``g · Δm`` is second-order accurate. Returns
    (measurements, displacements too long)."""
    H, W = info.shape[0], info.shape[1]
    m = pose_t.shape[0]
    R = np.empty((3, 3))
    q = np.empty(4)
    j = 0
    last_t = np.int64(-1)
    n_meas = 0
    n_far = 0
    max2 = max_disp * max_disp
    for i in range(t.shape[0]):
        ti = t[i]
        if ti != last_t:  # events of one timestamp share their rotation
            while j + 1 < m and pose_t[j + 1] <= ti:  # the last pose at or before ti
                j += 1
            if pose_t[j] == ti:  # exactly, so that which poses are still held cannot matter
                quat_to_rot_kernel(pose_q[j], R)
            else:
                s = (ti - pose_t[j]) / (pose_t[j + 1] - pose_t[j])
                quat_slerp_kernel(pose_q[j], pose_q[j + 1], s, q)
                quat_to_rot_kernel(q, R)
            last_t = ti
        xi, yi = x[i], y[i]
        r0, r1, r2 = rays[yi, xi, 0], rays[yi, xi, 1], rays[yi, xi, 2]
        u, v = _uv(R[0, 0] * r0 + R[0, 1] * r1 + R[0, 2] * r2, R[1, 0] * r0 + R[1, 1] * r1 + R[1, 2] * r2,
                   R[2, 0] * r0 + R[2, 1] * r1 + R[2, 2] * r2, W, H)
        if pix_t[yi, xi] >= 0:
            u0, v0 = pix_uv[yi, xi, 0], pix_uv[yi, xi, 1]
            du = u - u0
            if du >= 0.5 * W:  # across the azimuth seam
                du -= W
            elif du < -0.5 * W:
                du += W
            dv = v - v0
            d2 = du * du + dv * dv
            if d2 > max2:
                n_far += 1
            elif d2 > 0.0:
                um = u0 + 0.5 * du
                col = int(math.floor(um)) % W
                row = min(max(int(math.floor(v0 + 0.5 * dv)), 0), H - 1)
                z = contrast[0] if p[i] > 0 else -contrast[1]
                a = info[row, col]
                a[0] += du * du
                a[1] += du * dv
                a[2] += dv * dv
                a[3] += du * z
                a[4] += dv * z
                a[5] += 1.0
                n_meas += 1
        pix_t[yi, xi] = ti
        pix_uv[yi, xi, 0] = u
        pix_uv[yi, xi, 1] = v
    return n_meas, n_far


@njit(cache=True, nogil=True)
def pixel_gradients(info, ridge, min_n, gu, gv):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Per panorama pixel with at least ``min_n`` measurements, the
    gradient ``(A + ridge I)⁻¹ b`` into ``gu``, ``gv`` (H, W); zero elsewhere."""
    for i in range(info.shape[0]):
        for j in range(info.shape[1]):
            a = info[i, j]
            gu[i, j] = 0.0
            gv[i, j] = 0.0
            if a[5] >= min_n:
                a11, a12, a22 = a[0] + ridge, a[1], a[2] + ridge
                det = a11 * a22 - a12 * a12
                if det > 0.0:
                    gu[i, j] = (a22 * a[3] - a12 * a[4]) / det
                    gv[i, j] = (a11 * a[4] - a12 * a[3]) / det


def solve_gradients(info: np.ndarray, ridge: float, min_n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Per panorama pixel, the gradient ``(g_u, g_v)`` (log units per
    panorama px) of its accumulated measurements ``info`` (H, W, 6):
    ``(A + ridge I)⁻¹ b``, the Kalman filter's posterior mean from a
    zero-mean prior of variance ``σ_z² / ridge`` (``σ_z`` the measurement
    noise). Zero where fewer than ``min_n`` (>= 1) measurements landed."""
    if info.ndim != 3 or info.shape[2] != len(INFO_FIELDS):
        raise ValueError(f"solve_gradients: info must be (H, W, {len(INFO_FIELDS)}), got {info.shape}")
    if not ridge >= 0 or min_n < 1:
        raise ValueError(f"solve_gradients: ridge must be >= 0 and min_n >= 1, got {ridge}, {min_n}")
    gu = np.empty(info.shape[:2])
    gv = np.empty(info.shape[:2])
    pixel_gradients(np.ascontiguousarray(info, np.float64), float(ridge), float(min_n), gu, gv)
    return gu, gv
