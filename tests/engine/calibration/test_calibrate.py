"""``tectum.calibrate`` against the simulator's truth: intrinsics, distortion,
views, asymmetric grids, fisheye, stereo extrinsics, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from calibration_recordings import CAMERA, Recording, record

import tectum
from tectum.calibration import CalibrationError, calibrate_stereo, write_stereo
from tectum.camera import Camera, read_calibration, so3_exp
from tectum.sources.simulate.blink_board import Board, board_poses


def assert_close_to_truth(cam: Camera, truth: Camera, focal: float = 0.01, pp_px: float = 1.5,
                          k1: float = 0.01) -> None:
    assert abs(cam.fx / truth.fx - 1) < focal and abs(cam.fy / truth.fy - 1) < focal, (cam.K, truth.K)
    assert abs(cam.cx - truth.cx) < pp_px and abs(cam.cy - truth.cy) < pp_px, (cam.K, truth.K)
    assert abs(cam.D[0] - truth.D[0]) < k1, (cam.D, truth.D)


def test_recovers_the_simulated_camera(dots: Recording) -> None:
    cal = tectum.calibrate(dots.events, (7, 5), 0.03)
    assert_close_to_truth(cal.camera, CAMERA)
    assert cal.camera.size == (128, 96) and cal.camera.model == "radtan"
    assert abs(cal.blink_hz - 250.0) < 1.0  # found from the events
    assert len(cal.views) == 8 and all(v.status == "used" for v in cal.views)
    assert cal.rms < 0.2 and all(v.rms < 0.2 for v in cal.views)


def test_views_match_the_truth(dots: Recording) -> None:
    """Each view lies within its true still span, and its ordered dots are the
    true projections (up to the 180° turn a symmetric grid cannot tell)."""
    cal = tectum.calibrate(dots.events, "7x5", 0.03, frequency_hz=250)
    for v, (t0, t1), px in zip(cal.views, dots.truth.spans, dots.truth.pixels, strict=True):
        assert t0 <= v.t_start < v.t_end <= t1
        assert v.points is not None
        err = min(np.abs(v.points - px).max(), np.abs(v.points[::-1] - px).max())
        assert err < 0.35


def test_asymmetric_grid() -> None:
    rec = record(Board(4, 7, 0.015, 0.0045, asymmetric=True), 8, seed=3)
    cal = tectum.calibrate(rec.events, (4, 7), 0.015, asymmetric=True)
    assert_close_to_truth(cal.camera, CAMERA)
    for v, px in zip(cal.views, rec.truth.pixels, strict=True):  # asymmetric: no ambiguity of order
        assert v.points is not None and np.abs(v.points - px).max() < 0.35


def test_fisheye_model() -> None:
    fisheye = Camera(np.array([[70.0, 0, 63.7], [0, 70.0, 48.2], [0, 0, 1]]), np.array([0.05, -0.02, 0.01, 0.0]),
                     (128, 96), model="equidistant")
    rec = record(Board(), 8, camera=fisheye, seed=4)
    cal = tectum.calibrate(rec.events, (7, 5), 0.03, model="equidistant")
    assert cal.camera.model == "equidistant"
    assert_close_to_truth(cal.camera, fisheye, k1=0.03)
    assert cal.rms < 0.2


def test_flicker_and_timestamp_jitter() -> None:
    rec = record(Board(), 6, seed=5, flicker_hz=100.0, jitter_us=30.0)
    cal = tectum.calibrate(rec.events, (7, 5), 0.03, frequency_hz=250, min_views=5)
    assert_close_to_truth(cal.camera, CAMERA, pp_px=2.0)


def test_stereo_extrinsics_and_rectification(tmp_path) -> None:
    board = Board()
    right_cam = Camera(np.array([[104.0, 0, 62.1], [0, 104.2, 49.0], [0, 0, 1]]),
                       np.array([-0.25, 0.07, 0.0, 0.001]), (128, 96))
    R_rl = so3_exp(np.array([0.0, -0.05, 0.01]))  # x_right = R_rl x_left + T_rl
    T_rl = np.array([-0.06, 0.002, 0.001])
    R, t = board_poses(CAMERA, board, 30, seed=6, tilt_deg=35)
    Rr, tr = np.einsum("ij,njk->nik", R_rl, R), t @ R_rl.T + T_rl
    obj = board.object_points()
    inside = [k for k in range(len(R)) if np.all(np.isfinite(px := right_cam.project(obj @ Rr[k].T + tr[k])))
              and np.all((px > 4) & (px < np.array([123, 91])))][:7]
    left = record(board, camera=CAMERA, R=R[inside], t=t[inside], seed=7)
    right = record(board, camera=right_cam, R=Rr[inside], t=tr[inside], seed=8)
    st = calibrate_stereo(left.events, right.events, (7, 5), 0.03)
    s = st.stereo
    assert s.pairs == len(inside)
    assert np.abs(s.T - T_rl).max() < 0.002, s.T
    assert np.degrees(np.abs(s.R - R_rl).max()) < 0.3
    path = write_stereo(tmp_path / "stereo.yaml", s.left, s.right, s.R, s.T, s.R1, s.R2, s.P1, s.P2, rms=s.rms)
    cl, cr = read_calibration(path, "left"), read_calibration(path, "right")
    # rectified: a dot's two images lie on one row
    yl = cl.undistort_points(left.truth.pixels[0], P=cl.P, R=cl.R)[:, 1]
    yr = cr.undistort_points(right.truth.pixels[0], P=cr.P, R=cr.R)[:, 1]
    assert np.abs(yl - yr).max() < 0.3


# -- bad input: one message with counts, nothing invented ------------------------------------------
def test_too_few_views(dots: Recording) -> None:
    with pytest.raises(CalibrationError, match=r"8 still views found at 250\.0 Hz, 8 with the whole 7x5 grid; "
                                               r"need at least 12 views"):
        tectum.calibrate(dots.events, (7, 5), 0.03, frequency_hz=250, min_views=12)


def test_wrong_grid_says_the_dots_did_not_form_it(dots: Recording) -> None:
    with pytest.raises(CalibrationError, match=r"0 with the whole 6x5 grid.*8 where the dots did not form the grid"):
        tectum.calibrate(dots.events, (6, 5), 0.03, frequency_hz=250)


def test_board_never_fully_seen() -> None:
    """The board half out of view in every pose: views are found, counted as
    partial with the dots seen, never ordered."""
    board = Board()
    R, t = board_poses(CAMERA, board, 3, seed=9, tilt_deg=10)
    t = t + np.array([0.12, 0.0, 0.0])  # shifted right: part of the board leaves the image
    rec = record(board, R=R, t=t, seed=9)
    with pytest.raises(CalibrationError, match=r"3 still views found .* 0 with the whole 7x5 grid, 3 partial "
                                               r"\(dots seen: \d+, \d+, \d+ of 35\)"):
        tectum.calibrate(rec.events, (7, 5), 0.03, frequency_hz=250)


def test_no_blinking() -> None:
    rng = np.random.default_rng(0)
    n = 20_000
    ev = tectum.EventPacket.from_arrays(np.sort(rng.integers(0, 1_000_000, n)), rng.integers(0, 128, n),
                                        rng.integers(0, 96, n), np.where(rng.random(n) < 0.5, 1, -1),
                                        sensor=(128, 96))
    with pytest.raises(CalibrationError, match=r"no blinking found at 250\.0 Hz: 0 still views"):
        tectum.calibrate(ev, (7, 5), 0.03, frequency_hz=250)
    with pytest.raises(CalibrationError, match="no blinking found"):
        tectum.calibrate(ev.select(ev.p < 0), (7, 5), 0.03)  # no ON events: no period to find


def test_blinking_that_never_holds_still() -> None:
    """Dots that blink at 250 Hz but jump every 20 ms: blinking is found, no still view."""
    ts, xs, ys, ps = [], [], [], []
    for k in range(250):  # 1 s
        t0 = k * 4000
        shift = 3 * (t0 // 20_000) % 90
        for x in range(10 + shift, 14 + shift):
            for y in range(40, 44):
                ts += [t0, t0 + 2000]
                xs += [x, x]
                ys += [y, y]
                ps += [1, -1]
    order = np.argsort(ts, kind="stable")
    ev = tectum.EventPacket.from_arrays(np.array(ts)[order], np.array(xs)[order], np.array(ys)[order],
                                        np.array(ps)[order], sensor=(128, 96))
    with pytest.raises(CalibrationError, match=r"0 still views at 250\.0 Hz: \d+ pixels blink, but the pattern "
                                               r"never held still for 20 periods"):
        tectum.calibrate(ev, (7, 5), 0.03)
