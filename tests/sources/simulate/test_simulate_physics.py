"""Physics of the simulator: noise statistics, edges, rotation, depth, DAVIS."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tectum.sources.simulate import simulate


def static(intensity: float, w: int = 32, h: int = 24) -> dict:
    return {"sensor": [w, h], "background": {"intensity": intensity}}


def test_ideal_static_scene_gives_no_events():
    ev, _ = simulate("static", 200_000, sensor="32x24", preset="ideal")
    assert len(ev) == 0


@pytest.mark.parametrize("intensity", [0.0, 0.6])
def test_shot_noise_rate_within_poisson_bounds(intensity):
    hz, gain, T = 5.0, 2.0, 500_000
    ev, _ = simulate(static(intensity), T, seed=4, shot_noise_hz=hz, dark_gain=gain)
    mu = hz * (1 + gain * (1 - intensity)) * 32 * 24 * T * 1e-6
    assert abs(len(ev) - mu) < 5 * math.sqrt(mu)
    assert np.all(ev["noise"] == 1) and np.all(ev["object_id"] == -1) and np.all(np.isnan(ev["vx"]))
    on = int((ev.p == 1).sum())
    assert abs(on - len(ev) / 2) < 5 * math.sqrt(len(ev) / 4)


def test_hot_pixels_and_leak_rates():
    T = 500_000
    ev, _ = simulate(static(0.5), T, seed=1, hot_fraction=0.01, hot_hz=100.0)
    hot = np.unique(ev.y.astype(int) * 32 + ev.x)
    assert len(hot) == round(0.01 * 32 * 24) and np.all(ev["noise"] == 2) and np.all(ev.p == 1)
    mu = 100.0 * len(hot) * T * 1e-6
    assert abs(len(ev) - mu) < 5 * math.sqrt(mu)
    ev, _ = simulate(static(0.5), T, seed=1, leak_hz=2.0)  # period 0.5 s: exactly one per pixel
    assert np.all(ev["noise"] == 3)
    assert np.array_equal(np.bincount(ev.y.astype(int) * 32 + ev.x, minlength=32 * 24), np.ones(32 * 24))


def edge_scene(angle_deg: float, v: tuple[float, float]) -> dict:
    return {"sensor": [48, 32], "background": {"intensity": 0.2},
            "objects": [{"shape": "edge", "position": [8.0, 16.0], "angle_deg": angle_deg, "velocity": list(v),
                         "intensity": 0.8}]}


def edge_log_intensity(x, y, t_s, angle_deg, v, eps=1e-3):
    """The analytic log intensity of the anti-aliased edge (as rendered)."""
    a = math.radians(angle_deg)
    lx = math.cos(a) * (x - 8.0 - v[0] * t_s) + math.sin(a) * (y - 16.0 - v[1] * t_s)
    cov = np.clip(0.5 - lx, 0.0, 1.0)
    return np.log(0.2 + 0.6 * cov + eps)


def test_translating_edge_obeys_linearised_model_and_truth_flow():
    ang, v, c = 20.0, (100.0, 30.0), 0.2
    ev, _ = simulate(edge_scene(ang, v), 200_000, c_on=c, c_off=c)
    assert len(ev) > 500
    assert np.all(ev.p == 1)  # bright side advancing: only ON events
    np.testing.assert_array_equal(ev["vx"], np.float32(v[0]))
    np.testing.assert_array_equal(ev["vy"], np.float32(v[1]))
    assert np.all(ev["object_id"] == 1)
    # pixels the edge fully crossed: floor(dL / C) events each
    per_pix = np.bincount(ev.y.astype(int) * 48 + ev.x, minlength=48 * 32).reshape(32, 48)
    n = math.floor((math.log(0.8 + 1e-3) - math.log(0.2 + 1e-3)) / c)
    assert np.all(per_pix[2:30, 14:26] == n)
    # -grad(L) . u dt = p C between consecutive events of a pixel (gradient at the mid time)
    ratios = []
    order = np.lexsort((ev.t, ev.y, ev.x))
    x, y, t = ev.x[order].astype(float), ev.y[order].astype(float), ev.t[order].astype(float)
    for k in range(1, len(t)):
        if x[k] != x[k - 1] or y[k] != y[k - 1]:
            continue
        tm = 0.5 * (t[k] + t[k - 1]) * 1e-6
        h = 0.05
        gx = (edge_log_intensity(x[k] + h, y[k], tm, ang, v) - edge_log_intensity(x[k] - h, y[k], tm, ang, v)) / (2 * h)
        gy = (edge_log_intensity(x[k], y[k] + h, tm, ang, v) - edge_log_intensity(x[k], y[k] - h, tm, ang, v)) / (2 * h)
        ratios.append(-(gx * v[0] + gy * v[1]) * (t[k] - t[k - 1]) * 1e-6 / c)
    ratios = np.array(ratios)
    assert len(ratios) > 300
    assert abs(np.median(ratios) - 1) < 0.03
    assert np.mean(np.abs(ratios - 1) < 0.15) > 0.9
    # lifetime: time to move one pixel along the normal
    vn = abs(v[0] * math.cos(math.radians(ang)) + v[1] * math.sin(math.radians(ang)))
    assert np.median(ev["lifetime"]) == pytest.approx(1e6 / vn, rel=0.02)


def test_rotation_truth_matches_rotational_flow_formula():
    w = np.array([0.2, -0.5, 0.3])
    scene = {"sensor": [48, 36], "fov_deg": 70,
             "panorama": {"texture": {"kind": "noise", "size": 512, "contrast": 0.6}},
             "motion": {"angular_velocity": w.tolist()}}
    ev, truth = simulate(scene, 60_000, pose_rate_hz=500)
    np.testing.assert_allclose(truth["pose_angular_velocity"], np.tile(w, (30, 1)), atol=1e-6)
    assert len(ev) > 1000
    f, cx, cy = truth["camera"]
    x, y = (ev.x - cx) / f, (ev.y - cy) / f
    u = f * (-w[1] + w[2] * y + w[0] * x * y - w[1] * x * x)
    v = f * (w[0] - w[2] * x + w[0] * y * y - w[1] * x * y)
    np.testing.assert_allclose(ev["vx"], u, rtol=1e-3, atol=0.05)
    np.testing.assert_allclose(ev["vy"], v, rtol=1e-3, atol=0.05)


def test_forward_motion_depth_and_expansion_flow():
    vz, z0 = 0.5, 2.5
    scene = {"sensor": [40, 30], "planes": [{"center": [0, 0, z0], "texture": {"kind": "noise"}, "texel_m": 0.01}],
             "motion": {"velocity": [0, 0, vz]}}
    ev, truth = simulate(scene, 100_000, truth_fps=20)
    for t, d in zip(truth["frame_t"], truth["frame_depth"]):
        np.testing.assert_allclose(d, z0 - vz * t * 1e-6, rtol=1e-5)
    f, cx, cy = truth["camera"]
    # flow of a fronto-parallel plane approached at vz: (u - cx) vz / Z, at the step's time
    z = z0 - vz * ev.t * 1e-6
    np.testing.assert_allclose(ev["vx"], (ev.x - cx) * vz / z, rtol=0.01, atol=0.05)
    np.testing.assert_allclose(ev["vy"], (ev.y - cy) * vz / z, rtol=0.01, atol=0.05)


def test_led_grid_event_counts_follow_blink_frequency():
    ev, _ = simulate("led_grid", 100_000, sensor="64x48")
    ids = ev["object_id"]
    assert set(np.unique(ids)) <= set(range(0, 13))
    counts = np.bincount(ids, minlength=13)[1:]
    # every blink cycle gives the same events per LED: counts scale with frequency (50..600 Hz)
    assert counts[11] / counts[0] == pytest.approx(12, rel=0.15)


def test_imu_and_aps_from_the_trajectory():
    w = [0.0, 0.3, 0.0]
    scene = {"sensor": [32, 24], "background": {"intensity": 0.5}, "panorama": {"texture": 0.5},
             "motion": {"angular_velocity": w},
             "davis": {"imu_rate_hz": 1000, "aps_rate_hz": 100, "exposure_us": 2000}}
    _, truth = simulate(scene, 50_000)
    np.testing.assert_allclose(truth["imu_gyro"], np.tile(w, (50, 1)), atol=1e-9)
    # rotating about y keeps gravity (world +y) on the camera's y axis: specific force -g
    np.testing.assert_allclose(truth["imu_accel"], np.tile([0, -9.81, 0], (50, 1)), atol=1e-9)
    assert truth["aps_images"].shape == (5, 24, 32) and np.all(truth["aps_images"] == 128)  # 0.5 * 255
    np.testing.assert_array_equal(truth["aps_t"], np.arange(5) * 10_000 + 1000)


def test_aps_motion_blur_spreads_an_edge():
    scene = {**edge_scene(0.0, (2000.0, 0.0)), "davis": {"aps_rate_hz": 100, "exposure_us": 5000}}
    _, truth = simulate(scene, 30_000)
    row = truth["aps_images"][1, 16].astype(float)
    mid = np.sum((row > 0.2 * 255 + 3) & (row < 0.8 * 255 - 3))
    assert mid >= 8  # 2000 px/s x 5 ms = 10 px of blur (a sharp edge spans one pixel)


def test_feature_positions_follow_points_and_corners():
    X = [0.1, -0.05, 2.0]
    scene = {"sensor": [40, 30], "fov_deg": 60, "features": [X],
             "planes": [{"center": [0, 0, 3.0], "size": [1.0, 0.5], "intensity": 0.6}],
             "motion": {"velocity": [0.5, 0.0, 0.0]},
             "objects": [{"shape": "rect", "position": [10.0, 12.0], "size": [6.0, 4.0], "angle_deg": 90,
                          "velocity": [100.0, 0.0], "intensity": 0.9, "id": 4}]}
    _, truth = simulate(scene, 20_000, pose_rate_hz=1000)
    f, cx, cy = truth["camera"]
    t = truth["feature_t"] * 1e-6
    xy = truth["feature_xy"]
    assert xy.shape == (20, 1 + 4 + 4, 2)
    np.testing.assert_array_equal(truth["feature_object_id"], [0, 0, 0, 0, 0, 4, 4, 4, 4])
    # the user's point: camera translating along x at 0.5 m/s, no rotation
    np.testing.assert_allclose(xy[:, 0, 0], f * (X[0] - 0.5 * t) / X[2] + cx, atol=1e-9)
    np.testing.assert_allclose(xy[:, 0, 1], f * X[1] / X[2] + cy, atol=1e-9)
    # the plane's corners, e.g. (-0.5, -0.25, 3)
    np.testing.assert_allclose(xy[:, 1, 0], f * (-0.5 - 0.5 * t) / 3 + cx, atol=1e-9)
    np.testing.assert_allclose(xy[:, 1, 1], f * -0.25 / 3 + cy, atol=1e-9)
    # the rect turned by 90 degrees: its local (-3, -2) corner is at (+2, -3) from its centre
    np.testing.assert_allclose(xy[:, 5, 0], 10.0 + 100.0 * t + 2.0, atol=1e-9)
    np.testing.assert_allclose(xy[:, 5, 1], 12.0 - 3.0, atol=1e-9)
