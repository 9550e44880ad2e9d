"""Procedural textures for the simulator, and the pool the kernels read.

A texture is a 2-D float32 array of *linear* intensity (1.0 = full scale),
periodic in both axes so it can tile (sampling wraps around). Specs are dicts:

``kind``
    ``"noise"`` (blurred random lattice, the default), ``"checker"``,
    ``"grating"`` (sinusoid along the first axis), ``"constant"`` or
    ``"image"`` (a grey image file read with OpenCV, ``path``).
``size``
    texels per side (noise, checker, grating; default 256).
``mean``
    mean intensity (default 0.5).
``contrast``
    log-intensity standard deviation for ``noise`` (default 0.5), or the
    amplitude of the log-intensity square/sine wave for ``checker`` and
    ``grating`` (default 0.5): intensity = mean * exp(contrast * z).
``blur``
    Gaussian blur in texels (default 1.5 for noise, 1.0 for checker), so
    the texture is smooth at the sampling scale.
``period``
    texels per period of ``checker`` / ``grating`` (default 16).
``seed``
    added to the run's seed (default 0).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numba import njit

__all__ = ["make_texture", "TexturePool", "sample_texture", "texel_taps", "bilinear"]


def _wrap_blur(a: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return a
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(a, sigma, mode="wrap")


def make_texture(spec: Mapping[str, Any] | float | None, seed: int = 0) -> np.ndarray:
    """A texture array (float32 linear intensity) from a spec (see module doc).

    A bare number is a constant intensity (a 1x1 texture)."""
    if spec is None:
        spec = {"kind": "constant", "mean": 0.5}
    if isinstance(spec, (int, float)):
        return np.full((1, 1), float(spec), np.float32)
    kind = spec.get("kind", "noise")
    mean = float(spec.get("mean", 0.5))
    contrast = float(spec.get("contrast", 0.5))
    size = int(spec.get("size", 256))
    period = float(spec.get("period", 16))
    rng = np.random.default_rng([int(seed) & 0x7FFFFFFF, int(spec.get("seed", 0)) & 0x7FFFFFFF, 7])
    if kind == "constant":
        return np.full((1, 1), mean, np.float32)
    if kind == "noise":
        z = _wrap_blur(rng.standard_normal((size, size)), float(spec.get("blur", 1.5)))
        z = (z - z.mean()) / max(float(z.std()), 1e-12)
    elif kind == "checker":
        i = np.arange(size)
        z = np.where(((i[:, None] // (period / 2)) + (i[None, :] // (period / 2))) % 2 == 0, 1.0, -1.0)
        z = _wrap_blur(z, float(spec.get("blur", 1.0)))
    elif kind == "grating":
        u = np.arange(size)
        z = np.tile(np.sin(2 * np.pi * u / period)[None, :], (size, 1))
    elif kind == "image":
        import cv2

        img = cv2.imread(str(spec["path"]), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise ValueError(f"texture image {spec['path']!r} could not be read")
        return np.ascontiguousarray(np.maximum(img.astype(np.float32) / 255.0, 1e-3))
    else:
        raise ValueError(f"unknown texture kind {kind!r}; known: noise checker grating constant image")
    return np.ascontiguousarray((mean * np.exp(contrast * z)).astype(np.float32))


class TexturePool:
    """All textures of a scene in one flat array, for the kernels:
    ``data`` float32 and ``table`` int64 rows ``(offset, height, width)``."""

    def __init__(self) -> None:
        self._parts: list[np.ndarray] = []
        self._rows: list[tuple[int, int, int]] = []
        self._n = 0

    def add(self, tex: np.ndarray) -> int:
        """Add a texture; returns its id."""
        h, w = tex.shape
        self._rows.append((self._n, h, w))
        self._parts.append(np.ascontiguousarray(tex, np.float32).ravel())
        self._n += h * w
        return len(self._rows) - 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        data = np.concatenate(self._parts) if self._parts else np.zeros(1, np.float32)
        table = np.array(self._rows, np.int64).reshape(-1, 3)
        return data, table


@njit(cache=True, inline="always")
def texel_taps(u: float, n: int) -> tuple[int, int, float]:
    """The two wrapped texel indices around coordinate ``u`` on an axis of
    ``n`` texels (centres at integers) and the weight of the second."""
    fu = math.floor(u)
    a = u - fu
    i0 = int(fu)
    if i0 < 0 or i0 >= n:
        # wrap without integer division (slow): float quotient, then fix rounding
        i0 = int(fu - n * math.floor(fu / n))
        if i0 >= n:
            i0 -= n
        elif i0 < 0:
            i0 += n
    i1 = i0 + 1
    if i1 == n:
        i1 = 0
    return i0, i1, a


@njit(cache=True, inline="always")
def bilinear(data: np.ndarray, off: int, w: int, c0: int, c1: int, au: float, r0: int, r1: int,
             av: float) -> float:
    """Bilinear blend of the four texels (rows r0, r1; columns c0, c1)."""
    row0 = off + r0 * w
    row1 = off + r1 * w
    a = data[row0 + c0]
    b = data[row0 + c1]
    c = data[row1 + c0]
    d = data[row1 + c1]
    return (a * (1.0 - au) + b * au) * (1.0 - av) + (c * (1.0 - au) + d * au) * av


@njit(cache=True, inline="always")
def sample_texture(data: np.ndarray, table: np.ndarray, tid: int, u: float, v: float) -> float:
    """Bilinear, wrapping sample of texture ``tid`` at texel coordinates
    ``u`` (column) and ``v`` (row); texel centres at integers."""
    off, h, w = table[tid, 0], table[tid, 1], table[tid, 2]
    c0, c1, au = texel_taps(u, w)
    r0, r1, av = texel_taps(v, h)
    return bilinear(data, off, w, c0, c1, au, r0, r1, av)
