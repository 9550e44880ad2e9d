"""map.emvs's ``surface=``: the robust plane fit finds a known plane through
noisy semi-dense depth with outliers; the test refuses two planes, a box
scene and random depth; on points of one plane, ``surface="plane"`` gives
the plane's depth and ``"free"`` stays as it was; any packet split gives the
same planar maps."""

from __future__ import annotations

import numpy as np
import pytest

import tectum
from tectum.camera import quat_to_rot
from tectum.plugins.map._plane_fit import explains, fit_plane, plane_depth, plane_in_view, plane_to_world
from tectum.plugins.map.emvs import Emvs, translating_points
from tectum.testing import feed_ports

W, H, F = 120, 90, 100.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])
TRUE = np.array([0.08, -0.05, 0.5])  # 1/Z = a x + b y + c: a tilted plane about 2 m away
MIN_INLIERS = 0.8  # map.emvs's default plane_inliers
TOL = 2 * (1 / 0.5 - 1 / 5.0) / 59  # two DSI planes of OPTS below, 1/m
OPTS = {"calib": f"{F};{F};{(W - 1) / 2};{(H - 1) / 2}", "planes": 60, "min_depth": 0.5, "max_depth": 5.0}


def _semi_dense(inv_depth, share=0.15, seed=0):
    """``inv_depth`` (H, W; 1/m) as depth (m) at a random ``share`` of the
    pixels, NaN elsewhere."""
    rng = np.random.default_rng(seed)
    keep = rng.random((H, W)) < share
    return np.where(keep, 1.0 / inv_depth, np.nan)


def _plane_inv(coef):
    return 1.0 / plane_depth(np.asarray(coef), K, (H, W))


def test_the_fit_finds_a_known_plane_through_noise_and_outliers():
    rng = np.random.default_rng(1)
    inv = _plane_inv(TRUE) * (1 + 0.01 * rng.standard_normal((H, W)))  # 1 % noise
    wild = rng.random((H, W)) < 0.3  # 30 % outliers anywhere from 0.3 to 6 m
    inv[wild] = 1.0 / rng.uniform(0.3, 6.0, int(wild.sum()))
    depth = _semi_dense(inv)
    fit = fit_plane(depth, K)
    assert fit is not None and fit.n == np.isfinite(depth).sum()
    np.testing.assert_allclose(fit.coef, TRUE, atol=2e-3)
    # the plain least-squares fit is pulled off by the outliers: the robust weights matter
    v, u = np.nonzero(np.isfinite(depth))
    A = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones(len(u))], axis=1)
    ls = np.linalg.lstsq(A, 1.0 / depth[v, u], rcond=None)[0]
    assert np.abs(ls - TRUE).max() > 10 * np.abs(fit.coef - TRUE).max()
    assert explains(fit, TOL, 0.65) and not explains(fit, TOL, MIN_INLIERS)  # 70 % on it within two planes


def test_the_test_refuses_two_planes_a_box_scene_and_random_depth():
    rng = np.random.default_rng(2)
    near = _plane_inv(TRUE)
    far = _plane_inv(TRUE * 0.6)  # the same tilt, 1.67x farther
    uu, vv = np.meshgrid(np.arange(W), np.arange(H))
    two = np.where((abs(uu - W / 2) < 42) & (abs(vv - H / 2) < 32), near, far)  # a near plane before a far one
    # a box scene: floor, back wall and a box's front face in between
    floor = _plane_inv([0.0, 0.8, 0.0])  # y = 1.25 m below the camera
    wall = _plane_inv([0.0, 0.0, 1 / 6.0])
    box = _plane_inv([0.0, 0.0, 1 / 3.0])
    boxes = np.where(vv > 70, floor, np.where((uu > 30) & (uu < 70) & (vv > 30), box, wall))
    rand = 1.0 / rng.uniform(0.5, 5.0, (H, W))
    for name, inv in (("two planes", two), ("boxes", boxes), ("random", rand)):
        fit = fit_plane(_semi_dense(inv * (1 + 0.005 * rng.standard_normal((H, W)))), K)
        assert fit is not None
        assert not explains(fit, TOL, MIN_INLIERS), name
    assert explains(fit_plane(_semi_dense(near), K), TOL, MIN_INLIERS)


