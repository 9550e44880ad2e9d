"""Calibration files to :class:`~tectum.camera.Camera`.

* OpenCV ``FileStorage`` YAML/JSON: ``camera_matrix`` / ``distortion_coefficients``
  (or the short ``K``/``D``, ``cameraMatrix``/``distCoeffs``), stereo files with
  ``M1 D1 M2 D2 R T`` and optionally ``R1 R2 P1 P2``; the model from a
  ``distortion_model`` string or the calibration sample's ``fisheye_model: 1``.
* ROS ``camera_info`` YAML, as ``camera_calibration`` writes it
  (``camera_matrix: {rows, cols, data}``, ``distortion_model``,
  ``rectification_matrix``, ``projection_matrix``) or as the message prints
  (``width height distortion_model D K R P``, lower case in ROS 2).
* Plain JSON with the same keys.
* The UZH event-camera dataset's ``calib.txt``: one line ``fx fy cx cy k1 k2 p1 p2 k3``.

Distortion model names: ``radtan``, ``plumb_bob``, ``rational_polynomial``,
``radial_tangential`` are the radtan model; ``equidistant``, ``fisheye``,
``kannala_brandt`` the equidistant one.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

import numpy as np

from ._camera import Camera, Model
from .errors import FormatError

__all__ = ["camera_from", "read_calibration", "read_uzh_calib", "Side"]

Side = Literal["mono", "left", "right"]

_MODEL_NAMES: dict[str, Model] = {
    "radtan": "radtan", "plumb_bob": "radtan", "rational_polynomial": "radtan", "radial_tangential": "radtan",
    "equidistant": "equidistant", "fisheye": "equidistant", "kannala_brandt": "equidistant",
}


def read_uzh_calib(path: str | Path) -> Camera:
    """The UZH event-camera dataset's ``calib.txt``: ``fx fy cx cy k1 k2 p1 p2 k3``."""
    path = Path(path)
    vals = path.read_text().split()
    if len(vals) != 9:
        raise FormatError(f"expected 9 numbers 'fx fy cx cy k1 k2 p1 p2 k3', found {len(vals)}", path=str(path))
    try:
        fx, fy, cx, cy, *d = (float(v) for v in vals)
    except ValueError as e:
        raise FormatError(str(e), path=str(path)) from None
    return _camera(path, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]), np.array(d))


def read_calibration(path: str | Path, side: Side = "mono") -> Camera:
    """Read a calibration file (format by extension and content, see
    :mod:`tectum.camera`). ``side`` picks the camera of a stereo file; its
    rectification comes from ``R1/P1`` (``R2/P2``) or, when only ``R`` and
    ``T`` are given, from ``cv2.stereoRectify`` (needs the image size)."""
    path = Path(path)
    if path.suffix.lower() == ".txt":
        return read_uzh_calib(path)
    data = _read_json(path) if path.suffix.lower() == ".json" else _read_yaml(path)
    return _camera_from(data, side, path)


def camera_from(calib: str) -> Camera:
    """The camera an operator's ``calib=`` names: a calibration file (as
    :func:`read_calibration` reads) or inline intrinsics
    ``'fx;fy;cx;cy[;k1;k2;p1;p2[;k3]]'`` (px, radtan distortion; commas work
    too). An empty value is a ValueError saying how to give one."""
    if not calib:
        raise ValueError("needs calib= (a calibration file, or 'fx;fy;cx;cy[;k1;k2;p1;p2;k3]'); a recording's "
                         "calib.txt beside it is used when the pipeline's source is that recording")
    parts = calib.replace(",", ";").split(";")
    if len(parts) in (4, 8, 9):
        try:
            vals = [float(v) for v in parts]
        except ValueError:
            vals = []
        if vals:
            fx, fy, cx, cy, *d = vals
            return Camera(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), np.array(d or [0.0] * 4))
    if not Path(calib).is_file():
        raise ValueError(f"calib={calib!r} is neither a calibration file nor inline intrinsics "
                         "'fx;fy;cx;cy[;k1;k2;p1;p2[;k3]]' (4, 8 or 9 numbers)")
    return read_calibration(calib)


