"""Calibration files that :func:`tectum.camera.read_calibration` (and so
``filter.undistort``) reads back.

* ``opencv``: OpenCV ``FileStorage`` YAML (JSON for a ``.json`` name): ``image_width``, ``image_height``,
  ``camera_matrix``, ``distortion_coefficients``, ``distortion_model``,
  ``reprojection_error`` (px) and ``per_view_errors`` (px).
* ``ecd``: the event-camera dataset's ``calib.txt``, one line
  ``fx fy cx cy k1 k2 p1 p2 k3`` (radtan only).
* ``ros``: ROS ``camera_info`` YAML as ``camera_calibration`` writes it.
* stereo (OpenCV YAML): ``M1 D1 M2 D2 R T R1 R2 P1 P2`` and the image size,
  so ``filter.undistort:side=left|right`` rectifies each camera.

Files are written to a temporary name beside the target and renamed, so a
failed write leaves nothing behind.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from tectum.camera import Camera

__all__ = ["write_calibration", "write_stereo", "Format", "format_for"]

Format = Literal["opencv", "ecd", "ros"]


def format_for(path: str | Path) -> Format:
    """The layout a file name asks for: ``.txt`` is ECD's ``calib.txt``,
    anything else OpenCV YAML."""
    return "ecd" if Path(path).suffix.lower() == ".txt" else "opencv"


def _atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent or ".")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _opencv_yaml(entries: Sequence[tuple[str, object]], suffix: str = ".yaml") -> str:
    """OpenCV ``FileStorage`` text (YAML, or JSON for ``suffix`` ``.json``)."""
    import cv2

    fs = cv2.FileStorage(".json" if suffix.lower() == ".json" else ".yaml",
                         cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    for key, value in entries:
        if isinstance(value, np.ndarray):
            fs.write(key, np.asarray(value, np.float64))
        elif isinstance(value, str):
            fs.write(key, value)
        elif isinstance(value, int):
            fs.write(key, value)
        else:
            fs.write(key, float(value))  # type: ignore[arg-type]
    return str(fs.releaseAndGetString())


def _model_name(camera: Camera, ros: bool) -> str:
    if camera.model == "equidistant":
        return "equidistant"
    return "plumb_bob" if ros else "radtan"


def _ros_yaml(camera: Camera, name: str) -> str:
    def mat(a: np.ndarray) -> str:
        a = np.atleast_2d(a)
        vals = ", ".join(repr(float(v)) for v in a.ravel())
        return f"\n  rows: {a.shape[0]}\n  cols: {a.shape[1]}\n  data: [{vals}]"
    w, h = camera._size()
    P = np.hstack([camera.K, np.zeros((3, 1))])
    return (f"image_width: {w}\nimage_height: {h}\ncamera_name: {name}\ncamera_matrix:{mat(camera.K)}\n"
            f"distortion_model: {_model_name(camera, True)}\ndistortion_coefficients:{mat(camera.D[None])}\n"
            f"rectification_matrix:{mat(np.eye(3))}\nprojection_matrix:{mat(P)}\n")


def write_calibration(path: str | Path, camera: Camera, *, rms: float = float("nan"),
                      per_view: Sequence[float] = (), fmt: Format | None = None, name: str = "camera") -> Path:
    """Write ``camera`` (with its image size) to ``path`` in ``fmt``
    (default by extension, :func:`format_for`); ``rms`` px and
    ``per_view`` px go into the OpenCV layout."""
    path = Path(path)
    fmt = fmt or format_for(path)
    if fmt == "ecd":
        if camera.model != "radtan" or camera.D.size > 5:
            raise ValueError(f"calib.txt holds fx fy cx cy k1 k2 p1 p2 k3 (radtan); this camera is {camera.model} "
                             f"with {camera.D.size} coefficients: write OpenCV YAML instead")
        d = np.zeros(5)
        d[:camera.D.size] = camera.D
        text = " ".join(repr(float(v)) for v in (camera.fx, camera.fy, camera.cx, camera.cy, *d)) + "\n"
    elif fmt == "ros":
        text = _ros_yaml(camera, name)
    elif fmt == "opencv":
        w, h = camera._size()
        entries: list[tuple[str, object]] = [("image_width", w), ("image_height", h), ("camera_matrix", camera.K),
                                             ("distortion_coefficients", camera.D[None]),
                                             ("distortion_model", _model_name(camera, False)),
                                             ("reprojection_error", float(rms))]
        if len(per_view):
            entries.append(("per_view_errors", np.asarray(per_view, np.float64)[None]))
        text = _opencv_yaml(entries, path.suffix)
    else:
        raise ValueError(f"unknown calibration format {fmt!r}: opencv, ecd or ros")
    _atomic(path, text)
    return path


def write_stereo(path: str | Path, left: Camera, right: Camera, R: np.ndarray, T: np.ndarray, R1: np.ndarray,
                 R2: np.ndarray, P1: np.ndarray, P2: np.ndarray, *, rms: float = float("nan")) -> Path:
    """Write a stereo calibration (OpenCV YAML, ``M1 D1 M2 D2 R T R1 R2 P1
    P2``, ``x_right = R x_left + T`` m) that ``filter.undistort:side=left``
    and ``side=right`` read."""
    path = Path(path)
    w, h = left._size()
    text = _opencv_yaml([("image_width", w), ("image_height", h), ("distortion_model", _model_name(left, False)),
                         ("M1", left.K), ("D1", left.D[None]), ("M2", right.K), ("D2", right.D[None]),
                         ("R", np.asarray(R)), ("T", np.asarray(T).reshape(3, 1)), ("R1", R1), ("R2", R2),
                         ("P1", P1), ("P2", P2), ("reprojection_error", float(rms))], path.suffix)
    _atomic(path, text)
    return path