def test_degenerate_and_bad_input():
    assert fit_plane(np.full((H, W), np.nan), K) is None
    line = np.full((H, W), np.nan)
    line[10, :] = 2.0  # one image row: no plane fixed
    assert fit_plane(line, K) is None
    assert not explains(None, TOL, MIN_INLIERS)
    with pytest.raises(ValueError, match="depth must be"):
        fit_plane(np.ones(5), K)
    with pytest.raises(ValueError, match="min_inliers"):
        explains(None, TOL, 0.0)
    with pytest.raises(ValueError, match="surface must be"):
        Emvs(**OPTS, surface="sphere")


def _plane_scene():
    """Points of one plane 2 m in front (fronto-parallel) seen from a camera
    translating sideways, and its poses."""
    return translating_points(duration_us=200_000, sensor=(W, H), f=F, n_points=150, depth=(2.0, 2.0),
                              velocity=(1.5, 0.5, 0.0))


def _maps(streams, **kw):
    return [q for q in feed_ports(Emvs(**OPTS, keyframe_baseline=0.08, **kw), streams) if q.kind == "maps"]


def test_on_a_plane_surface_plane_gives_the_planes_depth_and_free_is_unchanged():
    s = {k: [v] for k, v in _plane_scene().items()}
    free, default, plane = _maps(s), _maps(s, surface="free"), _maps(s, surface="plane")
    assert len(free) == len(default) >= 2 and len(plane) >= 2
    for f, d in zip(free, default):  # free is the default, bit for bit, and says nothing
        np.testing.assert_array_equal(d.depth, f.depth)
        assert "planar" not in f.data and "planar" not in d.data
    for p in plane:  # each planar map within 10 % of the truth at its pixels (measured: median 2-3 %, max 7 %)
        known = np.isfinite(p.depth[0])
        err = np.abs(p.depth[0][known] - 2.0) / 2.0
        assert known.sum() > 500 and err.max() < 0.1 and np.median(err) < 0.05
        assert int(p.planar[0]) == 1 and np.isfinite(p.plane[0]).all()
    # the first map (same reference view in both): the same pixels, the free depth off by 17 % (median)
    known = np.isfinite(free[0].depth[0])
    assert np.array_equal(np.isfinite(plane[0].depth[0]), known)
    assert np.median(np.abs(free[0].depth[0][known] - 2.0) / 2.0) > 0.1
    # auto: EMVS's own depth of this plane has 36-43 % of its pixels within two DSI planes of the fit, so the
    # default test (80 %) keeps the free depth; asking for 30 % takes the plane
    auto = _maps(s, surface="auto")
    assert [int(a.planar[0]) for a in auto] == [0] * len(free)
    np.testing.assert_array_equal(auto[0].depth, free[0].depth)
    loose = _maps(s, surface="auto", plane_inliers=0.3)
    assert int(loose[0].planar[0]) == 1
    np.testing.assert_array_equal(loose[0].depth, plane[0].depth)