def _camera(path: Path, *args: Any) -> Camera:
    """``Camera(*args)``, its ValueError naming the file."""
    try:
        return Camera(*args)
    except ValueError as e:
        raise FormatError(str(e), path=str(path)) from None


# -- file formats ---------------------------------------------------------------
def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise FormatError(f"invalid JSON: {e.msg}", path=str(path), offset=e.pos) from None
    if not isinstance(data, dict):
        raise FormatError("expected a JSON object", path=str(path))
    return data


def _read_yaml(path: Path) -> dict[str, Any]:
    import cv2

    text = path.read_text()
    if not text.lstrip().startswith("%YAML"):
        text = "%YAML:1.0\n---\n" + text
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as e:
        raise FormatError(f"not an OpenCV YAML file ({str(e).strip().splitlines()[-1]})", path=str(path)) from None
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


def _pick(data: dict[str, Any], names: tuple[str, ...], path: Path) -> np.ndarray | None:
    for n in names:
        if n in data and data[n] is not None:
            try:
                return _matrix(data[n])
            except ValueError as e:
                raise FormatError(f"{n}: {e}", path=str(path)) from None
    return None


def _model(data: dict[str, Any], path: Path) -> Model:
    name = data.get("distortion_model")
    if name is None:
        return "equidistant" if data.get("fisheye_model") in (1, True, "1", "true") else "radtan"
    model = _MODEL_NAMES.get(str(name).strip().lower())
    if model is None:
        raise FormatError(f"unknown distortion_model {name!r}; known: {', '.join(_MODEL_NAMES)}", path=str(path))
    return model


def _camera_from(data: dict[str, Any], side: Side, path: Path) -> Camera:
    w = data.get("image_width", data.get("width"))
    h = data.get("image_height", data.get("height"))
    size = (int(w), int(h)) if w is not None and h is not None else None
    model = _model(data, path)
    if side == "mono":
        # a printed camera_info message: K D R P (k d r p in ROS 2); otherwise R is a stereo rotation
        message = "distortion_model" in data and ("K" in data or "k" in data)
        K = _pick(data, ("camera_matrix", "cameraMatrix", "K", "k", "M", "M1"), path)
        D = _pick(data, ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "d", "D1"), path)
        R = _pick(data, ("rectification_matrix", "R_rect", "Rect") + (("R", "r") if message else ()), path)
        P = _pick(data, ("projection_matrix", "P", "P_rect") + (("p",) if message else ()), path)
    else:
        i = "1" if side == "left" else "2"
        K = _pick(data, ("M" + i, "K" + i, "camera_matrix_" + side), path)
        D = _pick(data, ("D" + i, "distortion_coefficients_" + side), path)
        R = _pick(data, ("R" + i,), path)
        P = _pick(data, ("P" + i,), path)
        if R is None:
            R, P = _stereo_rectify(data, side, size, model, path)
    if K is None:
        raise FormatError(f"no camera matrix (camera_matrix, K, M or M1/M2) for side {side!r}", path=str(path))
    return _camera(path, K, np.zeros(0) if D is None else D, size, R, P, model)


def _stereo_rectify(data: dict[str, Any], side: Side, size: tuple[int, int] | None, model: Model,
                    path: Path) -> tuple[np.ndarray, np.ndarray]:
    import cv2

    need = [m for m in (_pick(data, (n,), path) for n in ("M1", "D1", "M2", "D2", "R", "T")) if m is not None]
    if len(need) < 6 or size is None:
        raise FormatError("stereo rectification needs R1/P1 (R2/P2), or M1 D1 M2 D2 R T "
                          "and image_width/image_height", path=str(path))
    M1, D1, M2, D2, R, T = need
    if model == "equidistant":
        R1, R2, P1, P2, _ = cv2.fisheye.stereoRectify(M1, D1, M2, D2, size, R, T, cv2.CALIB_ZERO_DISPARITY)
    else:
        R1, R2, P1, P2, *_ = cv2.stereoRectify(M1, D1, M2, D2, size, R, T, alpha=0)
    return (R1, P1) if side == "left" else (R2, P2)
