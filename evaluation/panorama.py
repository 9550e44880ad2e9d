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
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum.plugins.map._panorama import pano_rays, pano_shape
from tectum.sources.simulate.scenes import CompiledScene
from tectum.sources.simulate.textures import sample_texture

__all__ = ["truth_panorama", "swept_mask"]


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


def swept_mask(width: int, orientations: np.ndarray, f: float, cx: float, cy: float,
               sensor: tuple[int, int]) -> np.ndarray:
    """Panorama pixels (H, W) bool whose centre fell inside the pinhole
    image (focal ``f``, centre ``cx``, ``cy`` px, ``sensor`` (w, h)) at any
    of ``orientations`` (N, 3, 3) first-camera-from-camera rotations."""
    h, w = pano_shape(width)
    rays = pano_rays(width).reshape(-1, 3)
    seen = np.zeros(len(rays), bool)
    for R in orientations:
        c = rays @ R  # rows: Rᵀ d, the ray in the camera
        z = c[:, 2]
        front = z > 1e-9
        zs = np.where(front, z, 1.0)
        u = f * c[:, 0] / zs + cx
        v = f * c[:, 1] / zs + cy
        seen |= front & (u >= -0.5) & (u < sensor[0] - 0.5) & (v >= -0.5) & (v < sensor[1] - 0.5)
    return seen.reshape(h, w)
