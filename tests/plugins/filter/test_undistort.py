import json

import cv2
import numpy as np
import pytest

from tectum.camera import Camera, read_calibration, read_uzh_calib
from tectum.plugins.filter import Undistort, undistort_lut
from tectum.testing import assert_batch_invariant, feed

from helpers import shared_data

K = np.array([[30.0, 0, 12.0], [0, 31.0, 8.0], [0, 0, 1]])
D = np.array([-0.2, 0.05, 0.001, -0.002, 0.0])


FISHEYE = np.array([-0.3, 0.1, 0.0, 0.0])


def reference(ev, cam):
    """Per event, straight through cv2.undistortPoints (cv2.fisheye's for the
    equidistant model), rounded to the nearest pixel."""
    pts = np.stack([ev.x, ev.y], 1).astype(np.float64).reshape(-1, 1, 2)
    P = cam.P if cam.P is not None else cam.K
    if cam.model == "equidistant":
        u = cv2.fisheye.undistortPoints(pts, cam.K, cam.D, R=cam.R, P=P,
                                        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))[:, 0]
    else:
        u = cv2.undistortPoints(pts, cam.K, cam.D, R=cam.R, P=P)[:, 0]
    ux, uy = np.rint(u[:, 0]), np.rint(u[:, 1])
    ok = (ux >= 0) & (ux < ev.sensor[0]) & (uy >= 0) & (uy < ev.sensor[1])
    return ok, ux[ok].astype(int), uy[ok].astype(int)


def test_matches_per_event_opencv(make_pattern):
    ev = make_pattern()
    out = feed(Undistort(camera=Camera(K, D)), [ev])[0]
    ok, ux, uy = reference(ev, Camera(K, D))
    assert np.array_equal(out.t, ev.t[ok]) and np.array_equal(out.x, ux) and np.array_equal(out.y, uy)
    assert not ok.all()  # barrel distortion pushes corners out


def test_equidistant_matches_per_event_opencv(make_pattern, tmp_path):
    """The fisheye model, given directly and as a ROS camera_info file."""
    ev = make_pattern()
    cam = Camera(K, FISHEYE, model="equidistant")
    out = feed(Undistort(camera=cam), [ev])[0]
    ok, ux, uy = reference(ev, cam)
    assert np.array_equal(out.t, ev.t[ok]) and np.array_equal(out.x, ux) and np.array_equal(out.y, uy)
    assert not ok.all()
    ros = tmp_path / "fisheye.yaml"
    ros.write_text("image_width: 24\nimage_height: 16\ndistortion_model: equidistant\ncamera_matrix:\n  rows: 3\n"
                   "  cols: 3\n  data: [" + ", ".join(map(str, K.ravel())) + "]\ndistortion_coefficients:\n  rows: 1\n"
                   "  cols: 4\n  data: [" + ", ".join(map(str, FISHEYE)) + "]\n")
    from_file = feed(Undistort(calib=str(ros)), [ev])[0]
    assert np.array_equal(from_file.x, out.x) and np.array_equal(from_file.y, out.y)


def test_zero_distortion_is_identity():
    lx, ly = undistort_lut(Camera(K, np.zeros(5)), (24, 16))
    gx, gy = np.meshgrid(np.arange(24), np.arange(16))
    assert np.array_equal(lx, gx) and np.array_equal(ly, gy)


def test_batch_invariant(make_pattern):
    assert_batch_invariant(lambda: Undistort(camera=Camera(K, D)), make_pattern(), max_examples=5)


