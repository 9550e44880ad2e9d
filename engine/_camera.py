"""The pinhole camera with lens distortion (conventions in :mod:`tectum.camera`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from . import _lens

__all__ = ["Camera", "Model", "depth_points"]

Model = Literal["radtan", "equidistant"]
_COUNTS: dict[str, tuple[int, ...]] = {"radtan": (0, 4, 5, 8, 12, 14), "equidistant": (0, 4)}


@dataclass(frozen=True)
class Camera:
    """One calibrated camera.

    ``K`` 3x3 intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels
    (no skew); ``D`` the distortion coefficients of ``model``: ``"radtan"``
    (OpenCV's plumb-bob and its extensions, k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2
    s3 s4 [τx τy]]]]) or ``"equidistant"`` (OpenCV's fisheye, k1 k2 k3 k4);
    no coefficients means none. ``size`` (width, height) pixels when known.
    For rectification, ``R`` (3x3 rectifying rotation) and ``P`` (3x3 or 3x4
    new projection), used by :meth:`undistort_maps` only.

    ``params`` packs the intrinsics for the kernels of :mod:`tectum.camera`
    (:func:`~tectum.camera.project_kernel` and the others).
    """

    K: np.ndarray
    D: np.ndarray
    size: tuple[int, int] | None = None
    R: np.ndarray | None = None
    P: np.ndarray | None = None
    model: Model = "radtan"
    params: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        K = _finite(self.K, "K")
        if K.size != 9:
            raise ValueError(f"camera: K must be 3x3, got {K.size} numbers")
        K = K.reshape(3, 3)
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ValueError(f"camera: focal lengths must be positive, got fx={K[0, 0]:g}, fy={K[1, 1]:g} in K")
        if K[0, 1] != 0 or K[1, 0] != 0 or tuple(K[2]) != (0, 0, 1):
            raise ValueError(f"camera: K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {K.tolist()}")
        if self.model not in _COUNTS:
            raise ValueError(f"camera: unknown distortion model {self.model!r} (radtan or equidistant)")
        D = _finite(self.D, "D").ravel()
        if D.size not in _COUNTS[self.model]:
            counts = ", ".join(map(str, _COUNTS[self.model][1:]))
            raise ValueError(f"camera: {D.size} distortion coefficients; the {self.model} model takes {counts}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)
        if self.size is not None:
            w, h = (int(v) for v in self.size)
            if w <= 0 or h <= 0:
                raise ValueError(f"camera: image size must be positive, got {self.size}")
            object.__setattr__(self, "size", (w, h))
        if self.R is not None:
            R = _finite(self.R, "R")
            if R.size != 9:
                raise ValueError(f"camera: R must be 3x3, got {R.size} numbers")
            object.__setattr__(self, "R", R.reshape(3, 3))
        if self.P is not None:
            P = _finite(self.P, "P")
            if P.size not in (9, 12):
                raise ValueError(f"camera: P must be 3x3 or 3x4, got {P.size} numbers")
            object.__setattr__(self, "P", P.reshape(3, P.size // 3))
        object.__setattr__(self, "params", _lens.pack(K, D, self.model))

    # -- intrinsics ----------------------------------------------------------------
    @property
    def fx(self) -> float:
        """Focal length along x, pixels."""
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        """Focal length along y, pixels."""
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        """Principal point x, pixels."""
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        """Principal point y, pixels."""
        return float(self.K[1, 2])

    @property
    def width(self) -> int:
        """Image width in pixels (ValueError when the calibration has no size)."""
        return self._size()[0]

    @property
    def height(self) -> int:
        """Image height in pixels (ValueError when the calibration has no size)."""
        return self._size()[1]

    def _size(self, sensor: tuple[int, int] | None = None) -> tuple[int, int]:
        size = sensor if sensor is not None else self.size
        if size is None:
            raise ValueError("camera: no image size (give the sensor size, or a calibration with one)")
        return int(size[0]), int(size[1])

    def scaled(self, sx: float, sy: float | None = None) -> Camera:
        """The camera seen through an image scaled by ``sx`` (and ``sy``,
        default ``sx``): new pixels per old pixel, pixel centres kept
        (``u' = s (u + 1/2) - 1/2``), so ``scaled(1/2)`` matches
        ``filter.downsample`` with factor 2; the size becomes ``ceil(w sx)`` x
        ``ceil(h sy)``. The distortion coefficients (normalised coordinates)
        and ``R`` do not change; ``P`` scales like ``K``."""
        sy = sx if sy is None else sy
        if not (sx > 0 and sy > 0 and math.isfinite(sx) and math.isfinite(sy)):
            raise ValueError(f"camera.scaled: factors must be positive and finite, got {sx}, {sy}")
        S = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])
        size = None
        if self.size is not None:
            size = (math.ceil(self.size[0] * sx - 1e-9), math.ceil(self.size[1] * sy - 1e-9))
        P = None if self.P is None else S @ self.P
        return Camera(S @ self.K, self.D, size, self.R, P, self.model)

    # -- projection -----------------------------------------------------------------
    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of camera-frame points (N, 3) in metres, with
        distortion; NaN for points not in front of the camera (``Z <= 0``)."""
        pts = _points(points, 3, "camera.project points")
        out = np.empty((len(pts), 2))
        _lens.project_many(self.params, pts, out)
        return out

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Distorted normalised coordinates (N, 2) of undistorted ones ``(X/Z, Y/Z)`` (N, 2)."""
        pts = _points(xy, 2, "camera.distort_normalized xy")
        out = np.empty_like(pts)
        _lens.distort_many(self.params, pts, out)
        return out

    def undistort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates (N, 2) of distorted ones: the
        inverse of :meth:`distort_normalized`, NaN where it has none."""
        pts = _points(xy, 2, "camera.undistort_normalized xy")
        out = np.empty_like(pts)
        _lens.undistort_many(self.params, pts, out)
        return out

    def undistort_points(self, pixels: np.ndarray, P: np.ndarray | None = None,
                         R: np.ndarray | None = None) -> np.ndarray:
        """Pixels (N, 2) undistorted: each ray rotated by ``R`` (3x3, default
        none) and projected by ``P`` (3x3 or the left 3x3 of a 3x4, default
        ``K``) without distortion, as ``cv2.undistortPoints(..., R=R, P=P)``.
        NaN where the model has no inverse or the ray ends behind ``P``."""
        pts = _points(pixels, 2, "camera.undistort_points pixels")
        H = self._homography(P, R)
        out = np.empty_like(pts)
        _lens.undistort_pixels_many(self.params, pts, H, out)
        return out

    def _homography(self, P: np.ndarray | None, R: np.ndarray | None) -> np.ndarray:
        M = self.K if P is None else np.asarray(P, np.float64)
        if M.shape not in ((3, 3), (3, 4)):
            raise ValueError(f"camera: P must be 3x3 or 3x4, got {M.shape}")
        Rm = np.eye(3) if R is None else np.asarray(R, np.float64)
        if Rm.shape != (3, 3):
            raise ValueError(f"camera: R must be 3x3, got {Rm.shape}")
        return np.ascontiguousarray(M[:, :3] @ Rm)

    def bearings(self, pixels: np.ndarray) -> np.ndarray:
        """Unit rays (N, 3) in the camera frame through pixels (N, 2); NaN
        where the model has no inverse."""
        ray = self._rays(pixels, "camera.bearings pixels")
        return ray / np.linalg.norm(ray, axis=1, keepdims=True)

    def back_project(self, pixels: np.ndarray, depth: float | np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) in metres at ``depth`` (scalar or (N,),
        the ``Z`` coordinate in m, not the distance) along the rays of
        pixels (N, 2): ``project(back_project(p, d)) == p``."""
        ray = self._rays(pixels, "camera.back_project pixels")
        d = np.asarray(depth, np.float64)
        if d.ndim > 1 or (d.ndim == 1 and len(d) != len(ray)):
            raise ValueError(f"camera.back_project: depth must be a scalar or ({len(ray)},), got {d.shape}")
        return ray * (d[:, None] if d.ndim else d)

    def _rays(self, pixels: np.ndarray, name: str) -> np.ndarray:
        pts = _points(pixels, 2, name)
        xy = np.empty_like(pts)
        _lens.undistort_pixels_many(self.params, pts, np.eye(3), xy)
        return np.column_stack([xy, np.ones(len(xy))])

    def undistort_maps(self, sensor: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Where each pixel of a ``sensor`` (width, height; default ``size``)
        goes: ``(map_x, map_y)``, float64 (H, W), the undistorted position
        of the pixel centre, rectified by ``R`` and projected by ``P`` when
        the camera has them (else ``K``); NaN where the model has no inverse.
        This is the forward map events need (``filter.undistort``), not
        OpenCV's ``initUndistortRectifyMap``, which maps the other way for
        resampling images."""
        w, h = self._size(sensor)
        gx, gy = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        out = self.undistort_points(np.column_stack([gx.ravel(), gy.ravel()]), self.P, self.R)
        return out[:, 0].reshape(h, w), out[:, 1].reshape(h, w)


def depth_points(depth: np.ndarray, K: np.ndarray, R_wc: np.ndarray,
                 t_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The known pixels of a depth map (H, W, m along the optical axis;
    NaN, or not above 0, unknown) of a pinhole camera with intrinsics ``K``
    (3x3, px) at world-from-camera ``R_wc``, ``t_wc`` (m) as world points:
    ``(points (N, 3) m, rows, columns)``, the pixels in row-major order."""
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    Z = depth[v, u].astype(np.float64)
    pc = np.stack([(u - K[0, 2]) / K[0, 0] * Z, (v - K[1, 2]) / K[1, 1] * Z, Z], axis=1)
    return np.ascontiguousarray(pc @ np.asarray(R_wc, np.float64).T + np.asarray(t_wc, np.float64)), v, u


def _finite(a: object, name: str) -> np.ndarray:
    arr = np.asarray(a, np.float64)
    if not np.isfinite(arr).all():
        raise ValueError(f"camera: {name} holds a NaN or infinite value: {arr.tolist()}")
    return arr


def _points(a: object, k: int, name: str) -> np.ndarray:
    arr = np.asarray(a, np.float64)
    if arr.ndim != 2 or arr.shape[1] != k:
        raise ValueError(f"{name}: expected shape (N, {k}), got {arr.shape}")
    return np.ascontiguousarray(arr)
