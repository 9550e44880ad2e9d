"""tracker.edge_align: the analytic gradient against finite differences,
tracking after a bootstrap on a scene of known points, the bootstrap rows
are the given poses, a wrong map or none gives lost rows (never confident
garbage), relocalisation once the right map comes, bad input, and the
gyro: the turn between steps, its bias, its axes, its bad samples."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from tectum import ImuPacket, MapPacket, Packet, PosePacket, concat
from tectum.camera import quat_to_rot, se3_exp, so3_exp, so3_log
from tectum.plugins.tracker import EdgeAlign
from tectum.plugins.tracker._edge_align import _system, gradients
from tectum.plugins.tracker.edge_align import _points_scene
from tectum.testing import feed_ports

SENSOR = (240, 180)
F = 200.0
CALIB = f"{F};{F};{(SENSOR[0] - 1) / 2};{(SENSOR[1] - 1) / 2}"
SPEED = 0.5  # m/s along x
BOOT = 20_000  # µs
KW = {"window_events": 1500, "step_events": 500, "min_neighbours": 0}


@lru_cache(maxsize=2)
def _scene(seed: int = 0) -> dict[str, Packet]:
    return _points_scene(duration_us=200_000, sensor=SENSOR, f=F, speed=SPEED, n_points=150, seed=seed)


def _track(streams: dict[str, Packet | list[Packet]], **kw: object) -> tuple[PosePacket, EdgeAlign]:
    op = EdgeAlign(calib=CALIB, **{"bootstrap_us": BOOT, **KW, **kw})  # type: ignore[arg-type]
    out = feed_ports(op, {k: v if isinstance(v, list) else [v] for k, v in streams.items()})
    est = concat([q for q in out if isinstance(q, PosePacket)])
    assert isinstance(est, PosePacket)
    return est, op


def _errors(est: PosePacket) -> np.ndarray:
    """Position errors (m) of the rows against the camera sliding along x."""
    true = np.zeros((len(est), 3))
    true[:, 0] = SPEED * est.t * 1e-6
    return np.linalg.norm(est.position - true, axis=1)


def test_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    h, w = 60, 80
    E = gaussian_filter(rng.random((h, w)), 3.0)
    E = (E - E.min()) / (E.max() - E.min())
    gx, gy = np.empty_like(E), np.empty_like(E)
    gradients(E, gx, gy)
    pts = np.column_stack([rng.uniform(-0.5, 0.5, 200), rng.uniform(-0.4, 0.4, 200), rng.uniform(1.5, 2.5, 200)])
    cam = np.array([60.0, 60.0, 39.5, 29.5])
    R, t = np.eye(3), np.array([0.01, -0.02, 0.0])
    H, g = np.empty((6, 6)), np.empty(6)
    cost, n, _ = _system(pts, R, t, cam, E, gx, gy, 10.0, 5.0, 0.05, H, g)  # huber 10: all quadratic
    eps = 1e-6
    num = np.empty(6)
    for j in range(6):
        d = np.zeros(6)
        d[j] = eps
        Rd, td = se3_exp(d)
        cp, n_p, _ = _system(pts, Rd @ R, Rd @ t + td, cam, E, gx, gy, 10.0, 5.0, 0.05, H.copy(), np.empty(6))
        d[j] = -eps
        Rd, td = se3_exp(d)
        cm, n_m, _ = _system(pts, Rd @ R, Rd @ t + td, cam, E, gx, gy, 10.0, 5.0, 0.05, H.copy(), np.empty(6))
        assert n_p == n_m == n
        num[j] = (cp - cm) * n / (2 * eps)
    # the kernel's image gradient is the bilinear image of central differences, not the derivative of the
    # bilinear image: close (to 5 % of the largest component), not equal
    np.testing.assert_allclose(g, num, rtol=0.05, atol=0.05 * np.abs(num).max())


def test_tracks_after_bootstrap():
    s = _scene()
    est, op = _track({"events": s["events"], "maps": s["maps"], "poses": s["poses"]})
    after = est.t >= BOOT
    assert op.counts["tracked"] == after.sum() > 300 and not est.lost.any()
    e = _errors(est)[after]
    path = SPEED * (est.t[-1] - BOOT) * 1e-6  # 9 cm
    assert e[-1] <= 0.05 * path, (e[-1], path)
    assert e.max() <= 0.005
    # the velocity is the camera's (0.5 m/s along x) within 20 % once settled
    v = est.linear_velocity[after][len(e) // 2:]
    assert np.median(v[:, 0]) == pytest.approx(SPEED, rel=0.2)


def test_bootstrap_rows_are_the_given_poses():
    s = _scene()
    est, op = _track({"events": s["events"], "maps": s["maps"], "poses": s["poses"]})
    given = s["poses"]
    assert isinstance(given, PosePacket)
    k = int(np.searchsorted(given.t, BOOT))
    boot = est.t < BOOT
    assert op.counts["bootstrap_poses"] == boot.sum() == k
    np.testing.assert_array_equal(est.t[boot], given.t[:k])
    np.testing.assert_allclose(est.position[boot], given.position[:k])
    np.testing.assert_allclose(est.orientation[boot], given.orientation[:k])
    assert not est.lost[boot].any()


def _wrong_map() -> MapPacket:
    m = _scene(seed=7)["maps"]  # the points of another scene
    assert isinstance(m, MapPacket)
    return m


def test_wrong_map_gives_lost_rows_not_garbage():
    s = _scene()
    est, op = _track({"events": s["events"], "maps": _wrong_map(), "poses": s["poses"]})
    after = est.t >= BOOT
    assert est.lost[after].mean() >= 0.9, op.counts
    assert op.counts["lost_overlap"] + op.counts["lost_few_points"] == est.lost.sum()
    # whatever is not flagged lost is still right
    assert (_errors(est)[after & ~est.lost] <= 0.005).all()
    # lost rows coast at the bootstrap's velocity for coast_us (50 ms), then hold the pose
    late = est.take(np.flatnonzero(est.lost & (est.t > BOOT + 60_000)))
    assert isinstance(late, PosePacket) and len(late) > 100
    assert (late.linear_velocity == 0).all() and (late.angular_velocity == 0).all()
    assert np.ptp(late.position, axis=0).max() == 0


def test_no_map_gives_lost_rows():
    s = _scene()
    empty = MapPacket.empty(0, 200_001)
    est, op = _track({"events": s["events"], "maps": empty, "poses": s["poses"]})
    after = est.t >= BOOT
    assert est.lost[after].all() and op.counts["lost_no_map"] == after.sum()


def test_relocalises_when_the_right_map_comes():
    s = _scene()
    right = s["maps"]
    assert isinstance(right, MapPacket)
    late = MapPacket(np.array([60_000], np.int64), depth=right.depth, K=right.K, pose=right.pose, t_start=60_000,
                     t_end=200_001)
    wrong = _wrong_map()
    maps = [MapPacket(wrong.t, depth=wrong.depth, K=wrong.K, pose=wrong.pose, t_start=0, t_end=60_000), late]
    est, op = _track({"events": s["events"], "maps": maps, "poses": s["poses"]})
    assert op.counts["relocalised"] >= 1 and op.counts["lost_overlap"] >= 1
    tail = est.t >= 100_000
    assert not est.lost[tail].any()
    assert _errors(est)[tail].max() <= 0.005


def test_bad_input_is_refused():
    s = _scene()
    m = s["maps"]
    assert isinstance(m, MapPacket)
    with pytest.raises(ValueError, match="calib"):
        EdgeAlign()
    small = MapPacket(m.t, depth=m.depth[:, :40, :60], K=m.K, pose=m.pose, t_start=m.t_start, t_end=m.t_end)
    with pytest.raises(ValueError, match="60x40 px, the events 240x180"):
        _track({"events": s["events"], "maps": small, "poses": s["poses"]})
    K2 = m.K.copy()
    K2[:, 0, 0] *= 1.2
    other = MapPacket(m.t, depth=m.depth, K=K2, pose=m.pose, t_start=m.t_start, t_end=m.t_end)
    with pytest.raises(ValueError, match="intrinsics"):
        _track({"events": s["events"], "maps": other, "poses": s["poses"]})
    with pytest.raises(ValueError, match="window_events"):
        EdgeAlign(calib=CALIB, window_events=100, step_events=200)


@pytest.mark.slow
def test_evo_loop_from_the_command_line(tmp_path):
    """``tracker.evo`` (this tracker and map.emvs in a loop) on a simulated
    ECD-layout folder: the TUM file starts with the bootstrap's true poses,
    then the tracker's own; the maps go to the npz. The bound on the tracked
    poses is loose (measured: ATE 0.13 m over a 0.11 m path): it guards the
    wiring; the accuracy is the bench's (``tectum bench pose``, part evo)."""
    import importlib.util
    import subprocess
    import sys

    if importlib.util.find_spec("tectum.plugins.tracker.evo") is None:
        pytest.skip("the tracker.evo macro is not there")
    from tectum.evaluation.metrics.trajectory import trajectory_scores
    from tectum.sources.simulate import simulate

    ev, truth = simulate("plane_6dof", 500_000, sensor="120x90", seed=1)
    f, cx, cy = truth["camera"]
    np.savetxt(tmp_path / "events.txt", np.column_stack([ev.t / 1e6, ev.x, ev.y, (ev.p > 0).astype(int)]),
               fmt=["%.6f", "%d", "%d", "%d"])
    gt = np.column_stack([truth["pose_t"] / 1e6, truth["pose_position"], truth["pose_orientation"]])
    np.savetxt(tmp_path / "groundtruth.txt", gt, fmt="%.9f")
    (tmp_path / "calib.txt").write_text(f"{f} {f} {cx} {cy} 0 0 0 0 0\n")
    boot = 250_000
    out = subprocess.run([sys.executable, "-m", "tectum", "run", f"{tmp_path / 'events.txt'}?sensor=120x90", "--op",
                          f"tracker.evo:bootstrap_us={boot},window_events=6000,step_events=1500,min_depth=1,"
                          "max_depth=4,keyframe_baseline=0.1", "--sink", str(tmp_path / "traj.tum"),
                          "--sink", str(tmp_path / "maps.npz")], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    tum = np.loadtxt(tmp_path / "traj.tum")
    t = np.round(tum[:, 0] * 1e6).astype(np.int64)
    k = int(np.searchsorted(truth["pose_t"], boot))
    np.testing.assert_allclose(tum[:k], gt[:k], atol=1e-6)  # the bootstrap: the source's poses
    after = t >= boot
    assert after.sum() >= 50
    s = trajectory_scores(t[after], tum[after, 1:4], tum[after, 4:8], truth["pose_t"], truth["pose_position"],
                          truth["pose_orientation"], mode="none")
    assert s["ate_m"] <= 0.25, s
    z = np.load(tmp_path / "maps.npz")
    assert len(z["maps_t"]) >= 2 and z["maps_depth"].shape[1:] == (90, 120)
    assert z["poses_lost"].sum() == len(z["poses_t"]) - len(tum)  # lost rows are not in the TUM file


def test_planar_bootstrap_tracks_without_poses():
    """No poses: the first window's edges as a plane at ``plane_depth`` (the
    scene's points all lie 2 m away), the world is the first camera."""
    s = _points_scene(duration_us=200_000, sensor=SENSOR, f=F, speed=SPEED, n_points=150, depth=(2.0, 2.0))
    op = EdgeAlign(calib=CALIB, plane_depth=2.0, **KW)  # type: ignore[arg-type]
    out = feed_ports(op, {"events": [s["events"]], "maps": [MapPacket.empty(0, 200_001)]})
    est = concat([q for q in out if isinstance(q, PosePacket)])
    assert isinstance(est, PosePacket)
    assert op.counts["tracked"] == len(est) > 500 and not est.lost.any()
    moved = est.position - est.position[0]
    true = SPEED * (est.t - est.t[0]) * 1e-6
    path = true[-1]
    assert abs(moved[-1, 0] - path) <= 0.05 * path  # the scale is plane_depth's
    assert np.abs(moved[:, 1:]).max() <= 0.15 * path  # measured: 12 mm once, 0.3 mm at the end


def _diluted(m: MapPacket, t0: int, t1: int, share: float = 6.0) -> MapPacket:
    """``m``'s depth with ``share`` times as many pixels again at random
    depths (points off the scene's edges: a map whose points seldom all
    land on edges, like a plane filled in), valid from ``t0`` to ``t1`` µs."""
    rng = np.random.default_rng(5)
    depth = m.depth[0].copy()
    empty = np.flatnonzero(~np.isfinite(depth))
    fill = rng.choice(empty, int(share * np.isfinite(depth).sum()), replace=False)
    depth.ravel()[fill] = rng.uniform(1.0, 4.0, len(fill))
    return MapPacket(np.array([t0], np.int64), depth=depth[None], K=m.K, pose=m.pose, t_start=t0, t_end=t1)


def test_relocalises_on_a_map_whose_points_seldom_land_on_edges():
    """A right map diluted with points off the edges (its overlap about
    0.15, under the 0.2 asked of a map with no good steps yet), a wrong map
    for 30 ms, then the diluted map again: the tracker relocalises on it,
    judged against the overlap the diluted map had while tracking (the
    known overlap); without it, lost to the end."""
    s = _scene()
    right = s["maps"]
    assert isinstance(right, MapPacket)
    wrong = _wrong_map()
    maps = [_diluted(right, 0, 30_000),
            MapPacket(np.array([30_000], np.int64), depth=wrong.depth, K=wrong.K, pose=wrong.pose, t_start=30_000,
                      t_end=60_000),
            _diluted(right, 60_000, 200_001)]
    for known in (False, True):
        est, op = _track({"events": s["events"], "maps": maps, "poses": s["poses"]}, known_overlap=known)
        tail = est.t >= 100_000
        if not known:
            assert est.lost[tail].all(), op.counts
            continue
        assert op.counts["relocalised"] >= 1 and not est.lost[tail].any(), op.counts
        assert _errors(est)[tail].max() <= 0.015  # the points off the edges pull a little (1.2 cm at most)


# -- the gyro (port imu) ---------------------------------------------------------------------------------------
OMEGA = (0.2, 0.6, -0.3)  # rad/s, camera frame


@lru_cache(maxsize=1)
def _turning() -> dict[str, Packet]:
    return _points_scene(duration_us=200_000, sensor=SENSOR, f=F, speed=SPEED, n_points=150, omega=OMEGA)


def _with_gyro(gyro: np.ndarray) -> dict[str, Packet]:
    s = dict(_turning())
    imu = s["imu"]
    assert isinstance(imu, ImuPacket)
    s["imu"] = ImuPacket(imu.t, accel=imu.accel, gyro=gyro, t_start=imu.t_start, t_end=imu.t_end)
    return s


def _turn_errors(est: PosePacket, omega: tuple[float, float, float] = OMEGA) -> np.ndarray:
    """Rotation errors (rad) of the rows against world-from-camera exp(ω t)."""
    R = quat_to_rot(est.orientation)
    true = so3_exp(np.outer(est.t * 1e-6, omega))
    return np.linalg.norm(so3_log(np.einsum("nji,njk->nik", true, R)), axis=1)


def test_the_gyro_sets_the_turn_between_steps():
    """With a tight ``gyro_rad`` the tracked rotation is the gyro's, even a
    wrong gyro's: the rows turn at the gyro's rate, not the camera's. With
    the true gyro the rows are as good as without it or better."""
    s = _turning()
    imu = s["imu"]
    assert isinstance(imu, ImuPacket)
    boot_end = BOOT
    est, op = _track(dict(s), gyro_rad=1e-7)
    after = est.t >= boot_end
    assert op.counts["gyro_steps"] == op.counts["tracked"] > 100
    assert _turn_errors(est)[after].max() < 2e-3
    wrong = (OMEGA[0], OMEGA[1] + 0.3, OMEGA[2])
    est_w, op_w = _track(_with_gyro(np.tile(wrong, (len(imu), 1))), gyro_rad=1e-7, gyro_bias=(0.0, 0.0, 0.0))
    good = ~est_w.lost & (est_w.t >= boot_end + 20_000)
    assert good.sum() > 50
    # relative to the bootstrap's last pose the rows turn by the wrong gyro
    t_last = int(est_w.t[~est_w.lost & (est_w.t < boot_end)][-1]) if (est_w.t < boot_end).any() else boot_end
    R0 = so3_exp(np.asarray(OMEGA) * t_last * 1e-6)
    R = quat_to_rot(est_w.orientation[good])
    dt = (est_w.t[good] - t_last) * 1e-6
    want = np.einsum("ij,njk->nik", R0, so3_exp(np.outer(dt, wrong)))
    err = np.linalg.norm(so3_log(np.einsum("nji,njk->nik", want, R)), axis=1)
    assert err.max() < 2e-3, err.max()
    assert _turn_errors(est_w)[good].max() > 0.02  # and so away from the camera's own turn


def test_the_gyro_bias_is_measured_over_the_bootstrap():
    s = _turning()
    imu = s["imu"]
    assert isinstance(imu, ImuPacket)
    bias = np.array([0.02, -0.03, 0.01])
    est, op = _track(_with_gyro(imu.gyro + bias), gyro_rad=1e-7, bootstrap_us=60_000)
    np.testing.assert_allclose(op._bias, bias, atol=2e-3)
    assert _turn_errors(est)[est.t >= 60_000].max() < 3e-3
    # a bias given is kept as it is
    _, op2 = _track(_with_gyro(imu.gyro + bias), gyro_rad=1e-7, bootstrap_us=60_000, gyro_bias=(0.0, 0.0, 0.0))
    np.testing.assert_array_equal(op2._bias, np.zeros(3))


def test_gyro_samples_that_are_not_finite_are_dropped_and_counted():
    s = _turning()
    imu = s["imu"]
    assert isinstance(imu, ImuPacket)
    gyro = imu.gyro.copy()
    gyro[50:53, 1] = np.nan
    est, op = _track(_with_gyro(gyro), gyro_rad=1e-7)
    assert op.counts["imu_dropped"] == 3
    assert np.isfinite(est.orientation).all() and _turn_errors(est)[est.t >= BOOT].max() < 2e-3


def test_a_gyro_asked_for_without_samples_is_an_error():
    s = {k: v for k, v in _turning().items() if k != "imu"}
    with pytest.raises(ValueError, match=r"gyro_rad=0.001 but no gyro sample came on port 'imu' for the \d+ steps "
                       "after the bootstrap"):
        _track(s, gyro_rad=1e-3)
    with pytest.raises(ValueError, match="gyro_rad >= 0"):
        EdgeAlign(calib=CALIB, gyro_rad=-1.0)
    with pytest.raises(ValueError, match="gyro_bias takes 3"):
        EdgeAlign(calib=CALIB, gyro_bias=(0.1, 0.2))
    with pytest.raises(ValueError, match="imu_rotation takes 3 numbers"):
        EdgeAlign(calib=CALIB, imu_rotation=(0.1, 0.2))


def test_the_imu_rotation_turns_the_gyro_into_the_camera_frame():
    """A gyro mounted with its axes as diag(-1, 1, -1) of the camera's
    (DAVIS240's), given ``imu_rotation`` (a half turn about y), tracks as
    the camera's own gyro."""
    s = _turning()
    imu = s["imu"]
    assert isinstance(imu, ImuPacket)
    est, _ = _track(_with_gyro(imu.gyro * np.array([-1.0, 1.0, -1.0])), gyro_rad=1e-7,
                    imu_rotation=(0.0, np.pi, 0.0))
    assert _turn_errors(est)[est.t >= BOOT].max() < 2e-3