def test_readers_agree(tmp_path):
    txt = tmp_path / "calib.txt"
    txt.write_text("30.0 31.0 12.0 8.0 -0.2 0.05 0.001 -0.002 0.0\n")
    yml = tmp_path / "cam.yaml"
    fs = cv2.FileStorage(str(yml), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 24)
    fs.write("image_height", 16)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D.reshape(1, 5))
    fs.release()
    js = tmp_path / "cam.json"
    js.write_text(json.dumps({"K": K.tolist(), "D": D.tolist(), "width": 24, "height": 16}))
    ros = tmp_path / "ros.yaml"
    ros.write_text("image_width: 24\nimage_height: 16\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: ["
                   + ", ".join(map(str, K.ravel())) + "]\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n"
                   "  data: [" + ", ".join(map(str, D)) + "]\n")
    cams = [read_calibration(p) for p in (txt, yml, js, ros)]
    for c in cams:
        assert np.allclose(c.K, K) and np.allclose(c.D, D)
    assert cams[1].size == (24, 16) and cams[3].size == (24, 16)
    with pytest.raises(ValueError, match="bad.txt: expected 9 numbers"):
        (tmp_path / "bad.txt").write_text("1 2 3")
        read_uzh_calib(tmp_path / "bad.txt")


def test_sensor_size_mismatch(make_pattern, tmp_path):
    with pytest.raises(ValueError, match="sensor"):
        feed(Undistort(camera=Camera(K, D, size=(346, 260))), [make_pattern()])


def test_stereo_rectification_from_R_T(make_pattern, tmp_path):
    f = tmp_path / "stereo.yml"
    fs = cv2.FileStorage(str(f), cv2.FILE_STORAGE_WRITE)
    for k, v in {"M1": K, "D1": D, "M2": K, "D2": D, "R": cv2.Rodrigues(np.array([0.0, 0.05, 0.01]))[0],
                 "T": np.array([[-0.1], [0.0], [0.0]])}.items():
        fs.write(k, v)
    fs.write("image_width", 24)
    fs.write("image_height", 16)
    fs.release()
    left, right = read_calibration(f, "left"), read_calibration(f, "right")
    assert left.R is not None and left.P is not None and not np.allclose(left.R, right.R)
    ev = make_pattern()
    out = feed(Undistort(calib=str(f), side="right"), [ev])[0]
    ok, ux, uy = reference(ev, right)
    assert np.array_equal(out.x, ux) and np.array_equal(out.y, uy)


def test_uzh_calib_from_shared_data():
    root = shared_data()
    if root is None:
        pytest.skip("real recordings not available: ../shared/data is absent (set TECTUM_SHARED_DATA)")
    cam = read_calibration(root / "ecd" / "slider_depth" / "calib.txt")
    assert cam.K[0, 0] == pytest.approx(335.419462958) and cam.D.size == 5
    lx, ly = undistort_lut(cam, (240, 180))
    assert (lx >= 0).mean() > 0.9


@pytest.mark.parametrize("dist", [D, np.zeros(5)])
def test_extra_columns_follow_their_events(make_pattern, dist):
    """Extra columns stay with the kept events, with drops (barrel
    distortion) and without (no distortion: every event kept)."""
    ev = make_pattern()
    ev = ev.with_columns(index=np.arange(len(ev), dtype=np.int64))
    out = feed(Undistort(camera=Camera(K, dist)), [ev])[0]
    ok, ux, uy = reference(ev, Camera(K, dist))
    assert np.array_equal(out.columns["index"], np.flatnonzero(ok))
    assert np.array_equal(out.columns["noise"], ev.columns["noise"][ok])
    assert np.array_equal(out.x, ux) and np.array_equal(out.y, uy) and np.array_equal(out.p, ev.p[ok])


def test_output_is_checked_as_its_input_was(make_pattern):
    """The table lands only inside the sensor, so the output of a validated
    packet is marked checked (the pipeline's guard skips it) and passes
    validate; that of an unchecked packet stays unchecked; extra columns
    follow their events."""
    from tectum import EventPacket

    ev = make_pattern().validate()
    out = Undistort(camera=Camera(K, D)).process(ev)[0]
    ok, _, _ = reference(ev, Camera(K, D))
    assert out.checked and len(out) == ok.sum()
    out.validate()
    assert np.array_equal(out.columns["noise"], ev.columns["noise"][ok])
    raw = EventPacket(ev.t, ev.x, ev.y, ev.p, sensor=ev.sensor, t_start=ev.t_start, t_end=ev.t_end)
    assert not raw.checked and not Undistort(camera=Camera(K, D)).process(raw)[0].checked
