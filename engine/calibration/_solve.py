"""Intrinsics and stereo extrinsics from ordered grid views, with OpenCV.

Mono: ``cv2.calibrateCameraExtended`` (radtan: k1 k2 p1 p2, k3 with
``k3=True``) or ``cv2.fisheye.calibrate`` (equidistant: k1..k4). Outlier
views: after each solve, the worst view is dropped when its RMS exceeds
``outlier_factor`` times the median of the views' RMS and ``outlier_px``,
and the solve repeats (while at least ``min_views`` remain).

RMS conventions (px): a view's RMS is ``sqrt(mean |x - x̂|²)`` over its
points, the 2-D distance between detected and reprojected dots (OpenCV's
``perViewErrors``); the total is the same over all points of the views used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tectum.camera import Camera, Model

__all__ = ["Solution", "solve_mono", "solve_stereo", "StereoSolution", "reprojection"]


@dataclass(frozen=True)
class Solution:
    """A mono calibration: the ``camera``, total ``rms`` px over the views
    kept, ``used`` (indices into the views given), ``view_rms`` px per view
    given (NaN for outliers, computed after the last solve for every view),
    ``residuals`` per view given (N, 2) px, detected minus reprojected, and
    the board poses ``rvecs``/``tvecs`` (camera from board) per view given."""

    camera: Camera
    rms: float
    used: tuple[int, ...]
    view_rms: np.ndarray
    residuals: list[np.ndarray]
    rvecs: list[np.ndarray]
    tvecs: list[np.ndarray]


def reprojection(camera: Camera, obj: np.ndarray, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of board points ``obj`` (N, 3) m at pose ``rvec``/``tvec``."""
    import cv2

    if camera.model == "equidistant":
        px, _ = cv2.fisheye.projectPoints(obj.reshape(-1, 1, 3).astype(np.float64), rvec, tvec, camera.K, camera.D)
    else:
        px, _ = cv2.projectPoints(obj.astype(np.float64), rvec, tvec, camera.K, camera.D)
    return px.reshape(-1, 2)


def _fisheye_flag(name: str) -> int:
    """A ``cv2.fisheye`` flag: in ``cv2.fisheye`` up to OpenCV 4, in ``cv2`` from 5."""
    import cv2

    return int(getattr(cv2.fisheye, name, None) or getattr(cv2, name))


def _calibrate(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int], model: Model,
               k3: bool) -> tuple[Camera, list[np.ndarray], list[np.ndarray]]:
    import cv2

    if model == "equidistant":
        flags = _fisheye_flag("CALIB_RECOMPUTE_EXTRINSIC") | _fisheye_flag("CALIB_FIX_SKEW")
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
        # (1, N, 3) / (1, N, 2): the layout OpenCV 5's fisheye module takes (and 4's)
        _, K, D, rv, tv = cv2.fisheye.calibrate([o.reshape(1, -1, 3).astype(np.float64) for o in obj],
                                                [p.reshape(1, -1, 2).astype(np.float64) for p in img],
                                                size, np.eye(3), np.zeros((4, 1)), flags=flags, criteria=crit)
        D = D.ravel()
    else:
        flags = 0 if k3 else cv2.CALIB_FIX_K3
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
        _, K, D, rv, tv, *_ = cv2.calibrateCameraExtended(
            [o.astype(np.float32) for o in obj], [p.astype(np.float32).reshape(-1, 1, 2) for p in img],
            size, np.eye(3), np.zeros(5), flags=flags, criteria=crit)  # no initial guess: K and D are ignored
        D = D.ravel()[:5] if k3 else D.ravel()[:4]
    return Camera(K, D, size, model=model), list(rv), list(tv)


