"""tectum.camera: the lens models against OpenCV, rotations and poses against
scipy, calibration files, and the errors bad input gets."""

import json
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation, Slerp

import tectum
from tectum import FormatError
from tectum.camera import (
    Camera,
    compose,
    hat,
    interpolate_poses,
    invert,
    quat_conj,
    quat_mul,
    quat_slerp,
    quat_to_rot,
    read_calibration,
    read_uzh_calib,
    rot_to_quat,
    se3_exp,
    se3_log,
    so3_exp,
    so3_log,
    transform_points,
)

K = np.array([[300.0, 0, 170.0], [0, 310.0, 130.0], [0, 0, 1]])
SENSOR = (346, 260)
RADTAN = {
    4: [-0.25, 0.08, 0.001, -0.002],
    5: [-0.3, 0.1, 0.001, -0.002, -0.01],
    8: [-0.2, 0.05, 0.001, -0.002, 0.01, 0.1, 0.02, 0.01],
    12: [-0.2, 0.05, 0.001, -0.002, 0.01, 0.1, 0.02, 0.01, 0.001, 0.002, -0.001, 0.0005],
    14: [-0.2, 0.05, 0.001, -0.002, 0.01, 0.1, 0.02, 0.01, 0.001, 0.002, -0.001, 0.0005, 0.01, -0.02],
}
FISHEYE = [0.1, -0.05, 0.01, -0.002]
TIGHT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
CAMERAS = [pytest.param(Camera(K, d), id=f"radtan{n}") for n, d in RADTAN.items()]
CAMERAS.append(pytest.param(Camera(K, FISHEYE, model="equidistant"), id="equidistant"))


def points(n, spread, seed=0):
    """Random camera-frame points in front of the camera, normalised
    coordinates within ``spread``, depths 0.5..3 m."""
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-spread, spread, (n, 2)), np.ones(n)] * rng.uniform(0.5, 3.0, (n, 1))


def opencv_project(cam, P):
    if cam.model == "equidistant":
        return cv2.fisheye.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D)[0][:, 0]
    return cv2.projectPoints(P, np.zeros(3), np.zeros(3), cam.K, cam.D)[0][:, 0]


def opencv_undistort(cam, px, R=None, P=None):
    if cam.model == "equidistant":
        return cv2.fisheye.undistortPoints(px.reshape(-1, 1, 2), cam.K, cam.D, R=R, P=P, criteria=TIGHT)[:, 0]
    return cv2.undistortPoints(px.reshape(-1, 1, 2), cam.K, cam.D, R=R, P=P, criteria=TIGHT)[:, 0]


def spread_of(cam):
    return 1.5 if cam.model == "equidistant" else 0.6


# -- the lens models --------------------------------------------------------------
@pytest.mark.parametrize("cam", CAMERAS)
def test_project_matches_opencv(cam):
    P = points(2000, spread_of(cam))
    np.testing.assert_allclose(cam.project(P), opencv_project(cam, P), rtol=0, atol=1e-6)


@pytest.mark.parametrize("cam", CAMERAS)
def test_undistort_points_matches_opencv(cam):
    px = opencv_project(cam, points(2000, spread_of(cam), seed=1))
    np.testing.assert_allclose(cam.undistort_points(px), opencv_undistort(cam, px, P=cam.K), rtol=0, atol=1e-6)
    R = cv2.Rodrigues(np.array([0.02, -0.03, 0.01]))[0]
    newK = np.array([[250.0, 0, 160], [0, 250, 120], [0, 0, 1]])
    np.testing.assert_allclose(cam.undistort_points(px, P=newK, R=R), opencv_undistort(cam, px, R=R, P=newK),
                               rtol=0, atol=1e-6)


