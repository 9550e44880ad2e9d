"""Calibration files read back by ``tectum.camera.read_calibration`` (what
``filter.undistort`` reads): OpenCV YAML, ECD calib.txt, ROS camera_info, stereo."""

from __future__ import annotations

import numpy as np
import pytest

from tectum.calibration import write_calibration, write_stereo
from tectum.camera import Camera, read_calibration

CAM = Camera(np.array([[201.5, 0, 120.25], [0, 202.75, 88.5], [0, 0, 1]]), np.array([-0.31, 0.12, 0.0015, -0.002]),
             (240, 180))


@pytest.mark.parametrize("name, fmt", [("c.yaml", None), ("calib.txt", None), ("info.yaml", "ros"),
                                       ("c.json", "opencv")])
def test_round_trip(tmp_path, name, fmt) -> None:
    path = write_calibration(tmp_path / name, CAM, rms=0.07, per_view=[0.06, 0.08], fmt=fmt)
    back = read_calibration(path)
    np.testing.assert_allclose(back.K, CAM.K, rtol=1e-12)
    np.testing.assert_allclose(back.D[:4], CAM.D, rtol=1e-12)
    assert back.model == "radtan"
    if not name.endswith(".txt"):
        assert back.size == (240, 180)


def test_opencv_yaml_keys(tmp_path) -> None:
    import cv2

    path = write_calibration(tmp_path / "c.yaml", CAM, rms=0.07, per_view=[0.06, 0.08])
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.getNode("image_width").real() == 240 and fs.getNode("image_height").real() == 180
    assert fs.getNode("reprojection_error").real() == pytest.approx(0.07)
    np.testing.assert_allclose(fs.getNode("camera_matrix").mat(), CAM.K)
    np.testing.assert_allclose(fs.getNode("distortion_coefficients").mat().ravel(), CAM.D)
    np.testing.assert_allclose(fs.getNode("per_view_errors").mat().ravel(), [0.06, 0.08])


def test_fisheye_round_trip_and_calib_txt_refuses_it(tmp_path) -> None:
    fish = Camera(CAM.K, np.array([0.05, -0.01, 0.002, 0.0]), (240, 180), model="equidistant")
    for name, fmt in (("f.yaml", None), ("f_ros.yaml", "ros")):
        back = read_calibration(write_calibration(tmp_path / name, fish, fmt=fmt))  # type: ignore[arg-type]
        assert back.model == "equidistant"
        np.testing.assert_allclose(back.D, fish.D, rtol=1e-12)
    with pytest.raises(ValueError, match="calib.txt holds fx fy cx cy k1 k2 p1 p2 k3"):
        write_calibration(tmp_path / "calib.txt", fish)
    assert not (tmp_path / "calib.txt").exists() and not list(tmp_path.glob(".calib.txt*"))


def test_stereo_sides(tmp_path) -> None:
    import cv2

    right = Camera(CAM.K * [[1.01], [1.0], [1]], CAM.D * 0.9, (240, 180))
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
    T = np.array([-0.1, 0.001, 0.002])
    R1, R2, P1, P2, *_ = cv2.stereoRectify(CAM.K, CAM.D, right.K, right.D, (240, 180), R, T.reshape(3, 1), alpha=0)
    path = write_stereo(tmp_path / "s.yaml", CAM, right, R, T, R1, R2, P1, P2, rms=0.1)
    for side, cam, Rr, Pr in (("left", CAM, R1, P1), ("right", right, R2, P2)):
        back = read_calibration(path, side)  # type: ignore[arg-type]
        np.testing.assert_allclose(back.K, cam.K)
        np.testing.assert_allclose(back.R, Rr)
        np.testing.assert_allclose(back.P, Pr)
