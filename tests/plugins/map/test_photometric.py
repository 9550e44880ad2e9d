"""map.photometric: the geometry (a depth map moved into a frame's view, the
median of inverse depth), the frame and pose a map takes, maps waiting for
their frame and poses, the counted drops, bad input, batch invariance."""

from __future__ import annotations

import numpy as np
import pytest

from tectum import FramePacket, MapPacket, PosePacket
from tectum.plugins.map.photometric import Photometric, frame_before, log_image, median_depth, reproject
from tectum.testing import assert_batch_invariant, feed_ports

from helpers import SMALL_H as H
from helpers import SMALL_K as K
from helpers import SMALL_W as W
from helpers import STILL
from helpers import small_plane as _plane


def test_reproject_moves_a_plane_sideways_and_turns_it() -> None:
    # the camera 0.2 m to the right: a point of the plane 2 m away moves 50 * 0.2 / 2 = 5 px to the left
    d = np.full((H, W), np.nan)
    d[15, 20] = 2.0
    out = reproject(d, K, STILL, np.array([0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]))
    assert np.isfinite(out).sum() == 1 and out[15, 15] == 2.0
    # the camera turned 0.1 rad about y (x towards z): the point's depth is 2 cos 0.1 and it moves left
    a = 0.05
    q = np.array([0.0, np.sin(a), 0.0, np.cos(a)])
    out = reproject(d, K, STILL, np.concatenate([[0.0, 0.0, 0.0], q]))
    v, u = np.nonzero(np.isfinite(out))
    X = np.array([(20 - K[0, 2]) / K[0, 0] * 2.0, 0.0, 2.0])
    c, s = np.cos(0.1), np.sin(0.1)
    Xd = np.array([c * X[0] - s * X[2], X[1], s * X[0] + c * X[2]])  # R^T X, R about y by 0.1
    assert (int(v[0]), int(u[0])) == (15, int(np.rint(K[0, 0] * Xd[0] / Xd[2] + K[0, 2])))
    assert abs(out[v[0], u[0]] - Xd[2]) < 1e-9


def test_reproject_keeps_the_nearest_surface() -> None:
    d = np.full((H, W), np.nan)
    d[15, 10], d[15, 15] = 2.0, 4.0
    # from the camera 0.4 m to the left a point moves f t / z to the right: 10 px at 2 m, 5 px at 4 m: both at 20
    out = reproject(d, K, STILL, np.array([-0.4, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]))
    assert out[15, 20] == 2.0 and np.isfinite(out).sum() == 1


def test_median_depth_replaces_an_outlier_by_its_neighbours() -> None:
    d = _plane(2.0)
    d[10, 10] = 4.0
    d[0:3, :] = np.nan
    out = median_depth(d, 2)
    assert out[10, 10] == 2.0 and np.isnan(out[1, 5]) and np.allclose(out[5:, :], 2.0)
    assert median_depth(d, 0) is d


def test_log_image_and_frame_before() -> None:
    assert np.allclose(log_image(np.full((2, 3), 100, np.uint8), 255.0, 1e-3), np.log(100 / 255 + 1e-3))
    rgb = np.stack([np.full((2, 3), v, np.uint8) for v in (10, 20, 60)], axis=2)
    assert np.allclose(log_image(rgb, 255.0, 1e-3), np.log(30 / 255 + 1e-3))
    key = np.array([10, 20, 30], np.int64)
    assert [frame_before(key, t) for t in (9, 10, 29, 30, 99)] == [-1, 0, 1, 2, 2]


def _frames(t_end: int = 100_000) -> FramePacket:
    """Frames at 10, 50, 90 ms (exposure 5 ms) of brightness 10, 100, 200 DN."""
    t = np.array([10_000, 50_000, 90_000], np.int64)
    imgs = np.stack([np.full((H, W), v, np.uint8) for v in (10, 100, 200)])
    return FramePacket(t, images=imgs, exposure_start=t - 2500, exposure_end=t + 2500, t_start=0, t_end=t_end)