@pytest.mark.parametrize("cam", CAMERAS)
def test_round_trips(cam):
    rng = np.random.default_rng(2)
    px = rng.uniform([0, 0], SENSOR, (2000, 2))
    depth = rng.uniform(0.2, 10.0, 2000)
    X = cam.back_project(px, depth)
    np.testing.assert_allclose(X[:, 2], depth, rtol=1e-15)
    np.testing.assert_allclose(cam.project(X), px, rtol=0, atol=1e-9)
    b = cam.bearings(px)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.cross(b, X), 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cam.project(b), px, rtol=0, atol=1e-9)
    xy = (px - [cam.cx, cam.cy]) / [cam.fx, cam.fy]
    np.testing.assert_allclose(cam.distort_normalized(cam.undistort_normalized(xy)), xy, rtol=0, atol=1e-12)


def first_fold(derivative, stop):
    """The first zero of a radial derivative on a fine grid up to ``stop``."""
    r = np.linspace(0, stop, 200_001)
    bad = derivative(r) <= 0
    return r[np.argmax(bad)] if bad.any() else stop


@pytest.mark.parametrize("k", [[0.0142, 0.2703, -0.0712], [-0.6, 0.25, -0.03], [0.3, -0.2, 0.0]])
def test_inverse_on_the_whole_first_branch(k):
    """Points out to 0.99 of the fold of strongly distorted lenses come back;
    the first (pincushion, then folding) sent plain Newton into a 2-cycle."""
    fold = first_fold(lambda r: 1 + 3 * k[0] * r**2 + 5 * k[1] * r**4 + 7 * k[2] * r**6, 3.0)
    rng = np.random.default_rng(12)
    r, phi = rng.uniform(0, 0.99 * fold, 3000), rng.uniform(0, 2 * np.pi, 3000)
    xy = np.c_[r * np.cos(phi), r * np.sin(phi)]
    cam = Camera(K, [k[0], k[1], 0.001, -0.002, k[2]])
    np.testing.assert_allclose(cam.undistort_normalized(cam.distort_normalized(xy)), xy, rtol=0, atol=1e-12)


def test_no_inverse_and_behind_the_camera_are_nan():
    """Past the fold of a lens (r - 0.5 r³ + 0.1 r⁵ peaks at r = 1, 0.6,
    and rises again past r = √2) no ray of the first branch maps to the
    pixel: NaN, not a guess, and not the root out on the third branch."""
    cam = Camera(K, [-0.5, 0.1, 0, 0])
    rd = np.array([0.59, 0.601, 0.61, 0.7])
    und = cam.undistort_points(np.c_[cam.cx + 300 * rd, np.full(4, cam.cy)])
    assert np.isfinite(und[0]).all() and np.isnan(und[1:]).all()
    assert np.isnan(cam.bearings(np.array([[cam.cx, cam.cy - cam.fy * 0.61]]))).all()
    assert np.isnan(cam.project(np.array([[0.1, 0.1, 0.0], [0.1, 0.1, -1.0]]))).all()
    fish = Camera(K, [-0.7, 0, 0, 0], model="equidistant")  # θd(θ) peaks at θ = 0.69 rad
    assert np.isnan(fish.undistort_points(np.array([[cam.cx + 300 * 0.5, cam.cy]]))).all()
    fish = Camera(K, [-0.7, 0.2, 0, 0], model="equidistant")  # a fold at 0.85 rad, rising again past 1.17
    assert np.isnan(fish.undistort_normalized(np.array([[0.6, 0.0]]))).all()
    assert np.isfinite(fish.undistort_normalized(np.array([[0.45, 0.0]]))).all()
    wide = Camera(K, [0, 0, 0, 0], model="equidistant")  # θd = θ: past 90° is behind the camera
    assert np.isfinite(wide.bearings(np.array([[cam.cx + 300 * 1.55, cam.cy]]))).all()
    assert np.isnan(wide.bearings(np.array([[cam.cx + 300 * 1.6, cam.cy]]))).all()
    behind = cam.undistort_points(np.array([[cam.cx, cam.cy]]), R=so3_exp(np.array([0, 2.0, 0])))
    assert np.isnan(behind).all()  # the rectifying rotation turns the ray away from P


