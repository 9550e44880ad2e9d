"""map.emvs: the plane-sweep votes against a slow geometric reference, depth
of points seen from a translating camera, no depth from pure rotation, the
bad inputs, and the command line on an ECD-layout folder."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import tectum
from tectum import Pipeline, PipelineError, PosePacket
from tectum.camera import rot_to_quat, so3_exp
from tectum.plugins.map._dsi import focus_argmax, ray_traces, vote
from tectum.plugins.map.emvs import Emvs, depth_map, depth_planes, translating_points
from tectum.plugins.repr.motion_compensated import _rotating_points
from tectum.testing import ListSink, ListSource, feed_ports

SENSOR, F = (120, 90), 100.0
CX, CY = (SENSOR[0] - 1) / 2, (SENSOR[1] - 1) / 2
CALIB = f"{F};{F};{CX};{CY}"
OPTS = {"calib": CALIB, "planes": 60, "min_depth": 0.5, "max_depth": 5.0}


def _scene(depth=(1.0, 3.0), velocity=(1.5, 0.5, 0.0)):
    return translating_points(duration_us=200_000, sensor=SENSOR, f=F, n_points=50, depth=depth, velocity=velocity)


def _truth(depth, centre):
    """The scene's points (drawn as translating_points draws them) seen from
    a camera at ``centre`` (m): their pixels ``u, v`` and depths ``Z`` (m)."""
    rng = np.random.default_rng(0)
    Z = rng.uniform(depth[0], depth[1], 50)
    X = (rng.uniform(0.1, 0.9, 50) * SENSOR[0] - CX) / F * Z
    Y = (rng.uniform(0.1, 0.9, 50) * SENSOR[1] - CY) / F * Z
    Zc = Z - centre[2]
    u = np.round(F * (X - centre[0]) / Zc + CX).astype(int)
    v = np.round(F * (Y - centre[1]) / Zc + CY).astype(int)
    ok = (u >= 0) & (v >= 0) & (u < SENSOR[0]) & (v < SENSOR[1])
    return u[ok], v[ok], Zc[ok]


def _run(streams, **kw):
    op = Emvs(**{**OPTS, **kw})
    out = feed_ports(op, {k: [v] for k, v in streams.items()})
    return op, [q for q in out if q.kind == "maps"], [q for q in out if q.kind == "points"]


# -- kernels ------------------------------------------------------------------------
def _slow_votes(ev_xy, R_re, C, rays, depths, shape):
    """Each event's ray C + s d (reference frame) meets each plane Z at a
    point, projected into the reference view and voted bilinearly when its
    2x2 cell is inside: the geometry written out, one event at a time."""
    dsi = np.zeros(shape, np.float64)
    H, W = shape[1:]
    for (x, y) in ev_xy:
        d = R_re @ np.array([rays[y, x, 0], rays[y, x, 1], 1.0])
        for k, Z in enumerate(depths):
            s = (Z - C[2]) / d[2]
            if s <= 0:
                continue
            P = C + s * d
            u, v = F * P[0] / P[2] + CX, F * P[1] / P[2] + CY
            if not (0 <= u < W - 1 and 0 <= v < H - 1):
                continue
            iu, iv = int(u), int(v)
            fu, fv = u - iu, v - iv
            dsi[k, iv, iu] += (1 - fu) * (1 - fv)
            dsi[k, iv, iu + 1] += fu * (1 - fv)
            dsi[k, iv + 1, iu] += (1 - fu) * fv
            dsi[k, iv + 1, iu + 1] += fu * fv
    return dsi


def test_votes_match_the_plane_sweep_written_out():
    rng = np.random.default_rng(3)
    W, H = 40, 30
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays = np.ascontiguousarray(np.stack([(u - CX) / F, (v - CY) / F], axis=-1))
    depths = depth_planes(12, 0.5, 4.0)
    R_re = np.asarray(so3_exp(np.array([0.02, -0.03, 0.01])))
    C = np.array([0.08, -0.03, 0.6])  # in front of the two nearest planes: they get no votes
    x = rng.integers(0, W, 25).astype(np.uint16)
    y = rng.integers(0, H, 25).astype(np.uint16)
    seg = np.zeros(25, np.int64)
    trace = np.empty((4, 25), np.float32)
    ok = ray_traces(x, y, seg, rays, R_re[None], C[None], F, F, CX, CY, trace)
    assert ok == 25
    first = np.full(25, np.searchsorted(depths, C[2], side="right"))
    dsi = np.zeros((12, H, W), np.float32)
    vote(trace, first, 1.0 / depths, dsi)
    ref = _slow_votes(list(zip(x, y)), R_re, C, rays, depths, dsi.shape)
    assert ref[:2].sum() == 0 and ref.sum() > 20
    np.testing.assert_allclose(dsi, ref, atol=2e-3)


def test_votes_are_the_float32_sums_of_an_event_by_event_loop():
    """The kernel's chunked two-pass votes (dropped votes as weight 0) give
    exactly the float32 sums of the plain loop, cell by cell in event order:
    3.4 chunks of events on a 12x9 image (many votes per cell, so any
    change of order shows in the rounding), with NaN traces, traces leaving
    the image and events whose camera is past the nearest planes."""
    rng = np.random.default_rng(5)
    W, H, n = 12, 9, 3500
    trace = np.stack([rng.uniform(-3, W + 2, n), rng.uniform(-3, H + 2, n), rng.normal(0, 4, n),
                      rng.normal(0, 4, n)]).astype(np.float32)
    trace[:, rng.integers(0, n, 40)] = np.nan
    first = np.where(rng.random(n) < 0.2, rng.integers(1, 6, n), 0).astype(np.int64)
    rho = 1.0 / depth_planes(6, 0.5, 4.0)
    dsi = np.zeros((6, H, W), np.float32)
    cast = vote(trace, first, rho, dsi)
    ref = np.zeros_like(dsi)
    one, expected = np.float32(1), 0
    for k, r in enumerate(rho.astype(np.float32)):
        for i in range(n):
            u, v = trace[0, i] + r * trace[2, i], trace[1, i] + r * trace[3, i]
            if k < first[i] or not (0 <= u < W - 1 and 0 <= v < H - 1):
                continue
            iu, iv = int(u), int(v)
            fu, fv = u - np.float32(iu), v - np.float32(iv)
            ref[k, iv, iu] += (one - fu) * (one - fv)
            ref[k, iv, iu + 1] += fu * (one - fv)
            ref[k, iv + 1, iu] += (one - fu) * fv
            ref[k, iv + 1, iu + 1] += fu * fv
            expected += 1
    assert ref.dtype == np.float32 and 1000 < expected < 6 * n * 0.8
    assert cast == expected
    np.testing.assert_array_equal(dsi, ref)


def test_the_depth_map_reads_the_best_plane_and_thresholds_it():
    depths = depth_planes(10, 1.0, 4.0)
    dsi = np.zeros((10, 20, 20), np.float32)
    dsi[:, :, :] = 0.1
    dsi[6, 5:15, 10] = 9.0  # a line of strong votes on plane 6, background flat
    depth, conf = depth_map(dsi, depths, refine=False, median_size=3)
    assert np.isfinite(depth).sum() == 10
    np.testing.assert_allclose(depth[5:15, 10], depths[6], rtol=1e-6)
    assert conf[10, 10] == 9.0 and conf[0, 0] == pytest.approx(0.1)


def test_focus_picks_the_plane_whose_local_variance_is_largest():
    """focus_argmax against the local variance written out (the window
    clipped at the borders), without and with the parabola."""
    rng = np.random.default_rng(3)
    dsi = rng.random((6, 9, 11)).astype(np.float32)
    P, H, W = dsi.shape
    r = 2
    var = np.empty((P, H, W))
    for k in range(P):
        for j in range(H):
            for i in range(W):
                win = dsi[k, max(0, j - r):j + r + 1, max(0, i - r):i + r + 1].astype(np.float64)
                var[k, j, i] = win.var()
    index = np.empty((H, W))
    focus_argmax(dsi, r, False, index)
    np.testing.assert_array_equal(index, var.argmax(0))
    focus_argmax(dsi, r, True, index)
    k = var.argmax(0)
    inner = (k > 0) & (k < P - 1)
    a, b, c = (np.take_along_axis(var, np.clip(k + d, 0, P - 1)[None], 0)[0] for d in (-1, 0, 1))
    off = np.clip(0.5 * (a - c) / (a - 2 * b + c), -0.5, 0.5)
    np.testing.assert_allclose(index[inner], (k + off)[inner], atol=1e-9)
    np.testing.assert_array_equal(index[~inner], k[~inner])


def test_focus_finds_the_sharp_plane_where_smeared_votes_pile_higher():
    """A sharp pattern of votes on plane 3 (0 and 2, mean 1) and the same
    votes smeared flat but piled higher (1.5) on plane 7: the most votes
    put the pattern's dark pixels on plane 7, the sharpest slice puts
    every pixel on plane 3."""
    depths = depth_planes(10, 1.0, 4.0)
    dsi = np.full((10, 21, 21), 0.2, np.float32)
    yy, xx = np.mgrid[0:21, 0:21]
    dsi[3] = np.where((yy + xx) % 2 == 0, 2.0, 0.0)
    dsi[7] = 1.5
    opts = {"refine": False, "median_size": 1, "threshold_c": -1.0}  # every pixel kept
    free, _ = depth_map(dsi, depths, **opts)
    assert np.mean(free == np.float32(depths[7])) == pytest.approx(0.5, abs=0.01)
    sharp, conf = depth_map(dsi, depths, focus=2, **opts)
    np.testing.assert_allclose(sharp, depths[3], rtol=1e-6)
    assert conf.max() == 2.0  # the confidence is still the most votes
    with pytest.raises(ValueError, match="focus"):
        Emvs(calib=CALIB, focus=-1)


# -- the operator -------------------------------------------------------------------------
def test_points_at_known_depths_from_a_translating_camera():
    s = _scene()  # 0.32 m of travel before points 1-3 m away
    op, maps, clouds = _run(s, keyframe_baseline=0.5)
    assert op.counts["maps"] == len(maps) == 1 and op.counts["no_translation"] == 0
    m = maps[0]
    assert int(m.t_ref[0]) == 0 and m.pose[0].tolist() == [0, 0, 0, 0, 0, 0, 1]
    depth = m.depth[0]
    u, v, Z = _truth((1.0, 3.0), np.zeros(3))  # the reference view: the camera at t = 0
    est = depth[v, u]
    assert np.isfinite(est).mean() > 0.9
    assert np.nanmedian(np.abs(est - Z) / Z) < 0.04
    # the cloud: the map's pixels in the world, as many as the map knows
    c = clouds[0]
    assert len(c) == np.isfinite(depth).sum() and np.all(c.t == m.t[0])
    np.testing.assert_allclose(np.sort(c.position[:, 2]), np.sort(depth[np.isfinite(depth)]), rtol=1e-6)


def test_a_long_trajectory_gives_a_sequence_of_maps():
    velocity = np.array([2.0, 0.5, 0.0])  # 0.41 m in all
    s = _scene(depth=(1.5, 2.5), velocity=tuple(velocity))
    op, maps, _ = _run(s, keyframe_baseline=0.08)  # a new view after 8% of the scene depth
    assert len(maps) >= 3 and op.counts["maps"] == len(maps)
    refs = [int(m.t_ref[0]) for m in maps]
    assert refs == sorted(refs) and refs[0] == 0
    for m, t_ref in zip(maps, refs):
        np.testing.assert_allclose(m.pose[0][:3], velocity * t_ref * 1e-6, atol=1e-9)  # the reference's position
        u, v, Z = _truth((1.5, 2.5), velocity * t_ref * 1e-6)
        est = m.depth[0][v, u]
        assert np.nanmedian(np.abs(est - Z) / Z) < 0.15  # short baselines (13 cm at 2 m, f = 100 px): coarse



def test_overlapping_views_give_fresh_maps_with_long_baselines():
    # overlap 2 at 8 % of the scene depth: a map as often as one view at a time at 4 %, each integrating 8 %
    velocity = np.array([2.0, 0.5, 0.0])
    s = _scene(depth=(1.5, 2.5), velocity=tuple(velocity))
    _, long, _ = _run(s, keyframe_baseline=0.08)
    op, sliding, _ = _run(s, keyframe_baseline=0.08, overlap=2)
    _, short, _ = _run(s, keyframe_baseline=0.04)
    refs = [int(m.t_ref[0]) for m in sliding]
    assert refs == sorted(refs) and len(sliding) >= 2 * len(long) - 1 and op.counts["maps"] == len(sliding)
    assert np.all(np.diff([int(m.t[0]) for m in sliding]) > 0)  # one map at a time
    assert np.median(np.diff(refs)) < 0.6 * np.median(np.diff([int(m.t_ref[0]) for m in long]))
    # the first view is the same whatever the overlap; the later views start between those of one at a time
    tectum.testing.assert_streams_equal([long[0]], [sliding[0]], "first map")
    assert set(int(m.t_ref[0]) for m in long[:2]) <= set(refs)

    def error(m):
        u, v, Z = _truth((1.5, 2.5), velocity * int(m.t_ref[0]) * 1e-6)
        return float(np.nanmedian(np.abs(m.depth[0][v, u] - Z) / Z))

    full = sliding[:-1]  # the last ends with the stream
    base = [float(m.baseline[0]) for m in full]
    assert min(base) > 1.25 * max(float(m.baseline[0]) for m in short)  # each still over the long baseline
    assert max(error(m) for m in full) < 0.13 < np.median([error(m) for m in short[1:-1]])


def test_interim_maps_come_between_those_of_one_view_from_the_same_reference():
    s = _scene(depth=(1.5, 2.5), velocity=(2.0, 0.5, 0.0))
    _, whole, clouds = _run(s, keyframe_baseline=0.08)
    op, maps, interim_clouds = _run(s, keyframe_baseline=0.08, interim=2)
    # the views are the same: each ends in the same map, and an interim map of its DSI so far comes before
    finals = [m for i, m in enumerate(maps) if i + 1 == len(maps) or int(maps[i + 1].t_ref[0]) != int(m.t_ref[0])]
    tectum.testing.assert_streams_equal(whole, finals, "the views' final maps")
    early = [m for m in maps if all(m is not f for f in finals)]
    assert len(early) >= len(whole) - 1 and op.counts["maps"] == len(maps) == len(interim_clouds)
    for m in early:
        final = next(f for f in finals if int(f.t_ref[0]) == int(m.t_ref[0]))
        assert int(m.t[0]) < int(final.t[0]) and 0.4 < float(m.baseline[0]) / float(final.baseline[0]) < 0.75
    assert np.all(np.diff([int(m.t[0]) for m in maps]) > 0)
    with pytest.raises(ValueError, match="overlap or interim 1"):
        Emvs(**OPTS, interim=2, overlap=2)

def test_pure_rotation_gives_no_depth_and_says_so(caplog):
    s = _rotating_points(duration_us=40_000, sensor=SENSOR, f=F, omega=(0.3, 3.0, 0.5))
    t = np.arange(0, 40_001, 1_000, dtype=np.int64)
    q = rot_to_quat(so3_exp(np.outer(t * 1e-6, (0.3, 3.0, 0.5))))
    poses = PosePacket(t, position=np.zeros((len(t), 3)), orientation=q, t_start=0, t_end=40_001)
    with caplog.at_level("WARNING", logger="tectum.map.emvs"):
        op, maps, clouds = _run({"events": s["events"], "poses": poses})
    assert maps == [] and clouds == []
    assert op.counts["no_translation"] == 1 and op.counts["maps"] == 0
    assert "too little translation for depth (pure rotation" in caplog.text


def test_views_without_depth_are_said_once_then_counted(caplog):
    """A camera that stands still view after view (a tracker lost for a
    while): one warning for the run, every such view counted."""
    s = _rotating_points(duration_us=200_000, sensor=SENSOR, f=F, omega=(0.3, 3.0, 0.5))
    t = np.arange(0, 200_001, 1_000, dtype=np.int64)
    q = rot_to_quat(so3_exp(np.outer(t * 1e-6, (0.3, 3.0, 0.5))))
    poses = PosePacket(t, position=np.zeros((len(t), 3)), orientation=q, t_start=0, t_end=200_001)
    with caplog.at_level("WARNING", logger="tectum.map.emvs"):
        op = Emvs(**OPTS, gap_us=2_000)
        lost = PosePacket(t, position=poses.position, orientation=q, lost=(t // 10_000) % 2 == 1,
                          t_start=0, t_end=200_001)  # 10 ms good, 10 ms lost, ...
        feed_ports(op, {"events": [s["events"]], "poses": [lost]})
    assert op.counts["no_translation"] > 3
    assert caplog.text.count("too little translation") == 1


def test_any_packet_split_gives_the_same_maps():
    s = _scene(depth=(1.5, 2.5), velocity=(1.5, 0.2, 0.1))  # a few reference views
    whole = feed_ports(Emvs(**OPTS, keyframe_baseline=0.08), {k: [v] for k, v in s.items()})
    ev, ps = s["events"], s["poses"]
    pieces = {"events": list(ev.batches(997)), "poses": [ps.slice_time(a, a + 7_000) for a in range(0, 200_001, 7_000)]}
    split = feed_ports(Emvs(**OPTS, keyframe_baseline=0.08), pieces)
    tectum.testing.assert_streams_equal(whole, split, "split")
    assert sum(q.kind == "maps" for q in whole) >= 2


def _with_lost(poses, t0, t1):
    """``poses`` with the rows in ``[t0, t1]`` µs flagged lost (a tracker's gap)."""
    lost = (poses.t >= t0) & (poses.t <= t1)
    return PosePacket(poses.t, position=poses.position, orientation=poses.orientation, lost=lost,
                      t_start=poses.t_start, t_end=poses.t_end)


def test_lost_poses_end_the_map_in_progress_without_waiting_for_a_later_pose():
    # a tracker that lost track sends only lost rows: the map it waits for must still come (EVO's loop stalled)
    s = _scene()
    poses = _with_lost(s["poses"], 80_000, 200_000)
    op = Emvs(**OPTS, keyframe_baseline=0.5)
    out = op.process_ports({"events": s["events"], "poses": poses})
    maps = [q for q in out if q.kind == "maps"]
    assert len(maps) == 1 and int(maps[0].t_ref[0]) == 0 and int(maps[0].t[0]) < 80_000
    u, v, Z = _truth((1.0, 3.0), np.zeros(3))
    assert np.nanmedian(np.abs(maps[0].depth[0][v, u] - Z) / Z) < 0.1  # 13 cm of baseline
    assert op.counts["lost_poses"] == 121 and op.counts["skipped_lost_poses"] > 0
    assert [q for q in op.finish() if q.kind == "maps"] == []  # nothing left to map


def test_a_gap_of_lost_poses_is_not_mapped_and_a_new_view_starts_after_it():
    s = _scene()
    velocity = np.array([1.5, 0.5, 0.0])
    streams = {"events": s["events"], "poses": _with_lost(s["poses"], 80_000, 120_000)}
    op, maps, _ = _run(streams, keyframe_baseline=0.5)
    assert [int(m.t_ref[0]) for m in maps] == [0, 121_000]  # the first good pose after the gap
    assert int(maps[0].t[0]) < 80_000 and op.counts["maps"] == 2
    ev_t = s["events"].t
    assert 0 < op.counts["skipped_lost_poses"] <= np.sum((ev_t > 79_000) & (ev_t < 122_000))
    np.testing.assert_allclose(maps[1].pose[0][:3], velocity * 0.121, atol=1e-9)
    u, v, Z = _truth((1.0, 3.0), velocity * 0.121)
    assert np.nanmedian(np.abs(maps[1].depth[0][v, u] - Z) / Z) < 0.1
    # any packet split, also one at the gap's first lost row, gives the same maps
    whole = feed_ports(Emvs(**OPTS, keyframe_baseline=0.5), {k: [v] for k, v in streams.items()})
    ev, ps = streams["events"], streams["poses"]
    for cut in (7_000, 80_000, 100_000):
        pieces = {"events": list(ev.batches(997)), "poses": [ps.slice_time(a, a + cut) for a in range(0, 200_001, cut)]}
        tectum.testing.assert_streams_equal(whole, feed_ports(Emvs(**OPTS, keyframe_baseline=0.5), pieces), "split")
        # the events all there before the poses (a tracker's poses lag its events): no map is made early
        op = Emvs(**OPTS, keyframe_baseline=0.5)
        ahead = op.process_ports({"events": ev})
        for piece in pieces["poses"]:
            ahead += op.process_ports({"poses": piece})
        tectum.testing.assert_streams_equal(whole, ahead + op.finish(), "poses behind")



def test_overlapping_views_end_together_at_a_gap_as_one_map_under_any_split():
    s = _scene(depth=(1.5, 2.5), velocity=(2.0, 0.5, 0.0))
    streams = {"events": s["events"], "poses": _with_lost(s["poses"], 100_000, 130_000)}
    opts = {**OPTS, "keyframe_baseline": 0.08, "overlap": 3}
    op = Emvs(**opts)
    whole = feed_ports(op, {k: [v] for k, v in streams.items()})
    maps = [q for q in whole if q.kind == "maps"]
    stamps = [int(m.t[0]) for m in maps]
    assert np.all(np.diff(stamps) > 0)
    assert op.counts["superseded"] == 4  # the two younger views at the gap and at the end
    # the gap's map is the oldest view's (from 61.4 ms, as one view at a time has it), then new views after it
    one = [q for q in feed_ports(Emvs(**{**opts, "overlap": 1}), {k: [v] for k, v in streams.items()})
           if q.kind == "maps"]
    before = [m for m in maps if int(m.t[0]) < 100_000]
    assert [int(m.t_ref[0]) for m in one] == [0, 61_400, 131_000, 173_300]
    tectum.testing.assert_streams_equal([one[1]], [before[-1]], "the gap's map")
    assert [int(m.t_ref[0]) for m in maps[len(before):]][0] == 131_000
    ev, ps = streams["events"], streams["poses"]
    for cut in (7_000, 100_000):
        pieces = {"events": list(ev.batches(997)), "poses": [ps.slice_time(a, a + cut) for a in range(0, 200_001, cut)]}
        tectum.testing.assert_streams_equal(whole, feed_ports(Emvs(**opts), pieces), "split")

def test_a_short_run_of_lost_poses_is_bridged():
    # lost rows spanning less than gap_us (here 6 ms between good poses): mapped as if they were not there
    s = _scene()
    poses = _with_lost(s["poses"], 80_000, 84_000)
    op, maps, _ = _run({"events": s["events"], "poses": poses}, keyframe_baseline=0.5)
    good = poses.take(np.flatnonzero(~poses.lost))
    _, ref, _ = _run({"events": s["events"], "poses": good}, keyframe_baseline=0.5)
    tectum.testing.assert_streams_equal(ref, maps, "bridged")
    assert len(maps) == 1 and op.counts["lost_poses"] == 5 and op.counts["skipped_lost_poses"] == 0
    # with gap_us below that spacing they are a gap
    _, cut, _ = _run({"events": s["events"], "poses": poses}, keyframe_baseline=0.5, gap_us=5_000)
    assert len(cut) == 2 and int(cut[0].t_ref[0]) == 0 and 85_000 <= int(cut[1].t_ref[0]) < 88_000


# -- bad input ----------------------------------------------------------------------------
def test_no_pose_port_is_an_error_before_running():
    p = Pipeline()
    cam = p.source(ListSource([_scene()["events"]]), id="cam")
    p.op("map.emvs", cam, id="emvs", calib=CALIB)
    p.sink("null:", "emvs")
    with pytest.raises(PipelineError, match="required port.*'poses'"):
        p.validate()


def test_a_late_pose_stream_skips_the_events_before_it():
    s = _scene()
    late = s["poses"].slice_time(50_000, 200_001)
    op, maps, _ = _run({"events": s["events"], "poses": late})
    before = int((s["events"].t < late.t[0]).sum())
    assert before > 0 and op.counts["skipped_before_poses"] == before
    assert len(maps) == 1 and int(maps[0].t_ref[0]) >= 50_000


def test_poses_covering_no_event_are_an_error():
    s = _scene()
    ps = s["poses"]
    early = PosePacket(ps.t[:3] - 10_000, position=ps.position[:3], orientation=ps.orientation[:3],
                       t_start=-10_000, t_end=200_001)
    with pytest.raises(ValueError, match="none of the .* events lies within the poses on port 'poses'"):
        _run({"events": s["events"], "poses": early})


@pytest.mark.parametrize("bad, message", [
    (lambda q: np.where(np.arange(len(q))[:, None] == 5, np.nan, q), "pose at t=5000 µs .* not finite"),
    (lambda q: np.where(np.arange(len(q))[:, None] == 7, 2 * q, q), "t=7000 µs .* norm 2, not a unit quaternion"),
])
def test_bad_orientations_are_rejected_with_their_time(bad, message):
    s = _scene()
    ps = s["poses"]
    wrong = PosePacket(ps.t, position=ps.position, orientation=bad(ps.orientation.copy()), t_start=ps.t_start,
                       t_end=ps.t_end)
    with pytest.raises(ValueError, match=message):
        _run({"events": s["events"], "poses": wrong})


def test_poses_going_back_in_time_are_rejected():
    s = _scene()
    ps = s["poses"]
    op = Emvs(**OPTS)
    op.process_ports({"poses": ps.slice_time(0, 20_000)})
    with pytest.raises(ValueError, match="poses go back in time on port 'poses': 10000 µs after 19000 µs"):
        op.process_ports({"poses": ps.slice_time(10_000, 30_000)})


# -- the command line -------------------------------------------------------------------
def _ecd_folder(tmp_path, s):
    ev, ps = s["events"], s["poses"]
    with open(tmp_path / "events.txt", "w") as f:
        for t, x, y, p in zip(ev.t, ev.x, ev.y, ev.p):
            f.write(f"{t / 1e6:.6f} {x} {y} {int(p > 0)}\n")
    with open(tmp_path / "groundtruth.txt", "w") as f:
        for t, pos, q in zip(ps.t, ps.position, ps.orientation):
            f.write(f"{t / 1e6:.6f} {' '.join(map(str, pos))} {' '.join(map(str, q))}\n")
    (tmp_path / "calib.txt").write_text(f"{F} {F} {CX} {CY} 0 0 0 0 0\n")


def test_from_the_command_line_on_an_ecd_folder(tmp_path):
    s = _scene()
    _ecd_folder(tmp_path, s)
    out = subprocess.run([sys.executable, "-m", "tectum", "run", f"{tmp_path / 'events.txt'}?sensor=120x90", "--op",
                          "map.emvs:planes=60,min_depth=0.5,max_depth=5", "--sink", str(tmp_path / "depth.npz"),
                          "--sink", str(tmp_path / "cloud.ply")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    z = np.load(tmp_path / "depth.npz")
    _, ref, _ = _run(s)  # the same in Python: two reference views
    depth = np.concatenate([m.depth for m in ref])
    assert len(ref) == 2
    np.testing.assert_array_equal(z["maps_depth"], depth)
    np.testing.assert_array_equal(z["maps_t_ref"], [int(m.t_ref[0]) for m in ref])
    np.testing.assert_array_equal(z["maps_K"][0], np.array([[F, 0, CX], [0, F, CY], [0, 0, 1]]))
    known = depth[np.isfinite(depth)]
    cloud = tectum.sources.files.ply.PlySource(str(tmp_path / "cloud.ply"))
    pts = tectum.concat(list(cloud.packets()))
    assert len(pts) == known.size > 100
    np.testing.assert_allclose(np.sort(pts.position[:, 2]), np.sort(known), rtol=1e-6)


def test_on_an_ecd_folder_the_ports_fill_by_kind(tmp_path):
    s = _scene()
    _ecd_folder(tmp_path, s)
    p = Pipeline()
    src = p.source(str(tmp_path / "events.txt"), sensor=f"{SENSOR[0]}x{SENSOR[1]}")
    p.op("map.emvs", src, id="emvs", planes=60, min_depth=0.5, max_depth=5.0)  # calib.txt beside
    sink = ListSink()
    p.sink(sink, "emvs")
    tectum.run(p)
    maps = [q for q in sink.packets if q.kind == "maps" and len(q)]
    _, ref, _ = _run(s)
    assert len(maps) == len(ref) == 2
    for a, b in zip(maps, ref):
        np.testing.assert_array_equal(a.depth, b.depth)


def test_tracker_evo_passes_focus_to_its_mapper():
    p = Pipeline()
    cam = p.source("pattern:", id="cam")
    p.op("tracker.evo", events=cam, id="evo", calib=CALIB, focus=4)
    plan = p.validate()
    assert dict(plan.nodes["evo.mapper"].params) == {"calib": CALIB, "focus": 4}
    assert "focus" not in plan.nodes["evo.tracker"].params
    assert plan.nodes["evo.mapper"].instantiate().map_options["focus"] == 4