def _poses(lost: np.ndarray | None = None) -> PosePacket:
    """The camera along x at 1 m/s, a pose every ms."""
    t = np.arange(0, 100_000, 1000, dtype=np.int64)
    pos = np.stack([t * 1e-6, 0 * t, 0 * t], axis=1).astype(np.float64)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    extra = {"lost": lost} if lost is not None else {}
    return PosePacket(t, position=pos, orientation=quat, t_start=0, t_end=100_000, **extra)


def _maps(*t_maps: int, t_ref: int = 20_000, depth: np.ndarray | None = None) -> MapPacket:
    n = len(t_maps)
    pose = np.tile([t_ref * 1e-6, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], (n, 1))
    d = _plane() if depth is None else depth
    return MapPacket(np.array(t_maps, np.int64), depth=np.repeat(d[None], n, 0), K=np.repeat(K[None], n, 0),
                     pose=pose, t_start=0, t_end=100_000)


def _run(op: Photometric, **streams) -> list[MapPacket]:  # type: ignore[no-untyped-def]
    out = feed_ports(op, {k: [v] for k, v in streams.items()})
    assert all(isinstance(q, MapPacket) for q in out)
    return out  # type: ignore[return-value]


def test_a_map_takes_the_last_frame_exposed_before_it_at_that_frames_pose() -> None:
    op = Photometric(median_px=0)
    # made at 92.4 ms: the 90 ms frame's exposure ends at 92.5 ms, so the 50 ms frame is the last whole one
    out = _run(op, maps=_maps(92_400, 92_500), frames=_frames(), poses=_poses())
    assert [int(q.t[0]) for q in out] == [92_400, 92_500] and op.counts["out"] == 2
    m, at = out
    assert np.allclose(m.data["image"][0], np.log(100 / 255 + 1e-3), atol=1e-6)
    assert np.allclose(m.data["pose"][0], [0.05, 0, 0, 0, 0, 0, 1])  # the pose at the frame's time
    assert np.allclose(m.data["K"][0], K)
    # the plane seen from 30 mm further right: its pixels 50 * 0.03 / 2 = 0.75 px left, rounded to 1
    assert np.isnan(m.data["depth"][0][:, -1]).all() and np.allclose(m.data["depth"][0][:, :-1], 2.0)
    assert np.allclose(at.data["pose"][0][:3], [0.09, 0, 0])
    assert np.allclose(at.data["image"][0], np.log(200 / 255 + 1e-3), atol=1e-6)


def test_frames_without_exposure_end_are_taken_by_their_time() -> None:
    f = _frames()
    plain = FramePacket(f.t, images=f.data["images"], t_start=0, t_end=100_000)
    out = _run(Photometric(median_px=0), maps=_maps(90_000), frames=plain, poses=_poses())
    assert np.allclose(out[0].data["pose"][0][:3], [0.09, 0, 0])


def test_lost_poses_are_not_used() -> None:
    ps = _poses()
    lost = (ps.t >= 45_000) & (ps.t <= 55_000)
    pos = ps.position.copy()
    pos[lost] = 9.0  # garbage the lost rows carry
    bad = PosePacket(ps.t, position=pos, orientation=ps.orientation, lost=lost, t_start=0, t_end=100_000)
    out = _run(Photometric(median_px=0), maps=_maps(60_000), frames=_frames(), poses=bad)
    # interpolated between the good rows at 44 and 56 ms: on the straight path, at 50 mm
    assert np.allclose(out[0].data["pose"][0][:3], [0.05, 0, 0])