def solve_mono(obj: np.ndarray, views: list[np.ndarray], size: tuple[int, int], *, model: Model = "radtan",
               k3: bool = False, min_views: int = 3, outlier_factor: float = 3.0,
               outlier_px: float = 0.5) -> Solution:
    """Calibrate from ordered views (each (N, 2) px of the board points
    ``obj`` (N, 3) m) on a ``size`` (w, h) image; see the module docstring."""
    import cv2

    keep = list(range(len(views)))
    while True:
        cam, rv, tv = _calibrate([obj] * len(keep), [views[i] for i in keep], size, model, k3)
        res = [views[i] - reprojection(cam, obj, r, t) for i, r, t in zip(keep, rv, tv, strict=True)]
        rms = np.array([float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) for r in res])
        worst = int(np.argmax(rms))
        if (len(keep) <= min_views or rms[worst] <= outlier_px
                or rms[worst] <= outlier_factor * float(np.median(rms))):
            break
        keep.pop(worst)
    # every view's residuals against the final camera (outliers: their own best pose)
    all_res, all_rv, all_tv = [], [], []
    for i, v in enumerate(views):
        if i in keep:
            k = keep.index(i)
            r, t = rv[k], tv[k]
        else:
            undist = cam.undistort_points(v)
            _, r, t = cv2.solvePnP(obj.astype(np.float64), undist, cam.K, None)
        all_rv.append(np.asarray(r).ravel())
        all_tv.append(np.asarray(t).ravel())
        all_res.append(v - reprojection(cam, obj, all_rv[-1], all_tv[-1]))
    view_rms = np.array([float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) for r in all_res])
    total = float(np.sqrt(np.mean(np.concatenate([np.sum(all_res[i] ** 2, axis=1) for i in keep]))))
    return Solution(cam, total, tuple(keep), view_rms, all_res, all_rv, all_tv)


@dataclass(frozen=True)
class StereoSolution:
    """Two calibrated cameras and the pose of the right one: ``R`` (3, 3),
    ``T`` (3,) m with ``x_right = R x_left + T`` (OpenCV's convention), the
    rectification ``R1 R2 P1 P2`` of ``cv2.stereoRectify``, the stereo
    ``rms`` px and the number of ``pairs`` used."""

    left: Camera
    right: Camera
    R: np.ndarray
    T: np.ndarray
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    rms: float
    pairs: int


def solve_stereo(obj: np.ndarray, left: list[np.ndarray], right: list[np.ndarray], cam_l: Camera,
                 cam_r: Camera) -> StereoSolution:
    """Extrinsics between two calibrated cameras from pairs of views of the
    same board at the same time (``left[k]`` with ``right[k]``), intrinsics
    fixed; then the rectification."""
    import cv2

    if cam_l.size is None or cam_r.size is None:
        raise ValueError("stereo: both cameras need an image size")
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    if cam_l.model == "equidistant":
        o = [obj.reshape(1, -1, 3).astype(np.float64)] * len(left)
        rms, _, _, _, _, R, T = cv2.fisheye.stereoCalibrate(
            o, [p.reshape(1, -1, 2).astype(np.float64) for p in left],
            [p.reshape(1, -1, 2).astype(np.float64) for p in right], cam_l.K, cam_l.D, cam_r.K, cam_r.D,
            cam_l.size, flags=_fisheye_flag("CALIB_FIX_INTRINSIC"), criteria=crit)[:7]
        R1, R2, P1, P2, _ = cv2.fisheye.stereoRectify(cam_l.K, cam_l.D, cam_r.K, cam_r.D, cam_l.size, R, T,
                                                      cv2.CALIB_ZERO_DISPARITY)
    else:
        o32 = [obj.astype(np.float32)] * len(left)
        rms, _, _, _, _, R, T, *_ = cv2.stereoCalibrate(
            o32, [p.astype(np.float32).reshape(-1, 1, 2) for p in left],
            [p.astype(np.float32).reshape(-1, 1, 2) for p in right], cam_l.K, cam_l.D, cam_r.K, cam_r.D,
            cam_l.size, flags=cv2.CALIB_FIX_INTRINSIC, criteria=crit)
        R1, R2, P1, P2, *_ = cv2.stereoRectify(cam_l.K, cam_l.D, cam_r.K, cam_r.D, cam_l.size, R, T, alpha=0)
    return StereoSolution(cam_l, cam_r, R, np.asarray(T).ravel(), R1, R2, P1, P2, float(rms), len(left))
