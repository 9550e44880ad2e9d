"""Circle-grid ordering: OpenCV's order on distorted, tilted, shuffled
views; partial boards and larger boards never ordered."""

from __future__ import annotations

import numpy as np
import pytest
from calibration_recordings import CAMERA

from tectum.calibration import Grid, order_grid
from tectum.sources.simulate.blink_board import Board, board_poses


def projected(board: Board, seed: int, n: int = 6) -> list[np.ndarray]:
    R, t = board_poses(CAMERA, board, n, seed=seed, tilt_deg=40)
    return [CAMERA.project(board.object_points() @ Rk.T + tk) for Rk, tk in zip(R, t, strict=True)]


@pytest.mark.parametrize("asymmetric", [False, True])
def test_orders_shuffled_views_like_opencv(asymmetric) -> None:
    board = Board(4, 7, 0.015, 0.004, asymmetric=True) if asymmetric else Board(7, 5)
    grid = Grid(board.cols, board.rows, board.spacing, asymmetric)
    np.testing.assert_allclose(grid.object_points(), board.object_points(), atol=1e-7)
    rng = np.random.default_rng(0)
    for truth in projected(board, seed=1):
        got = order_grid(truth[rng.permutation(len(truth))], grid)
        assert got is not None
        if not asymmetric and not np.allclose(got, truth):  # a symmetric grid: either end may come first
            truth = truth[::-1]
        np.testing.assert_allclose(got, truth)


def test_symmetric_order_starts_top_left() -> None:
    grid = Grid(7, 5, 0.03)
    for truth in projected(Board(), seed=2):
        got = order_grid(truth[::-1], grid)
        assert got is not None and got[0].sum() < got[-1].sum()


def test_partial_and_larger_boards_are_not_ordered() -> None:
    grid = Grid(7, 5, 0.03)
    truth = projected(Board(), seed=3, n=1)[0]
    assert order_grid(truth[:-1], grid) is None  # a dot out of view
    assert order_grid(truth[truth[:, 0] < np.median(truth[:, 0])], grid) is None  # half the board
    assert order_grid(truth, Grid(6, 5, 0.03)) is None  # a 6x5 grid is inside, but the board goes on
    assert order_grid(truth, Grid(7, 4, 0.03)) is None
    rng = np.random.default_rng(1)
    noisy = np.vstack([truth, rng.uniform([0, 0], [128, 96], (1, 2)) + [500, 500]])  # a stray blob far away
    assert order_grid(noisy, grid) is not None


def test_grid_rejects_nonsense() -> None:
    with pytest.raises(ValueError, match="at least 2x2"):
        Grid(1, 5, 0.03)
    with pytest.raises(ValueError, match="spacing must be > 0"):
        Grid(7, 5, 0.0)