def test_a_map_waits_for_its_frame_and_the_poses_after_it() -> None:
    op = Photometric(median_px=0)
    fr, ps = _frames(), _poses()
    assert op.process_ports({"maps": _maps(60_000).slice_time(0, 61_000), "frames": fr.slice_time(0, 40_000),
                             "poses": ps.slice_time(0, 40_000)}) == []  # the 50 ms frame may still come
    assert op.process_ports({"frames": fr.slice_time(40_000, 61_000), "poses": ps.slice_time(40_000, 50_000)}) == []
    assert op.output_mark(61_000) == 60_000  # on a loop: the waiting map goes out at its own time
    out = op.process_ports({"poses": ps.slice_time(50_000, 51_000)})  # a pose at the frame's time: out
    assert len(out) == 1 and np.allclose(out[0].data["pose"][0][:3], [0.05, 0, 0])


def test_drops_are_counted() -> None:
    # no frame before the map; no pose at or before the frame; no pose within max_wait_us after it
    op = Photometric(median_px=0)
    assert _run(op, maps=_maps(5_000), frames=_frames(), poses=_poses()) == []
    assert op.counts["no_frame"] == 1
    op = Photometric(median_px=0)
    assert _run(op, maps=_maps(60_000), frames=_frames(), poses=_poses().slice_time(55_000, 100_000)) == []
    assert op.counts["no_pose"] == 1
    op = Photometric(median_px=0, max_wait_us=5000)
    assert _run(op, maps=_maps(60_000), frames=_frames(), poses=_poses().slice_time(0, 45_000)) == []
    assert op.counts["no_pose"] == 1
    # too few pixels with depth
    sparse = np.full((H, W), np.nan)
    sparse[10:12, 10:12] = 2.0
    op = Photometric(median_px=0)
    assert _run(op, maps=_maps(60_000, depth=sparse), frames=_frames(), poses=_poses()) == []
    assert op.counts["few_pixels"] == 1
    # more maps waiting than max_pending: the oldest go
    op = Photometric(median_px=0, max_pending=2)
    assert op.process_ports({"maps": _maps(60_000, 61_000, 62_000, 63_000).slice_time(0, 64_000)}) == []
    assert op.counts["overflow"] == 2
    out = feed_ports(op, {"frames": [_frames()], "poses": [_poses()]})
    assert [int(q.t[0]) for q in out] == [62_000, 63_000]


def test_bad_input() -> None:
    no_k = MapPacket(np.array([60_000], np.int64), depth=_plane()[None], t_start=0, t_end=100_000)
    with pytest.raises(ValueError, match="no K, pose"):
        Photometric().process_ports({"maps": no_k})
    small = FramePacket(np.array([10_000], np.int64), images=np.zeros((1, 20, 30), np.uint8), t_start=0,
                        t_end=100_000)
    with pytest.raises(ValueError, match="30x20 px, the maps 40x30"):
        _run(Photometric(), maps=_maps(60_000), frames=small, poses=_poses())
    with pytest.raises(ValueError, match="gain"):
        Photometric(gain=0)


def test_batch_invariance() -> None:
    s = Photometric.conformance_stream()
    op = Photometric()
    out = feed_ports(op, {k: [v] for k, v in s.items()})
    assert len(out) >= 5 and op.counts["out"] == len(out)
    assert len(op._fimg) <= 2  # the frames no later map can take are forgotten
    assert_batch_invariant(Photometric, s, max_examples=25)
    # a map whose frame (36 ms) has no good pose within max_wait_us after it, but one later (42 ms): dropped
    # however the ports are split (not taken when the later pose happens to come before the watermark passes)
    ps = s["poses"]
    lost = ps.data["lost"] | ((ps.t > 35_000) & (ps.t < 42_000))
    s["poses"] = PosePacket(ps.t, position=ps.position, orientation=ps.orientation, lost=lost, t_start=ps.t_start,
                            t_end=ps.t_end)
    op = Photometric(max_wait_us=3000)
    feed_ports(op, {k: [v] for k, v in s.items()})
    assert op.counts["no_pose"] == 1
    assert_batch_invariant(lambda: Photometric(max_wait_us=3000), s, max_examples=25)
