"""The rotation truth of any pixel (``feature_scenes.rotation_tracks``)
against the simulator's own feature truth (world points projected at each
pose), and the DAVIS rotation scene's streams."""

from __future__ import annotations

import numpy as np

from tectum.sources.simulate import simulate
from tectum.sources.simulate.feature_scenes import davis_rotation, davis_rotation_scene, rotation_tracks


def test_rotation_tracks_match_the_simulators_feature_positions():
    scene = davis_rotation_scene((64, 48), aps_rate_hz=0.0)
    del scene["davis"]
    # world points in front of the camera at several depths (rotation only: depth does not matter)
    scene["features"] = [[0.1, -0.05, 1.0], [-0.4, 0.2, 3.0], [0.02, 0.1, 10.0]]
    _, truth = simulate(scene, 60_000, sensor=(64, 48))
    ft, fxy = np.asarray(truth["feature_t"]), np.asarray(truth["feature_xy"])
    n = len(ft)
    for f in range(3):
        got = rotation_tracks(truth, np.full(n, float(ft[0])), np.tile(fxy[0, f], (n, 1)), ft.astype(np.float64))
        assert np.allclose(got, fxy[:, f], atol=1e-6), f
    moved = np.linalg.norm(fxy[-1, :3] - fxy[0, :3], axis=1)
    assert moved.min() > 2.0  # the check is not about points standing still


def test_davis_rotation_gives_events_frames_and_poses():
    ev, frames, truth = davis_rotation((48, 36), 60_000, aps_rate_hz=50.0)
    assert ev.sensor == (48, 36) and len(ev) > 1000
    assert frames.images.shape[1:] == (36, 48) and len(frames) == 3
    assert np.all(np.diff(np.asarray(truth["pose_t"])) > 0)
    outside = rotation_tracks(truth, np.array([-1.0]), np.array([[10.0, 10.0]]), np.array([0.0]))
    assert np.isnan(outside).all()  # before the poses: unknown, not invented
