"""The solver on exact projections: it recovers the camera, drops a view
that does not fit, and reports per-view RMS as OpenCV defines it."""

from __future__ import annotations

import numpy as np
from calibration_recordings import CAMERA

from tectum.calibration import Grid
from tectum.calibration._solve import solve_mono
from tectum.sources.simulate.blink_board import Board, board_poses


def test_outlier_view_is_dropped_and_the_rest_fit() -> None:
    board, grid = Board(), Grid(7, 5, 0.03)
    R, t = board_poses(CAMERA, board, 10, seed=31, tilt_deg=40)
    rng = np.random.default_rng(0)
    obj = grid.object_points().astype(np.float64)
    views = [CAMERA.project(obj @ Rk.T + tk) + 0.05 * rng.standard_normal((35, 2)) for Rk, tk in zip(R, t)]
    views[4] = views[4] + rng.normal(0, 1.5, (35, 2))  # a view whose dots were found badly
    sol = solve_mono(obj, views, (128, 96))
    assert 4 not in sol.used and len(sol.used) == 9
    assert abs(sol.camera.fx / CAMERA.fx - 1) < 0.006 and abs(sol.camera.D[0] - CAMERA.D[0]) < 0.005
    assert sol.view_rms[4] > 1.0 and np.all(np.delete(sol.view_rms, 4) < 0.1)
    for k in sol.used:  # RMS: sqrt of the mean squared 2-D distance over the view's points
        assert sol.view_rms[k] == np.sqrt(np.mean(np.sum(sol.residuals[k] ** 2, axis=1)))
    expect = np.sqrt(np.mean(np.concatenate([np.sum(sol.residuals[k] ** 2, axis=1) for k in sol.used])))
    assert abs(sol.rms - expect) < 1e-12
