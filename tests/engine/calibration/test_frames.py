"""Checkerboards in frames (APS frames, reconstructions) and on blinking screens."""

from __future__ import annotations

import numpy as np
import pytest
from calibration_recordings import CAMERA, record

import tectum
from tectum import FramePacket
from tectum.calibration import CalibrationError, calibrate_frames
from tectum.sources.simulate.blink_board import Board, _sample_rays, board_poses, coverage_kernel

CHECKER = Board(7, 5, 0.025, 0.0, checker=True)  # 7x5 inner corners, 2.5 cm squares


def frames_of(board: Board, views: int, seed: int) -> FramePacket:
    """Grey images of a printed checkerboard seen through the true lens, 100 ms apart."""
    R, t = board_poses(CAMERA, board, views, seed=seed, tilt_deg=40, margin_px=8)
    rays = _sample_rays(CAMERA, 4)
    images = []
    for Rk, tk in zip(R, t, strict=True):
        cb, cd = np.zeros((96, 128)), np.zeros((96, 128))
        coverage_kernel(rays, Rk, tk, board.cols, board.rows, board.spacing, 0.0, board.kind,
                        np.array(board.extent()), cb, cd)
        images.append(0.1 + 0.3 * cb + 0.5 * cd)  # dark room, grey board, white squares
    return FramePacket(np.arange(views, dtype=np.int64) * 100_000, images=np.array(images))


def test_checkerboard_frames_recover_the_camera() -> None:
    cal = calibrate_frames(frames_of(CHECKER, 12, seed=21), (7, 5), 0.025)
    c = cal.camera
    assert abs(c.fx / CAMERA.fx - 1) < 0.01 and abs(c.fy / CAMERA.fy - 1) < 0.01
    assert abs(c.cx - CAMERA.cx) < 1.5 and abs(c.cy - CAMERA.cy) < 1.5
    assert abs(c.D[0] - CAMERA.D[0]) < 0.02 and cal.rms < 0.3


def test_frames_without_the_board_say_so() -> None:
    blank = FramePacket(np.arange(8, dtype=np.int64) * 100_000, images=np.full((8, 96, 128), 0.5))
    with pytest.raises(CalibrationError, match=r"8 frames, 8 looked at .* 0 with the whole 7x5 checkerboard"):
        calibrate_frames(blank, (7, 5), 0.025)


def test_blinking_checker_screen() -> None:
    """Corners of a blinking checkerboard's transition map: 0.2 px off on
    average on this small sensor (dots: 0.05 px), so looser bounds."""
    rec = record(CHECKER, 8, seed=22)
    cal = tectum.calibrate(rec.events, (7, 5), 0.025, pattern="checker", min_views=5)
    c = cal.camera
    assert abs(c.fx / CAMERA.fx - 1) < 0.03 and abs(c.cx - CAMERA.cx) < 2 and abs(c.cy - CAMERA.cy) < 2
    assert cal.rms < 0.4 and len(cal.used) >= 5


def test_reconstruct_gives_frames_from_events() -> None:
    """``--reconstruct-us``: map.high_pass images every 20 ms, as frames."""
    from tectum.calibration._frames import reconstruct

    rec = record(Board(), 1, seed=23, still_us=60_000)
    frames = reconstruct(rec.events, 20_000)
    assert frames.images.shape == (3, 96, 128) and list(frames.t) == [19_999, 39_999, 59_999]  # at each window's last µs
    lit = frames.images[-1][np.isfinite(frames.images[-1])]
    assert lit.size > 0 and np.ptp(lit) > 0  # the dots show
