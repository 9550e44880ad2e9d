"""Panorama truth for ``map.poisson_mosaic``: the simulator's panorama
texture as the mosaic's equirectangular picture, and the part of it a
camera trajectory swept.

The simulator (:mod:`tectum.sources.simulate.render`) colours a world ray
of azimuth ``az = atan2(X, Z)`` and elevation ``el = asin(Y/|d|)`` by the
panorama texture sampled bilinearly (wrapping) at texel ``(az, el) /
texel`` (``texel`` = 2π / texture width rad). The mosaic's pixel centres
look along rays of the world = the camera frame at the first pose, so each
is rotated by that pose into the simulator's world and sampled the same
way, with the same ``log(I + eps)``. A panorama coarser than the texture
averages ``supersample²`` samples of log intensity per pixel (a point
sample would alias the texture's detail into noise).

Scenes at a finite depth (planes, boxes: the simulator's patches) have no
single panorama: what a mosaic shows depends on where the camera stood.
:func:`cast_panorama` ray-casts the mosaic's pixel rays from one camera
centre (the first pose's, the convention's world origin) against the
patches, as the renderer does (nearest hit, texture sampled at the local
coordinates / texel), the scene's panorama or background where no patch is
hit, and gives the range of each ray (m) with it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum.plugins.map._panorama import pano_rays, pano_shape
from tectum.sources.simulate.scenes import CompiledScene
from tectum.sources.simulate.textures import sample_texture

__all__ = ["truth_panorama", "cast_panorama", "swept_mask"]


@njit(cache=True)
def _sample(d, pano, data, table, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    tid = int(pano[0])
    for i in range(d.shape[0]):
        az = np.arctan2(d[i, 0], d[i, 2])
        el = np.arcsin(d[i, 1] / np.sqrt(d[i, 0] ** 2 + d[i, 1] ** 2 + d[i, 2] ** 2))
        out[i] = sample_texture(data, table, tid, az / pano[1], el / pano[1])


def truth_panorama(cs: CompiledScene, width: int, R0: np.ndarray, eps: float = 1e-3,
                   supersample: int | None = None) -> np.ndarray:
    """True log intensity (H, W) float64 of a compiled scene's panorama in
    the mosaic's convention, ``R0`` (3x3) the simulator's world-from-camera
    rotation at the first pose, ``eps`` the sensor model's log offset;
    ``supersample`` samples per pixel side (default: texture width / width)."""
    if cs.pano[0] < 0:
        raise ValueError(f"scene {cs.name!r} has no panorama")
    h, w = pano_shape(width)
    s = supersample or max(1, round(int(cs.tex_table[int(cs.pano[0]), 2]) / width))
    d = np.ascontiguousarray(pano_rays(width * s).reshape(-1, 3) @ np.asarray(R0, np.float64).T)
    out = np.empty(len(d))
    _sample(d, cs.pano, cs.tex_data, cs.tex_table, out)
    return np.log(out + eps).reshape(h, s, w, s).mean(axis=(1, 3))


@njit(cache=True)
def _cast(o, d, patches, pano, bg0, data, table, val, rng):  # type: ignore[no-untyped-def]  # pragma: no cover
    for i in range(d.shape[0]):
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        best = np.inf
        hit = -1
        ba = 0.0
        bb = 0.0
        for k in range(patches.shape[0]):
            q = patches[k]
            den = q[9] * dx + q[10] * dy + q[11] * dz
            if abs(den) < 1e-12:
                continue
            s = (q[9] * (q[0] - o[0]) + q[10] * (q[1] - o[1]) + q[11] * (q[2] - o[2])) / den
            if s <= 1e-9 or s >= best:
                continue
            rx, ry, rz = o[0] + s * dx - q[0], o[1] + s * dy - q[1], o[2] + s * dz - q[2]
            al = rx * q[3] + ry * q[4] + rz * q[5]
            if abs(al) > q[12]:
                continue
            be = rx * q[6] + ry * q[7] + rz * q[8]
            if abs(be) > q[13]:
                continue
            best, hit, ba, bb = s, k, al, be
        rng[i] = best  # d is a unit vector: s is the range
        if hit >= 0:
            q = patches[hit]
            val[i] = q[16] if q[14] < 0 else sample_texture(data, table, int(q[14]), ba / q[15], bb / q[15])
        elif pano[0] >= 0:
            az = np.arctan2(dx, dz)
            el = np.arcsin(min(1.0, max(-1.0, dy)))
            val[i] = sample_texture(data, table, int(pano[0]), az / pano[1], el / pano[1])
        else:
            val[i] = bg0


def cast_panorama(cs: CompiledScene, width: int, R0: np.ndarray, origin: np.ndarray, eps: float = 1e-3,
                  supersample: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The scene seen from the point ``origin`` (m, simulator world) in the
    mosaic's convention (``R0`` (3x3) the world-from-camera rotation of the
    first pose): true log intensity (H, W) float64, the mean of
    ``supersample²`` rays' ``log(I + eps)`` per pixel, and the range (m) of
    the pixel's rays to the nearest patch (their mean; inf where one hits none)."""
    h, w = pano_shape(width)
    R0 = np.asarray(R0, np.float64)
    o = np.asarray(origin, np.float64).reshape(3)
    d = np.ascontiguousarray(pano_rays(width * supersample).reshape(-1, 3) @ R0.T)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    val, rng = np.empty(len(d)), np.empty(len(d))
    _cast(o, d, cs.patches, cs.pano, float(cs.bg[0]), cs.tex_data, cs.tex_table, val, rng)
    s = supersample
    log_i = np.log(val + eps).reshape(h, s, w, s).mean(axis=(1, 3))
    return log_i, rng.reshape(h, s, w, s).mean(axis=(1, 3))


@njit(cache=True)
def _swept(rays, Rs, f, cx, cy, w, h, seen):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    for i in range(rays.shape[0]):
        for k in range(Rs.shape[0]):
            R = Rs[k]
            x = rays[i, 0] * R[0, 0] + rays[i, 1] * R[1, 0] + rays[i, 2] * R[2, 0]  # Rᵀ d: the ray in the camera
            y = rays[i, 0] * R[0, 1] + rays[i, 1] * R[1, 1] + rays[i, 2] * R[2, 1]
            z = rays[i, 0] * R[0, 2] + rays[i, 1] * R[1, 2] + rays[i, 2] * R[2, 2]
            if z <= 1e-9:
                continue
            u = f * x / z + cx
            v = f * y / z + cy
            if -0.5 <= u < w - 0.5 and -0.5 <= v < h - 0.5:
                seen[i] = True
                break


def swept_mask(width: int, orientations: np.ndarray, f: float, cx: float, cy: float,
               sensor: tuple[int, int]) -> np.ndarray:
    """Panorama pixels (H, W) bool whose centre fell inside the pinhole
    image (focal ``f``, centre ``cx``, ``cy`` px, ``sensor`` (w, h)) at any
    of ``orientations`` (N, 3, 3) first-camera-from-camera rotations."""
    h, w = pano_shape(width)
    rays = np.ascontiguousarray(pano_rays(width).reshape(-1, 3))
    seen = np.zeros(len(rays), np.bool_)
    _swept(rays, np.ascontiguousarray(orientations, np.float64).reshape(-1, 3, 3), float(f), float(cx), float(cy),
           int(sensor[0]), int(sensor[1]), seen)
    return seen.reshape(h, w)
