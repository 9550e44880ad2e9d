"""map.poisson_mosaic: the Poisson solve inverts forward differences exactly,
rays land where the panorama's convention says, the gradient filter equals
a sequential Kalman filter and finds a known edge, the mosaic does not
depend on packet splits, and from the command line an ECD-layout folder
(events, ground-truth poses, calibration) gives a mosaic of the simulated
panorama; bad pose streams are refused or counted."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from tectum import PacketError, Pipeline, PipelineError, PosePacket
from tectum.camera import quat_to_rot
from tectum.evaluation.metrics.maps import pearson
from tectum.evaluation.panorama import truth_panorama
from tectum.plugins.map._panorama import map_events, pano_angles, pano_coords, pano_rays, solve_gradients
from tectum.plugins.map._poisson import forward_gradients, poisson_solve
from tectum.plugins.map.poisson_mosaic import PoissonMosaic, rotating_camera_stream
from tectum.testing import ListSource, assert_batch_invariant, feed_ports

F, SENSOR = 30.0, (32, 24)
CALIB = f"{F};{F};{(SENSOR[0] - 1) / 2};{(SENSOR[1] - 1) / 2}"


# -- Poisson solve ----------------------------------------------------------------
@pytest.mark.parametrize("wrap", [False, True])
@pytest.mark.parametrize("shape", [(48, 64), (33, 70), (1, 9), (8, 1)])
def test_poisson_gives_back_the_image_of_its_forward_differences(shape, wrap):
    rng = np.random.default_rng(1)
    L = rng.standard_normal(shape) + np.linspace(0, 5, shape[1])[None, :]  # a ramp too
    gx, gy = forward_gradients(L, wrap_x=wrap)
    got = poisson_solve(gx, gy, wrap_x=wrap)
    assert np.abs((got - got.mean()) - (L - L.mean())).max() < 1e-10


def test_poisson_is_the_least_squares_fit_of_inconsistent_gradients():
    """Noisy gradients (no image has them): the solve's image has a zero
    gradient of the least-squares cost, checked against scipy's lsqr."""
    from scipy.sparse import diags, eye, kron, vstack
    from scipy.sparse.linalg import lsqr

    h, w = 7, 9
    rng = np.random.default_rng(2)
    gx, gy = rng.standard_normal((h, w)), rng.standard_normal((h, w))
    gx[:, -1] = 0
    gy[-1] = 0
    D = lambda n: diags([-np.ones(n), np.ones(n - 1)], [0, 1]).tolil()  # noqa: E731
    dx, dy = D(w), D(h)
    dx[-1, -1] = 0
    dy[-1, -1] = 0
    A = vstack([kron(eye(h), dx), kron(dy, eye(w))]).tocsr()
    ref = lsqr(A, np.concatenate([gx.ravel(), gy.ravel()]), atol=1e-14, btol=1e-14, iter_lim=10_000)[0]
    got = poisson_solve(gx, gy).ravel()
    assert np.abs((got - got.mean()) - (ref - ref.mean())).max() < 1e-8