def _rot(axis, angle):
    """A rotation matrix about ``axis`` by ``angle`` (rad)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def test_a_world_plane_seen_from_any_pose_puts_every_pixel_on_it():
    n = np.array([0.1, -0.2, 1.0]) / np.linalg.norm([0.1, -0.2, 1.0])
    o = 2.5  # the plane n . W = 2.5 m
    for R, t in ((np.eye(3), np.zeros(3)), (_rot([0.3, 1, 0.2], 0.4), np.array([0.5, -0.3, 0.4]))):
        coef = plane_in_view(n, o, R, t)
        assert coef is not None
        depth = plane_depth(coef, K, (H, W))
        v, u = np.nonzero(np.isfinite(depth))
        X = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones(len(u))], axis=1) * depth[v, u][:, None]
        np.testing.assert_allclose((X @ R.T + t) @ n, o, rtol=1e-9)  # the pixels' points lie on the world plane
        n2, o2 = plane_to_world(coef, R, t)  # and back
        np.testing.assert_allclose(n2, n, atol=1e-12)
        assert o2 == pytest.approx(o, rel=1e-12)
    assert plane_in_view(n, o, np.eye(3), n * o) is None  # the centre on the plane: no depth
    with pytest.raises(ValueError, match="in front"):
        plane_to_world(np.zeros(3), np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="plane_maps"):
        Emvs(**OPTS, surface="world_plane", plane_maps=0)


def test_world_plane_keeps_the_first_maps_plane_in_the_world():
    """``world_plane``: the first ``plane_maps`` maps are ``plane``'s; every
    later map takes the world plane they made (here the first map's) at its
    own reference pose, not a plane of its own."""
    s = {k: [v] for k, v in _plane_scene().items()}
    plane, world = _maps(s, surface="plane"), _maps(s, surface="world_plane", plane_maps=1)
    assert len(plane) == len(world) >= 2
    np.testing.assert_array_equal(world[0].depth, plane[0].depth)
    assert [int(m.planar[0]) for m in world] == [1] * len(world)

    def pose(m):
        return quat_to_rot(m.pose[0, 3:]), m.pose[0, :3]

    n, o = plane_to_world(plane[0].plane[0], *pose(plane[0]))
    for p, w in zip(plane[1:], world[1:]):
        want = plane_in_view(n, o, *pose(w))
        np.testing.assert_allclose(w.plane[0], want, rtol=1e-9)
        assert np.abs(p.plane[0] - want).max() > 1e-4  # its own fit differs: the plane was not fitted again
        known = np.isfinite(w.depth[0])
        np.testing.assert_array_equal(known, np.isfinite(p.depth[0]))
        np.testing.assert_allclose(w.depth[0][known], plane_depth(want, K, (H, W))[known], rtol=1e-6)
        assert np.median(np.abs(w.depth[0][known] - 2.0) / 2.0) < 0.05


def test_auto_keeps_free_depth_where_no_plane_explains_the_map():
    s = {k: [v] for k, v in translating_points(duration_us=200_000, sensor=(W, H), f=F, n_points=80,
                                                depth=(1.0, 3.0), velocity=(1.5, 0.5, 0.0)).items()}
    free, auto = _maps(s), _maps(s, surface="auto")
    assert len(free) == len(auto) >= 2
    for f, a in zip(free, auto):
        np.testing.assert_array_equal(a.depth, f.depth)
        assert int(a.planar[0]) == 0 and np.isnan(a.plane[0]).all()


@pytest.mark.parametrize("surface", ["plane", "world_plane"])
def test_any_packet_split_gives_the_same_planar_maps(surface):
    s = _plane_scene()
    opts = {**OPTS, "keyframe_baseline": 0.08, "surface": surface, "plane_maps": 1}
    whole = feed_ports(Emvs(**opts), {k: [v] for k, v in s.items()})
    ev, ps = s["events"], s["poses"]
    pieces = {"events": list(ev.batches(997)), "poses": [ps.slice_time(a, a + 7_000) for a in range(0, 200_001, 7_000)]}
    split = feed_ports(Emvs(**opts), pieces)
    tectum.testing.assert_streams_equal(whole, split, "split")
    assert sum(q.kind == "maps" for q in whole) >= 2


def test_tracker_evo_passes_surface_to_its_mapper():
    p = tectum.Pipeline()
    cam = p.source("pattern:", id="cam")
    p.op("tracker.evo", events=cam, id="evo", calib="40;40;20;15", surface="plane")
    plan = p.validate()
    assert dict(plan.nodes["evo.mapper"].params) == {"calib": "40;40;20;15", "surface": "plane"}
    assert "surface" not in plan.nodes["evo.tracker"].params
    assert plan.nodes["evo.mapper"].instantiate().surface == "plane"
