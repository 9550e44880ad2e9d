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

from collections.abc import Mapping
import math
from typing import Any

import numpy as np
from numba import njit

__all__ = ["make_texture", "TexturePool", "sample_texture"]


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
def sample_texture(data: np.ndarray, table: np.ndarray, tid: int, u: float, v: float) -> float:
    """Bilinear, wrapping sample of texture ``tid`` at texel coordinates
    ``u`` (column) and ``v`` (row); texel centres at integers."""
    off, h, w = table[tid, 0], table[tid, 1], table[tid, 2]
    fu = math.floor(u)
    fv = math.floor(v)
    au = u - fu
    av = v - fv
    # wrap without integer division (slow): float quotient, then fix rounding
    c0 = int(fu - w * math.floor(fu / w))
    r0 = int(fv - h * math.floor(fv / h))
    if c0 >= w:
        c0 -= w
    elif c0 < 0:
        c0 += w
    if r0 >= h:
        r0 -= h
    elif r0 < 0:
        r0 += h
    c1 = c0 + 1
    if c1 == w:
        c1 = 0
    r1 = r0 + 1
    if r1 == h:
        r1 = 0
    row0 = off + r0 * w
    row1 = off + r1 * w
    a = data[row0 + c0]
    b = data[row0 + c1]
    c = data[row1 + c0]
    d = data[row1 + c1]
    return (a * (1.0 - au) + b * au) * (1.0 - av) + (c * (1.0 - au) + d * au) * av
