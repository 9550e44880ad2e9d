"""The photometric-loop measurement (docs/evo.md, "The photometric loop"):
the photometric map made of the last frame before the map (the geometry,
:mod:`tectum.plugins.map.photometric`'s, is tested with it)."""

from __future__ import annotations

from typing import Any

import numpy as np

from tectum import FramePacket, MapPacket, PosePacket
from tectum.evaluation.suites._pose_evo_photo import Run, photo_map

from helpers import SMALL_H as H
from helpers import SMALL_K as K
from helpers import SMALL_W as W
from helpers import small_plane as _plane


def _run() -> Run:
    """Frames at 10, 50, 90 ms (exposure 5 ms), the camera moving along x at 1 m/s."""
    t = np.array([10_000, 50_000, 90_000], np.int64)
    imgs = np.stack([np.full((H, W), v, np.uint8) for v in (10, 100, 200)])
    frames = FramePacket(t, images=imgs, exposure_start=t - 2500, exposure_end=t + 2500, t_start=0, t_end=100_000)
    return Run(events=None, truth=None, frames=frames, sim=None, K=K, eps=1e-3)  # type: ignore[arg-type]


def _poses() -> PosePacket:
    t = np.arange(0, 100_001, 1000, dtype=np.int64)
    pos = np.stack([t * 1e-6, 0 * t, 0 * t], axis=1).astype(np.float64)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    return PosePacket(t, position=pos, orientation=quat, t_start=0, t_end=100_001)


def _emvs_map(t_map: int, t_ref: int, **extra: Any) -> MapPacket:
    pose = np.array([t_ref * 1e-6, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    return MapPacket(np.array([t_map], np.int64), depth=_plane()[None], confidence=np.ones((1, H, W)), K=K[None],
                     pose=pose[None], t_ref=np.array([t_ref], np.int64), t_start=t_map, t_end=t_map + 1, **extra)


def test_photo_map_takes_the_last_frame_exposed_before_the_map() -> None:
    run, poses = _run(), _poses()
    # made at 92.4 ms: the 90 ms frame's exposure ends at 92.5 ms, so the 50 ms frame is the last whole one
    m = photo_map(_emvs_map(92_400, 20_000), 0, run, poses, median_px=0)
    assert m is not None
    assert np.allclose(m.data["image"][0], np.log(100 / 255 + 1e-3))
    assert np.allclose(m.data["pose"][0], [0.05, 0, 0, 0, 0, 0, 1])  # the pose at the frame's time
    # the plane seen from 30 mm further right: its pixels 50 * 0.03 / 2 = 0.75 px left, rounded to 1
    assert np.isnan(m.data["depth"][0][:, -1]).all() and np.allclose(m.data["depth"][0][:, :-1], 2.0)
    at = photo_map(_emvs_map(92_500, 20_000), 0, run, poses, median_px=0)
    assert at is not None and np.allclose(at.data["pose"][0][:3], [0.09, 0, 0])
    ref = photo_map(_emvs_map(92_400, 20_000), 0, run, poses, frame="ref", median_px=0)
    assert ref is not None and np.allclose(ref.data["pose"][0][:3], [0.01, 0, 0])  # nearest the map's view


def test_photo_map_needs_a_pose_at_the_frame() -> None:
    run, poses = _run(), _poses()
    late = poses.slice_time(60_000, 100_001)
    assert photo_map(_emvs_map(70_000, 20_000), 0, run, late) is None  # the 50 ms frame is before the poses
    assert photo_map(_emvs_map(5_000, 0), 0, run, poses) is None  # no frame exposed yet


def test_the_pipeline_gives_the_poses_of_its_operators_driven_by_hand() -> None:
    """``tracker.evo:tracker=pose_6dof`` under ``tectum.run`` (the bench's
    row) against the same operators fed 5 ms slices by hand, wired as the
    macro wires them: the same rows, bit for bit (0.3 s of bootstrap, 0.1 s
    tracked on the bench's plane)."""
    from tectum.evaluation.suites._pose_evo import PHOTO_MAPPER
    from tectum.evaluation.suites._pose_evo_photo import pipeline, simulate_davis, wired

    run = simulate_davis(400_000)
    est, maps, _ = pipeline(run, 0, PHOTO_MAPPER)
    ref, emaps, _ = wired(run, 0, PHOTO_MAPPER)
    assert (est.t > 300_000).sum() > 50 and not est.lost.any() and len(maps) >= 3
    np.testing.assert_array_equal(est.t, ref.t)
    np.testing.assert_array_equal(est.position, ref.position)
    np.testing.assert_array_equal(est.orientation, ref.orientation)
    assert sum(len(m) for m in maps) == sum(len(m) for m in emaps)