def test_poisson_refuses_non_finite_gradients():
    g = np.zeros((4, 4))
    g[1, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        poisson_solve(g, np.zeros((4, 4)))


# -- the panorama's convention ------------------------------------------------------
def test_known_rays_land_on_known_pixels():
    W, H = 1024, 512
    rays = np.array([[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, -1, 1], [0, 1, 1], [0, 0, -1.0], [1e-9, 1, 0]])
    uv = pano_coords(rays, W)
    expect = [(W / 2, H / 2), (3 * W / 4, H / 2), (W / 4, H / 2), (W / 2, H / 4), (W / 2, 3 * H / 4), (W, H / 2),
              (3 * W / 4, H)]
    np.testing.assert_allclose(uv, expect, atol=1e-9)


def test_pixel_centres_map_to_themselves():
    W = 64
    rays = pano_rays(W)
    uv = pano_coords(rays.reshape(-1, 3), W).reshape(W // 2, W, 2)
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(W // 2) + 0.5)
    np.testing.assert_allclose(uv[..., 0], jj, atol=1e-9)
    np.testing.assert_allclose(uv[..., 1], ii, atol=1e-9)
    az, el = pano_angles(W)
    assert az[0] == pytest.approx(-math.pi + math.pi / W) and el[-1] == pytest.approx(math.pi / 2 - math.pi / W)


# -- the gradient filter --------------------------------------------------------------
EDGE_AZ, EDGE_WIDTH, EDGE_STEP = 0.05, 0.3, 1.2  # rad, rad, log intensity


def _edge(az, el):
    """A vertical edge: a smooth step of EDGE_STEP in azimuth."""
    return EDGE_STEP / (1.0 + np.exp(-(az - EDGE_AZ) / EDGE_WIDTH * 4))


def _slow_kalman(streams, W, contrast, ridge):
    """The obvious reference: per event, its ray rotated by the slerped pose
    (scipy), its panorama position, and a sequential 2-D Kalman update of
    the gradient at the displacement's midpoint pixel (P0 = I/ridge, R = 1)."""
    ev, poses = streams["events"], streams["poses"]
    rot = Slerp(poses.t, Rotation.from_quat(poses.orientation))(ev.t).as_matrix()
    cx, cy = (SENSOR[0] - 1) / 2, (SENSOR[1] - 1) / 2
    rays = np.stack([(ev.x - cx) / F, (ev.y - cy) / F, np.ones(len(ev))], axis=1)
    uv = pano_coords(np.einsum("nij,nj->ni", rot, rays), W)
    g, P = {}, {}
    last = {}
    for k in range(len(ev)):
        key = (int(ev.x[k]), int(ev.y[k]))
        if key in last:
            dm = uv[k] - last[key]
            if 0 < dm @ dm <= 9:
                mid = last[key] + dm / 2
                pix = (int(mid[1]), int(math.floor(mid[0])) % W)
                gk, Pk = g.get(pix, np.zeros(2)), P.get(pix, np.eye(2) / ridge)
                z = contrast if ev.p[k] > 0 else -contrast
                S = dm @ Pk @ dm + 1.0
                K = Pk @ dm / S
                g[pix] = gk + K * (z - dm @ gk)
                P[pix] = Pk - np.outer(K, dm @ Pk)
        last[key] = uv[k]
    return g


def test_the_information_form_is_the_kalman_filter_and_finds_the_edge():
    W, C, ridge = 128, 0.1, 0.01  # a panorama px (0.05 rad) spans 1.5 sensor px
    streams = rotating_camera_stream(60_000, SENSOR, F, omega=(0.0, 3.0, 0.0), log_intensity=_edge, contrast=C)
    ev, poses = streams["events"], streams["poses"]
    assert len(ev) > 1000
    info = np.zeros((W // 2, W, 6))
    cx, cy = (SENSOR[0] - 1) / 2, (SENSOR[1] - 1) / 2
    u, v = np.meshgrid(np.arange(SENSOR[0]), np.arange(SENSOR[1]))
    rays = np.ascontiguousarray(np.stack([(u - cx) / F, (v - cy) / F, np.ones(u.shape)], axis=-1))
    n_meas, _ = map_events(ev.t, ev.x, ev.y, ev.p, poses.t, poses.orientation, rays, np.array([C, C]), 3.0,
                           np.full(SENSOR[::-1], -1, np.int64), np.zeros(SENSOR[::-1] + (2,)), info)
    gu, gv = solve_gradients(info, ridge)
    ref = _slow_kalman(streams, W, C, ridge)
    assert set(ref) == set(zip(*np.nonzero(info[..., 5])))
    for (i, j), g in ref.items():
        assert gu[i, j] == pytest.approx(g[0], abs=1e-9) and gv[i, j] == pytest.approx(g[1], abs=1e-9)
    # against the edge's true slope (a function of azimuth only) at the well-measured pixels
    px = 2 * math.pi / W  # rad per panorama px
    az = pano_angles(W)[0]
    s = 4 * (az - EDGE_AZ) / EDGE_WIDTH
    slope = EDGE_STEP * 4 / EDGE_WIDTH * np.exp(-s) / (1 + np.exp(-s)) ** 2 * px  # log units per px
    good = (info[..., 5] >= 5) & (slope[None, :] > 0.05)
    assert good.sum() >= 20
    np.testing.assert_allclose(gu[good], np.broadcast_to(slope, good.shape)[good], rtol=0.1)
    assert np.abs(gv[good]).max() < 0.02  # no vertical gradient


# -- the operator -------------------------------------------------------------------
def _op(**kw):
    return PoissonMosaic(**{**PoissonMosaic.conformance_params, **kw})


def test_batch_invariance():
    streams = PoissonMosaic.conformance_stream()
    assert_batch_invariant(lambda: _op(), streams, max_examples=10)


def test_the_mosaic_of_a_grating_is_the_grating():
    streams = rotating_camera_stream(120_000, SENSOR, F, omega=(0.0, 1.0, 0.0), circle_rad=0.15)
    op = _op(pano_width=128, emit_us=10**9, contrast=0.2)
    out = feed_ports(op, {k: [v] for k, v in streams.items()})
    assert len(out) == 1 and out[0].t[0] == 120_000 - 1
    img = out[0].image[0]
    assert img.shape == (64, 128) and img.dtype == np.float32
    az, el = pano_angles(128)
    truth = np.sin(15 * az)[None, :] * np.cos(15 * el)[:, None]
    seen = np.isfinite(img)
    assert 0.03 < seen.mean() < 0.2
    assert pearson(img, truth) > 0.9
    np.testing.assert_array_equal(out[0].pose[0], [0, 0, 0, 0, 0, 0, 1])
    assert (out[0].confidence[0][~seen] == 0).all()


def test_emits_every_emit_us_and_at_the_end():
    streams = PoissonMosaic.conformance_stream()  # 30 ms
    out = feed_ports(_op(emit_us=12_000), {k: [v] for k, v in streams.items()})
    assert [int(o.t[0]) for o in out] == [11_999, 23_999, 29_999]
    assert [(o.t_start, o.t_end) for o in out] == [(0, 12_000), (12_000, 24_000), (24_000, 30_000)]


def test_events_outside_the_poses_are_counted_not_mapped():
    streams = PoissonMosaic.conformance_stream()
    ev, poses = streams["events"], streams["poses"]
    late = poses.slice_time(8_000, 20_001)  # poses from 8 ms to 20 ms only
    op = _op(emit_us=10**9)
    out = feed_ports(op, {"events": [ev], "poses": [late]})
    before = int((ev.t < 8_000).sum())
    after = int((ev.t > 20_000).sum())
    assert before > 0 and after > 0
    assert op.counts["before_poses"] == before and op.counts["after_poses"] == after
    assert op.counts["mapped"] == len(ev) - before - after
    # the same as feeding only the covered events
    ref_op = _op(emit_us=10**9)
    ref = feed_ports(ref_op, {"events": [ev.slice_time(8_000, 20_001)], "poses": [late]})
    np.testing.assert_array_equal(ref_op.info, op.info)
    np.testing.assert_array_equal(out[-1].image, ref[-1].image)


def test_a_pose_stream_that_never_starts_maps_nothing():
    streams = PoissonMosaic.conformance_stream()
    empty = PosePacket(np.empty(0, np.int64), position=np.empty((0, 3)), orientation=np.empty((0, 4)),
                       t_start=0, t_end=30_000)
    op = _op()
    assert feed_ports(op, {"events": [streams["events"]], "poses": [empty]}) == []
    assert op.counts["before_poses"] == len(streams["events"]) and op.counts["mapped"] == 0


def _poses(t, q):
    return PosePacket(np.asarray(t, np.int64), position=np.zeros((len(t), 3)), orientation=np.asarray(q, float))


def test_bad_poses_are_refused_naming_the_sample():
    ident = [0, 0, 0, 1.0]
    with pytest.raises(PacketError, match=r"decrease at index 2: 1000 then 500"):  # the packet itself
        _poses([0, 1000, 500], [ident] * 3)
    with pytest.raises(ValueError, match=r"increase strictly; a pose at t=1000 µs follows one at t=1000 µs"):
        _op().process_ports({"poses": _poses([0, 1000, 1000], [ident] * 3)})
    op = _op()
    op.process_ports({"poses": _poses([0, 1000], [ident] * 2)})
    with pytest.raises(ValueError, match=r"increase strictly; a pose at t=1000 µs follows one at t=1000 µs"):
        op.process_ports({"poses": _poses([1000], [ident])})  # across packets too
    with pytest.raises(ValueError, match=r"orientation at t=1000 µs .* not finite"):
        _op().process_ports({"poses": _poses([0, 1000], [ident, [0, 0, np.nan, 1]])})
    with pytest.raises(ValueError, match=r"orientation at t=0 µs has norm 2"):
        _op().process_ports({"poses": _poses([0], [[0, 0, 0, 2.0]])})


def test_without_a_poses_port_the_pipeline_says_so_before_running():
    p = Pipeline()
    p.source(ListSource([PoissonMosaic.conformance_stream()["events"]]), id="cam")
    p.op("map.poisson_mosaic", "cam", id="mosaic", calib=CALIB)
    p.sink("null:", "mosaic")
    with pytest.raises(PipelineError, match=r"required port\(s\) 'poses' \(poses\) not connected"):
        p.validate()


def test_parameters_are_checked():
    with pytest.raises(ValueError, match="pano_width must be even"):
        _op(pano_width=101)
    with pytest.raises(ValueError, match="needs calib="):
        PoissonMosaic()


# -- the user's path: an ECD-layout folder from the simulator -----------------------------
def _scene():
    """The simulator's rotation scene with a fast circling motion, so that
    100 ms see every gradient direction."""
    from tectum.sources.simulate import load_scene

    scene = load_scene("rotation", "96x72")
    scene["motion"] = {"rotation_amplitude": [0.06, 0.08, 0.03], "rotation_freq_hz": [5, 4, 3]}
    return scene


def _ecd_folder(tmp_path, scene, duration_us):
    from tectum.sources.simulate import simulate

    ev, truth = simulate(scene, duration_us, seed=3)
    f, cx, cy = truth["camera"]
    np.savetxt(tmp_path / "events.txt", np.column_stack([ev.t / 1e6, ev.x, ev.y, (ev.p > 0).astype(int)]),
               fmt=["%.6f", "%d", "%d", "%d"])
    gt = np.column_stack([truth["pose_t"] / 1e6, truth["pose_position"], truth["pose_orientation"]])
    np.savetxt(tmp_path / "groundtruth.txt", gt, fmt=["%.6f"] + ["%.9f"] * 7)
    (tmp_path / "calib.txt").write_text(f"{f} {f} {cx} {cy} 0 0 0 0 0\n")
    return truth


def test_from_the_command_line_on_an_ecd_folder(tmp_path):
    from tectum.sources.simulate.scenes import compile_scene

    scene = _scene()
    truth = _ecd_folder(tmp_path, scene, 100_000)
    out = tmp_path / "pano.npz"
    run = subprocess.run([sys.executable, "-m", "tectum", "run", str(tmp_path / "events.txt"), "--op",
                          "map.poisson_mosaic:pano_width=512,emit_us=60000", "--sink", str(out)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    z = np.load(out)
    assert z["maps_image"].shape == (2, 256, 512) and list(z["maps_t"]) == [59_999, 99_999]
    img = z["maps_image"][-1]
    truth_pano = truth_panorama(compile_scene(scene), 512, quat_to_rot(truth["pose_orientation"][0]))
    assert np.isfinite(img).sum() > 4000
    assert pearson(img, truth_pano) > 0.75  # 0.86 measured (a 96x72 sensor for 0.1 s)
