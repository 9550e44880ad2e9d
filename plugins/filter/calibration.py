"""Camera calibrations for undistortion: the OpenCV pinhole model.

Readers for OpenCV ``FileStorage`` YAML/JSON (``camera_matrix`` /
``distortion_coefficients``, the ``K``/``D`` short names, stereo files with
``M1 D1 M2 D2 R T`` and optionally ``R1 R2 P1 P2``, ROS ``camera_info``
layout with ``rows/cols/data`` maps), plain JSON with the same keys, and
the UZH event-camera dataset's ``calib.txt`` (one line ``fx fy cx cy k1 k2
p1 p2 k3``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

__all__ = ["Camera", "read_calibration", "read_uzh_calib"]

Side = Literal["mono", "left", "right"]


@dataclass(frozen=True)
class Camera:
    """One camera: ``K`` (3x3 intrinsics, pixels), ``D`` distortion
    coefficients in OpenCV order (k1 k2 p1 p2 [k3 [k4 k5 k6 ...]]), optional
    ``size`` (width, height) pixels, and for rectification ``R`` (3x3
    rectifying rotation) and ``P`` (3x3 or 3x4 new projection)."""

    K: np.ndarray
    D: np.ndarray
    size: tuple[int, int] | None = None
    R: np.ndarray | None = None
    P: np.ndarray | None = None

    def __post_init__(self) -> None:
        K = np.asarray(self.K, np.float64).reshape(3, 3)
        D = np.asarray(self.D, np.float64).ravel()
        if D.size not in (0, 4, 5, 8, 12, 14):
            raise ValueError(f"{D.size} distortion coefficients; OpenCV takes 4, 5, 8, 12 or 14")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)
        if self.R is not None:
            object.__setattr__(self, "R", np.asarray(self.R, np.float64).reshape(3, 3))
        if self.P is not None:
            P = np.asarray(self.P, np.float64)
            object.__setattr__(self, "P", P.reshape(3, P.size // 3))


def read_uzh_calib(path: str | Path) -> Camera:
    """The UZH event-camera dataset's ``calib.txt``: ``fx fy cx cy k1 k2 p1 p2 k3``."""
    path = Path(path)
    vals = path.read_text().split()
    if len(vals) != 9:
        raise ValueError(f"{path}: expected 9 numbers 'fx fy cx cy k1 k2 p1 p2 k3', found {len(vals)}")
    try:
        fx, fy, cx, cy, *d = (float(v) for v in vals)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    return Camera(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), np.array(d))


def read_calibration(path: str | Path, side: Side = "mono") -> Camera:
    """Read a calibration file (format by extension and content, see the
    module docstring). ``side`` picks the camera of a stereo file; its
    rectification comes from ``R1/P1`` (``R2/P2``) or, when only ``R`` and
    ``T`` are given, from ``cv2.stereoRectify`` (needs the image size)."""
    path = Path(path)
    if path.suffix.lower() == ".txt":
        return read_uzh_calib(path)
    data = _read_json(path) if path.suffix.lower() == ".json" else _read_yaml(path)
    return _camera_from(data, side, path)


# -- file formats ---------------------------------------------------------------
def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: invalid JSON at byte {e.pos}: {e.msg}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object")
    return data


def _read_yaml(path: Path) -> dict[str, Any]:
    import cv2

    text = path.read_text()
    if not text.lstrip().startswith("%YAML"):
        text = "%YAML:1.0\n---\n" + text
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as e:
        raise ValueError(f"{path}: not an OpenCV YAML file ({str(e).strip().splitlines()[-1]})") from None
    try:
        root = fs.root()
        return {k: _node(root.getNode(k)) for k in root.keys()}
    finally:
        fs.release()


def _node(n: Any) -> Any:
    if n.isMap():
        keys = n.keys()
        if "dt" in keys and "data" in keys:  # an !!opencv-matrix
            m = n.mat()
            if m is not None:
                return m
        return {k: _node(n.getNode(k)) for k in keys}
    if n.isSeq():
        return [_node(n.at(i)) for i in range(n.size())]
    if n.isInt():
        return int(n.real())
    if n.isReal():
        return n.real()
    if n.isString():
        return n.string()
    return None


def _matrix(v: Any) -> np.ndarray:
    if isinstance(v, dict):
        if "data" not in v:
            raise ValueError("matrix entry has no 'data'")
        arr = np.asarray(v["data"], np.float64)
        if "rows" in v and "cols" in v:
            arr = arr.reshape(int(v["rows"]), int(v["cols"]))
        return arr
    return np.asarray(v, np.float64)


def _pick(data: dict[str, Any], names: tuple[str, ...]) -> np.ndarray | None:
    for n in names:
        if n in data and data[n] is not None:
            return _matrix(data[n])
    return None


def _camera_from(data: dict[str, Any], side: Side, path: Path) -> Camera:
    w = data.get("image_width", data.get("width"))
    h = data.get("image_height", data.get("height"))
    size = (int(w), int(h)) if w is not None and h is not None else None
    if side == "mono":
        K = _pick(data, ("camera_matrix", "cameraMatrix", "K", "M", "M1"))
        D = _pick(data, ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "D1"))
        R = _pick(data, ("rectification_matrix", "R_rect", "Rect"))
        P = _pick(data, ("projection_matrix", "P", "P_rect"))
    else:
        i = "1" if side == "left" else "2"
        K = _pick(data, ("M" + i, "K" + i, "camera_matrix_" + side))
        D = _pick(data, ("D" + i, "distortion_coefficients_" + side))
        R = _pick(data, ("R" + i,))
        P = _pick(data, ("P" + i,))
        if R is None:
            R, P = _stereo_rectify(data, side, size, path)
    if K is None:
        raise ValueError(f"{path}: no camera matrix (camera_matrix, K, M or M1/M2) for side {side!r}")
    return Camera(K, np.zeros(0) if D is None else D, size, R, P)


def _stereo_rectify(data: dict[str, Any], side: Side, size: tuple[int, int] | None,
                    path: Path) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    need = [_pick(data, (n,)) for n in ("M1", "D1", "M2", "D2", "R", "T")]
    if any(v is None for v in need) or size is None:
        raise ValueError(f"{path}: stereo rectification needs R1/P1 (R2/P2), or M1 D1 M2 D2 R T "
                         "and image_width/image_height")
    M1, D1, M2, D2, R, T = need
    R1, R2, P1, P2, *_ = cv2.stereoRectify(M1, D1, M2, D2, size, R, T, alpha=0)
    return (R1, P1) if side == "left" else (R2, P2)
