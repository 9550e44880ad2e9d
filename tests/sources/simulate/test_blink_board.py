"""The blinking-board simulator: rendering through the lens, events where the
dots are, noise at the asked rate."""

from __future__ import annotations

import numpy as np
import pytest

from tectum.camera import Camera
from tectum.sources.simulate.blink_board import Board, board_poses, coverage_kernel, simulate_board

PINHOLE = Camera(np.array([[100.0, 0, 40.0], [0, 100.0, 30.0], [0, 0, 1]]), np.zeros(4), (80, 60))
LENS = Camera(PINHOLE.K, np.array([-0.35, 0.12, 0.0, 0.0]), (80, 60))


def coverage(camera: Camera, board: Board, R: np.ndarray, t: np.ndarray, s: int = 8) -> tuple[np.ndarray, ...]:
    from tectum.sources.simulate.blink_board import _sample_rays

    cb, cd = np.zeros((60, 80)), np.zeros((60, 80))
    coverage_kernel(_sample_rays(camera, s), R, t, board.cols, board.rows, board.spacing, board.radius, board.kind,
                    np.array(board.extent()), cb, cd)
    return cb, cd


def test_fronto_parallel_dots_have_the_pinhole_area_and_centre() -> None:
    board = Board(3, 2, 0.05, 0.01)
    t = np.array([-0.05, -0.025, 0.5])
    _, cd = coverage(PINHOLE, board, np.eye(3), t)
    r_px = 0.01 * 100 / 0.5
    assert cd.sum() == pytest.approx(6 * np.pi * r_px ** 2, rel=0.02)
    centres = PINHOLE.project(board.object_points() + t)
    vv, uu = np.indices(cd.shape)
    for cx, cy in centres:
        m = np.where((uu - cx) ** 2 + (vv - cy) ** 2 < (2 * r_px) ** 2, cd, 0)
        assert (m * uu).sum() / m.sum() == pytest.approx(cx, abs=0.02)
        assert (m * vv).sum() / m.sum() == pytest.approx(cy, abs=0.02)


def test_through_the_lens_a_dot_lands_where_the_camera_projects_it() -> None:
    board = Board(2, 2, 0.14, 0.004)
    t = np.array([-0.07, -0.07, 0.25])
    _, cd = coverage(LENS, board, np.eye(3), t)
    vv, uu = np.indices(cd.shape)
    for cx, cy in LENS.project(board.object_points() + t):
        m = np.where((uu - cx) ** 2 + (vv - cy) ** 2 < 16, cd, 0)
        # within 0.1 px (the lens bends the disk's image, so its centroid is not exactly its centre's
        # image); the pinhole puts it more than 1 px away
        assert (m * uu).sum() / m.sum() == pytest.approx(cx, abs=0.1)
        assert (m * vv).sum() / m.sum() == pytest.approx(cy, abs=0.1)
    assert np.abs(PINHOLE.project(board.object_points() + t) - LENS.project(board.object_points() + t)).min() > 1


def test_events_blink_at_the_dots_and_noise_comes_at_its_rate() -> None:
    board = Board(3, 2, 0.03, 0.008)
    R, t = board_poses(LENS, board, 2, seed=0)
    ev, truth = simulate_board(LENS, board, R, t, blink_hz=500, still_us=40_000, move_us=20_000)
    assert truth.spans.tolist() == [[0, 40_000], [60_000, 100_000]]
    first = ev.slice_time(0, 40_000)
    near = np.linalg.norm(np.column_stack([first.x, first.y])[:, None] - truth.pixels[0][None], axis=2).min(axis=1)
    assert len(first) > 1000 and np.all(near < 4)  # nothing but the dots fires while the board is still
    assert np.all(first.p[first.t % 2000 < 500] > 0) and np.all(first.p[first.t % 2000 >= 1000] < 0)
    noisy, _ = simulate_board(LENS, board, R, t, blink_hz=500, still_us=40_000, move_us=20_000, noise_hz=50.0)
    extra = len(noisy) - len(ev)
    assert extra == pytest.approx(50.0 * 0.1 * 80 * 60, rel=0.1)


def test_board_poses_keep_the_board_in_view() -> None:
    board = Board()
    R, t = board_poses(LENS, board, 5, seed=1, tilt_deg=30)
    for Rk, tk in zip(R, t, strict=True):
        px = LENS.project(board.object_points() @ Rk.T + tk)
        assert np.all((px > 4) & (px < np.array([75, 55])))
    with pytest.raises(ValueError, match="keep the whole board in view"):
        board_poses(LENS, board, 2, distance=0.05)
