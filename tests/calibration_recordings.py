"""Simulated recordings of blinking boards for the calibration tests (small
sensors, short views), and a writer of events to a file."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tectum import EventPacket, Pipeline, run
from tectum.camera import Camera
from tectum.sources.simulate.blink_board import Board, BoardTruth, board_poses, simulate_board
from tectum.testing import ListSource

W, H = 128, 96
#: The true camera: strong barrel distortion (k1 -0.3), principal point off centre.
CAMERA = Camera(np.array([[106.0, 0, 65.3], [0, 106.5, 46.7], [0, 0, 1]]), np.array([-0.3, 0.1, 0.001, -0.001]),
                (W, H))


@dataclass
class Recording:
    events: EventPacket
    truth: BoardTruth


def record(board: Board, views: int = 8, *, camera: Camera = CAMERA, seed: int = 1, tilt_deg: float = 40.0,
           R: np.ndarray | None = None, t: np.ndarray | None = None, **kw: object) -> Recording:
    """A recording of ``board`` in ``views`` random poses (or ``R``, ``t``)."""
    if R is None or t is None:
        R, t = board_poses(camera, board, views, seed=seed, tilt_deg=tilt_deg)
    kw = {"still_us": 100_000, "move_us": 40_000, "seed": seed, **kw}
    ev, truth = simulate_board(camera, board, R, t, **kw)  # type: ignore[arg-type]
    return Recording(ev, truth)


def write_events(events: EventPacket, path: Path) -> Path:
    """``events`` to a file, as a user's recording."""
    p = Pipeline()
    p.source(ListSource([events]), id="src")
    p.sink(str(path), "src")
    run(p)
    return path