@pytest.mark.parametrize("model", ["radtan", "equidistant"])
def test_undistort_maps_with_rectification(model):
    """The maps are undistort_points on every pixel centre, with the
    camera's own R and P, row-major (H, W)."""
    D = RADTAN[5] if model == "radtan" else FISHEYE
    R = cv2.Rodrigues(np.array([0.01, 0.02, -0.01]))[0]
    P = np.array([[280.0, 0, 160, -28.0], [0, 280, 125, 0], [0, 0, 1, 0]])
    cam = Camera(K, D, (40, 30), R, P, model)
    mx, my = cam.undistort_maps()
    assert mx.shape == (30, 40)
    gx, gy = np.meshgrid(np.arange(40.0), np.arange(30.0))
    ref = opencv_undistort(cam, np.c_[gx.ravel(), gy.ravel()], R=R, P=P)
    np.testing.assert_allclose(np.c_[mx.ravel(), my.ravel()], ref, rtol=0, atol=1e-6)


def test_scaled_keeps_pixel_centres():
    cam = Camera(K, RADTAN[5], SENSOR)
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (173, 130) and half.scaled(2.0).size == SENSOR
    P = points(100, 0.5)
    np.testing.assert_allclose(half.project(P), (cam.project(P) + 0.5) / 2 - 0.5, rtol=0, atol=1e-12)
    assert (half.fx, half.fy) == (150.0, 155.0)
    assert Camera(K, []).scaled(3.0, 2.0).K[1, 2] == pytest.approx(2 * 130.5 - 0.5)


# -- rotations and poses ----------------------------------------------------------------
ANGLES = [0.0, 1e-12, 1e-7, 1e-4, 9.9e-3, 1e-2, 0.3, 1.5, 2.7, math.pi - 1e-3, math.pi - 1e-8]


def rotvecs(seed=0):
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(len(ANGLES) * 20, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * np.repeat(ANGLES, 20)[:, None]


def test_so3_against_scipy():
    w = rotvecs()
    R = so3_exp(w)
    np.testing.assert_allclose(R, Rotation.from_rotvec(w).as_matrix(), rtol=0, atol=1e-15 * 4)
    np.testing.assert_allclose(so3_log(R), w, rtol=0, atol=1e-9)  # angles near π: the axis is ill-conditioned
    small = np.abs(np.linalg.norm(w, axis=1) - math.pi) > 1e-3 / 2
    np.testing.assert_allclose(so3_log(R[small]), w[small], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(so3_exp(w[5]), R[5], rtol=0, atol=0)  # one element, no stack
    np.testing.assert_allclose(hat(w[30]) @ np.array([1.0, 2, 3]), np.cross(w[30], [1.0, 2, 3]), rtol=1e-15)


def test_so3_log_at_pi_is_a_logarithm():
    for axis in np.eye(3).tolist() + [[1 / math.sqrt(2), -1 / math.sqrt(2), 0]]:
        R = Rotation.from_rotvec(math.pi * np.array(axis)).as_matrix()
        w = so3_log(R)
        assert np.linalg.norm(w) == pytest.approx(math.pi)
        np.testing.assert_allclose(so3_exp(w), R, atol=1e-15 * 4)


def test_quaternions_against_scipy():
    rot = Rotation.from_rotvec(rotvecs(1))
    q = rot.as_quat()  # x, y, z, w
    np.testing.assert_allclose(quat_to_rot(q), rot.as_matrix(), rtol=0, atol=1e-15 * 4)
    qq = rot_to_quat(rot.as_matrix())
    assert (qq[:, 3] >= 0).all()
    np.testing.assert_allclose(qq * np.sign(q[:, 3:] + 1e-300), q, rtol=0, atol=1e-15 * 4)
    other = Rotation.from_rotvec(rotvecs(2))
    prod = quat_mul(q, other.as_quat())
    np.testing.assert_allclose(quat_to_rot(prod), (rot * other).as_matrix(), rtol=0, atol=1e-14)
    np.testing.assert_allclose(quat_to_rot(quat_conj(q)), rot.inv().as_matrix(), rtol=0, atol=1e-15 * 4)
    np.testing.assert_allclose(quat_mul(q[3], q[3]), (rot[3] * rot[3]).as_quat(), atol=1e-15 * 4)  # single ones


def test_slerp_against_scipy():
    rng = np.random.default_rng(3)
    a, b = Rotation.random(200, random_state=4), Rotation.random(200, random_state=5)
    s = rng.uniform(0, 1, 200)
    got = quat_to_rot(quat_slerp(a.as_quat(), -b.as_quat(), s))  # the shorter arc whatever the sign
    want = np.stack([Slerp([0, 1], Rotation.concatenate([a[i], b[i]]))(s[i]).as_matrix() for i in range(200)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)
    close = b * Rotation.from_rotvec([1e-10, 0, 0])  # nearly equal ends
    np.testing.assert_allclose(quat_to_rot(quat_slerp(b[0].as_quat(), close[0].as_quat(), 0.5)),
                               (b[0] * Rotation.from_rotvec([5e-11, 0, 0])).as_matrix(), atol=1e-15 * 4)


def test_se3_exp_is_the_matrix_exponential():
    rng = np.random.default_rng(6)
    w = rotvecs(7)
    w = w[np.linalg.norm(w, axis=1) < math.pi - 1e-3]
    xi = np.c_[w, rng.normal(size=(len(w), 3))]  # rotation first
    R, t = se3_exp(xi)
    for i in range(0, len(xi), 7):
        T = np.zeros((4, 4))
        T[:3, :3], T[:3, 3] = hat(xi[i, :3]), xi[i, 3:]
        E = expm(T)
        np.testing.assert_allclose(R[i], E[:3, :3], atol=1e-13)
        np.testing.assert_allclose(t[i], E[:3, 3], atol=1e-12)
    np.testing.assert_allclose(se3_log(R, t), xi, rtol=1e-9, atol=1e-12)


def test_transform_compose_invert():
    rng = np.random.default_rng(8)
    Ra, Rb = Rotation.random(2, random_state=9).as_matrix()
    ta, tb = rng.normal(size=(2, 3))
    P = rng.normal(size=(50, 3))
    np.testing.assert_allclose(transform_points(Ra, ta, P), (Ra @ P.T).T + ta, atol=1e-15 * 8)
    Rc, tc = compose((Ra, ta), (Rb, tb))
    np.testing.assert_allclose(transform_points(Rc, tc, P), transform_points(Ra, ta, transform_points(Rb, tb, P)),
                               atol=1e-13)

    def m4(R, t):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R, t
        return M

    np.testing.assert_allclose(compose(m4(Ra, ta), m4(Rb, tb)), m4(Rc, tc), atol=1e-15 * 8)
    Ri, ti = invert((Ra, ta))
    np.testing.assert_allclose(transform_points(Ri, ti, transform_points(Ra, ta, P)), P, atol=1e-13)
    np.testing.assert_allclose(invert(m4(Ra, ta)), np.linalg.inv(m4(Ra, ta)), atol=1e-14)
    with pytest.raises(ValueError, match="both"):
        compose(m4(Ra, ta), (Rb, tb))


def trajectory(n=40, seed=10):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(1, 20_000, n)).astype(np.int64) + 1_000_000
    return t, rng.normal(size=(n, 3)), Rotation.random(n, random_state=seed).as_quat()


def test_interpolate_poses():
    t, pos, ori = trajectory()
    p, q, ok = interpolate_poses(t, t, pos, ori)  # at the samples: the samples, bit for bit
    assert ok.all() and np.array_equal(p, pos) and np.array_equal(q, ori)
    rng = np.random.default_rng(11)
    tq = rng.integers(t[0], t[-1] + 1, 500)
    p, q, ok = interpolate_poses(tq, t, pos, ori)
    assert ok.all() and np.isfinite(p).all() and np.isfinite(q).all()
    for k in range(3):
        np.testing.assert_allclose(p[:, k], np.interp(tq, t, pos[:, k]), rtol=0, atol=1e-12)
    want = Slerp(t.astype(float), Rotation.from_quat(ori))(tq.astype(float)).as_matrix()
    np.testing.assert_allclose(quat_to_rot(q), want, rtol=0, atol=1e-12)
    p, q, ok = interpolate_poses(np.array([t[0] - 1, t[-1] + 1, t[0], t[-1]]), t, pos, ori)
    assert ok.tolist() == [False, False, True, True]  # never extrapolated
    assert np.isnan(p[:2]).all() and np.isnan(q[:2]).all()
    p, q, ok = interpolate_poses(t[:3], t[:0], pos[:0], ori[:0])
    assert not ok.any()


def test_interpolate_poses_with_repeated_times():
    t, pos, ori = trajectory(5)
    t[2] = t[1]
    p, q, ok = interpolate_poses(np.array([t[1], (t[1] + t[3]) // 2]), t, pos, ori)
    assert ok.all() and np.array_equal(p[0], pos[2])  # the last sample of a repeated time
    np.testing.assert_allclose(p[1], pos[2] + ((t[1] + t[3]) // 2 - t[2]) / (t[3] - t[2]) * (pos[3] - pos[2]))


# -- calibration files ---------------------------------------------------------------------
def ros_yaml(model, D, extra=""):
    def mat(name, rows, cols, data):
        return f"{name}:\n  rows: {rows}\n  cols: {cols}\n  data: [{', '.join(map(str, np.ravel(data)))}]\n"

    return ("image_width: 346\nimage_height: 260\ncamera_name: dvxplorer\n" + mat("camera_matrix", 3, 3, K)
            + f"distortion_model: {model}\n" + mat("distortion_coefficients", 1, len(D), D)
            + mat("rectification_matrix", 3, 3, np.eye(3)) + mat("projection_matrix", 3, 4, np.c_[K, np.zeros(3)])
            + extra)


@pytest.mark.parametrize("name", ["equidistant", "fisheye"])
def test_ros_camera_info_equidistant(tmp_path, name):
    f = tmp_path / "cam.yaml"
    f.write_text(ros_yaml(name, FISHEYE))
    cam = read_calibration(f)
    assert cam.model == "equidistant" and cam.size == (346, 260) and np.array_equal(cam.D, FISHEYE)
    P = points(100, 1.2)
    np.testing.assert_allclose(cam.project(P), opencv_project(cam, P), atol=1e-6)
    f.write_text(ros_yaml("plumb_bob", RADTAN[5]))
    assert read_calibration(f).model == "radtan"


def test_ros_message_layouts(tmp_path):
    """camera_info as the message prints it: flat K D R P, lower case in ROS 2."""
    flat = lambda a: "[" + ", ".join(map(str, np.ravel(a))) + "]"  # noqa: E731
    R = cv2.Rodrigues(np.array([0.0, 0.01, 0.0]))[0]
    for k, d, r, p in (("K", "D", "R", "P"), ("k", "d", "r", "p")):
        f = tmp_path / f"info_{k}.yaml"
        f.write_text(f"height: 260\nwidth: 346\ndistortion_model: equidistant\n{d}: {flat(FISHEYE)}\n{k}: {flat(K)}\n"
                     f"{r}: {flat(R)}\n{p}: {flat(np.c_[K, np.zeros(3)])}\n")
        cam = read_calibration(f)
        assert cam.model == "equidistant" and cam.size == SENSOR and np.allclose(cam.K, K) and np.allclose(cam.R, R)
        assert cam.P is not None and cam.P.shape == (3, 4)


def test_opencv_fisheye_files(tmp_path):
    y = tmp_path / "out_camera_data.yml"
    fs = cv2.FileStorage(str(y), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 346)
    fs.write("image_height", 260)
    fs.write("fisheye_model", 1)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array(FISHEYE).reshape(4, 1))
    fs.release()
    assert read_calibration(y).model == "equidistant"
    js = tmp_path / "cam.json"
    js.write_text(json.dumps({"K": K.tolist(), "D": FISHEYE, "distortion_model": "equidistant"}))
    assert read_calibration(js).model == "equidistant"
    js.write_text(json.dumps({"K": K.tolist(), "D": FISHEYE, "distortion_model": "omni"}))
    with pytest.raises(FormatError, match="cam.json: unknown distortion_model 'omni'"):
        read_calibration(js)


def test_fisheye_stereo_rectification_from_R_T(tmp_path):
    f = tmp_path / "stereo.yml"
    fs = cv2.FileStorage(str(f), cv2.FILE_STORAGE_WRITE)
    R, T = cv2.Rodrigues(np.array([0.0, 0.05, 0.01]))[0], np.array([[-0.1], [0.0], [0.0]])
    D = np.array(FISHEYE).reshape(4, 1)
    for k, v in {"M1": K, "D1": D, "M2": K, "D2": D, "R": R, "T": T}.items():
        fs.write(k, v)
    fs.write("distortion_model", "equidistant")
    fs.write("image_width", 346)
    fs.write("image_height", 260)
    fs.release()
    right = read_calibration(f, "right")
    R1, R2, P1, P2, _ = cv2.fisheye.stereoRectify(K, D, K, D, SENSOR, R, T, cv2.CALIB_ZERO_DISPARITY)
    assert right.model == "equidistant" and np.allclose(right.R, R2) and np.allclose(right.P, P2)


# -- bad input ----------------------------------------------------------------------------
def test_bad_calibrations(tmp_path):
    txt = tmp_path / "calib.txt"
    txt.write_text("199.0 198.8 132.2 110.7 -0.37 0.15 -0.0003 -0.0008\n")
    with pytest.raises(FormatError, match=r"calib.txt: expected 9 numbers 'fx fy cx cy k1 k2 p1 p2 k3', found 8"):
        read_uzh_calib(txt)
    txt.write_text("0.0 198.8 132.2 110.7 -0.37 0.15 -0.0003 -0.0008 0.0\n")
    with pytest.raises(FormatError, match=r"calib.txt: camera: focal lengths must be positive, got fx=0"):
        read_calibration(txt)
    with pytest.raises(ValueError, match=r"fx=0, fy=310"):
        Camera(np.array([[0.0, 0, 170], [0, 310, 130], [0, 0, 1]]), [])
    with pytest.raises(ValueError, match="no skew"):
        Camera(np.array([[300.0, 0.5, 170], [0, 310, 130], [0, 0, 1]]), [])
    with pytest.raises(ValueError, match="NaN"):
        Camera(K, [np.nan, 0, 0, 0])
    with pytest.raises(ValueError, match="5 distortion coefficients; the equidistant model takes 4"):
        Camera(K, RADTAN[5], model="equidistant")
    with pytest.raises(ValueError, match="unknown distortion model 'omni'"):
        Camera(K, [], model="omni")  # type: ignore[arg-type]


def test_bad_rotations():
    with pytest.raises(ValueError, match=r"quaternion 1 .* has norm 2, not 1"):
        quat_to_rot(np.array([[0, 0, 0, 1.0], [0, 0, 0, 2.0]]))
    with pytest.raises(ValueError, match="quat_slerp q1: not finite .* at index 0"):
        quat_slerp([0, 0, 0, 1.0], [np.nan, 0, 0, 1.0], 0.5)
    t, pos, ori = trajectory(4)
    ori[2] *= 1.01
    with pytest.raises(ValueError, match="interpolate_poses orientation: quaternion 2"):
        interpolate_poses(t, t, pos, ori)
    with pytest.raises(ValueError, match=r"times go back at index 2"):
        interpolate_poses(t, t[[0, 2, 1, 3]], pos, trajectory(4)[2])
    with pytest.raises(ValueError, match="integer µs"):
        interpolate_poses(t.astype(float), t, pos, trajectory(4)[2])
    with pytest.raises(ValueError, match="not a rotation"):
        so3_log(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match=r"expected shape \(3\) or \(N, 3\)"):
        so3_exp(np.zeros(4))


def test_imports_no_plugin_source_or_sink():
    code = ("import sys, tectum.camera; print(sorted(m for m in sys.modules "
            "if m.startswith(('tectum.plugins', 'tectum.sources', 'tectum.sinks'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
    assert tectum.camera.Camera is Camera


def test_camera_from_takes_inline_intrinsics_or_a_file(tmp_path):
    from tectum.camera import camera_from

    cam = camera_from("200;201;120.5;90;0.1;-0.02;0.001;0.002")
    assert np.allclose(cam.K, [[200, 0, 120.5], [0, 201, 90], [0, 0, 1]])
    assert np.allclose(cam.D[:4], [0.1, -0.02, 0.001, 0.002])
    f = tmp_path / "calib.txt"
    f.write_text("200 201 120.5 90 0.1 -0.02 0.001 0.002 0\n")
    assert np.allclose(camera_from(str(f)).K, cam.K)
    with pytest.raises(ValueError, match="calib="):
        camera_from("")
    for bad in ("207.85;nan", "200;201;120;x", str(tmp_path / "absent.yaml")):
        with pytest.raises(ValueError, match="neither a calibration file nor inline intrinsics"):
            camera_from(bad)


def test_depth_points_are_the_known_pixels_back_projected_into_the_world() -> None:
    """A depth map's known pixels (finite and above 0) as world points, in
    row-major order, against :meth:`Camera.back_project` and the pose."""
    from tectum.camera import Camera, depth_points, so3_exp

    K = np.array([[120.0, 0.0, 31.5], [0.0, 110.0, 22.5], [0.0, 0.0, 1.0]])
    depth = np.random.default_rng(2).uniform(0.5, 4.0, (45, 64))
    depth[3, 5], depth[10, 7], depth[20, 30] = np.nan, 0.0, -1.0  # unknown, and no depth
    R, t = so3_exp(np.array([0.1, -0.2, 0.3])), np.array([0.5, -1.0, 2.0])
    pts, v, u = depth_points(depth, K, R, t)
    known = np.isfinite(depth) & (depth > 0)
    assert len(pts) == known.sum() == depth.size - 3
    assert np.array_equal(np.ravel_multi_index((v, u), depth.shape), np.flatnonzero(known))
    cam = Camera(K, np.zeros(0))
    expect = cam.back_project(np.column_stack([u, v]).astype(np.float64), depth[v, u]) @ R.T + t
    np.testing.assert_allclose(pts, expect, rtol=0, atol=1e-12)


# -- the gyro ----------------------------------------------------------------------------------------------------
def test_gyro_turn_is_the_held_rates_product_and_ignores_older_samples():
    """A constant rate gives exp(ω T); a varying one the product of the held
    steps in time order, bit for bit the same whatever older samples are
    kept, and the same turn as :func:`gyro_rotations` gives."""
    from tectum.camera import gyro_rotations, gyro_turn, rotation_matrix

    w = np.array([0.3, -0.5, 0.2])
    kt = np.arange(0, 10_001, 1000, dtype=np.int64)
    np.testing.assert_allclose(gyro_turn(kt, np.tile(w, (len(kt), 1)), 1500, 8200), so3_exp(w * 6.7e-3), atol=1e-12)
    rng = np.random.default_rng(0)
    kw = rng.normal(0, 1.0, (len(kt), 3))
    want = so3_exp(kw[1] * 0.5e-3) @ so3_exp(kw[2] * 1e-3) @ so3_exp(kw[3] * 0.2e-3)
    np.testing.assert_allclose(gyro_turn(kt, kw, 1500, 3200), want, atol=1e-12)
    np.testing.assert_array_equal(gyro_turn(kt[1:], kw[1:], 1500, 3200), gyro_turn(kt, kw, 1500, 3200))
    R = gyro_rotations(np.array([1500], np.int64), kt, kw, 3200)[0]  # camera at 3200 from camera at 1500
    np.testing.assert_allclose(R.T, gyro_turn(kt, kw, 1500, 3200), atol=1e-12)
    np.testing.assert_array_equal(gyro_turn(kt, kw, 4000, 4000), np.eye(3))
    np.testing.assert_allclose(rotation_matrix((0.0, np.pi, 0.0)), np.diag([-1.0, 1.0, -1.0]), atol=1e-12)
    with pytest.raises(ValueError, match="imu_rotation as 9 numbers must be a rotation"):
        rotation_matrix(np.ones(9), "imu_rotation")
