"""tracker.features: the EKLT and ICP kernels against slow references and
finite differences, accuracy on a small simulated DAVIS (rotation truth
for every corner), the maps port (no frames), the user's path from the
command line (CSV, reopened with ``tectum info``) and the missing-image
error at validation."""

from __future__ import annotations

import math
import subprocess
import sys
from functools import lru_cache

import numpy as np
import pytest

import tectum
from tectum import EventPacket, FramePacket, TrackPacket, concat
from tectum.evaluation.metrics.tracks import TrackScore, score_tracks
from tectum.plugins.tracker import FeatureTracker
from tectum.plugins.tracker._eklt import eklt_align, eklt_cost, observed_patch
from tectum.plugins.tracker._icp import icp_align
from tectum.plugins.tracker.features import image_derivatives
from tectum.sources.simulate.feature_scenes import davis_rotation, rotation_tracks
from tectum.testing import ListSink, ListSource, feed_ports

SENSOR = (120, 90)
DURATION = 300_000  # µs

# -- kernels ------------------------------------------------------------------------------------------


def _template(seed: int = 0, size: int = 31) -> np.ndarray:
    """Derivatives (5, S, S) of a smooth random log image."""
    rng = np.random.default_rng(seed)
    return image_derivatives(rng.normal(0.0, 1.0, (size, size)), sigma=2.0)


def test_observed_patch_is_the_blurred_normalised_polarity_sum():
    rng = np.random.default_rng(1)
    half, cx, cy = 4, 20, 30
    ex = rng.integers(cx - 6, cx + 7, 200).astype(np.float64)
    ey = rng.integers(cy - 6, cy + 7, 200).astype(np.float64)
    ep = rng.choice([-1.0, 1.0], 200)
    P = 2 * half + 1
    out = np.empty(P * P)
    inside = observed_patch(ex, ey, ep, 150, cx, cy, half, out)
    # reference: a histogram of the first 150 events, blurred by the 5-tap kernel with zero padding
    raw = np.zeros((P, P))
    keep = (np.abs(ex[:150] - cx) <= half) & (np.abs(ey[:150] - cy) <= half)
    np.add.at(raw, ((ey[:150][keep] - cy + half).astype(int), (ex[:150][keep] - cx + half).astype(int)),
              ep[:150][keep])
    k = np.exp(-0.5 * np.arange(-2, 3) ** 2)
    k /= k.sum()
    blurred = np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 1, raw)
    blurred = np.apply_along_axis(lambda c: np.convolve(c, k, "same"), 0, blurred)
    assert inside == keep.sum()
    assert np.allclose(out, (blurred / np.linalg.norm(blurred)).ravel(), atol=1e-6)


def predicted_patch(tmpl: np.ndarray, xref: float, yref: float, cx: int, cy: int, half: int, x: float, y: float,
                    theta: float, phi: float) -> np.ndarray:
    """EKLT's prediction ``-∇L(W(u)) · R(θ) v̂``, normalised, the slow obvious way: every patch pixel warped
    into the template (pixel (0, 0) at frame pixel (0, 0)) and its gradient sampled by scipy (bilinear)."""
    from scipy.ndimage import map_coordinates

    j, i = np.mgrid[0:2 * half + 1, 0:2 * half + 1]
    d = np.stack([(cx - half + i - x).ravel(), (cy - half + j - y).ravel()])
    R = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])
    wx, wy = np.array([[xref], [yref]]) + R @ d
    g = np.stack([map_coordinates(tmpl[c], [wy, wx], order=1, mode="constant") for c in (0, 1)])
    v = R @ np.array([math.cos(phi), math.sin(phi)])
    pred = -(g[0] * v[0] + g[1] * v[1])
    return pred / np.linalg.norm(pred)


def _quadratic_template(size: int = 31) -> np.ndarray:
    """Derivatives (5, S, S) of ``L = 0.01 x² - 0.02 y² + 0.015 x y + 0.3 x - 0.1 y``: gradients linear
    in x and y, so bilinear sampling is exact and the analytic Jacobian must match finite differences."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    a, b, c, d, e = 0.01, -0.02, 0.015, 0.3, -0.1
    one = np.ones_like(x)
    return np.stack([2 * a * x + c * y + d, 2 * b * y + c * x + e, 2 * a * one, c * one, 2 * b * one])


@pytest.mark.parametrize("rotation", [False, True])
def test_eklt_cost_is_obs_minus_prediction_and_its_jacobian_matches_finite_differences(rotation):
    tmpl = _quadratic_template()
    half, cx, cy = 5, 40, 50
    xref, yref, ox, oy = 15.3, 14.8, 0.0, 0.0  # the feature at frame pixel (15.3, 14.8) = template pixel
    q = np.array([40.2, 49.7, 0.1, 0.7]) if rotation else np.array([40.2, 49.7, 0.7])
    P = 2 * half + 1
    obs = np.random.default_rng(2).normal(size=P * P)
    obs /= np.linalg.norm(obs)
    res, J = np.empty(P * P), np.empty((P * P, len(q)))
    cost = eklt_cost(obs, tmpl, ox, oy, xref, yref, cx, cy, half, q, rotation, res, J, True)
    theta, phi = (q[2], q[3]) if rotation else (0.0, q[2])
    pred = predicted_patch(tmpl, xref, yref, cx, cy, half, q[0], q[1], theta, phi)
    assert np.allclose(res, obs - pred, atol=1e-12)
    assert math.isclose(cost, float(np.sum((obs - pred) ** 2)), rel_tol=1e-12)
    for a in range(len(q)):
        h = 1e-5
        qp, qm = q.copy(), q.copy()
        qp[a] += h
        qm[a] -= h
        rp, rm, scratch = np.empty(P * P), np.empty(P * P), np.empty((P * P, len(q)))
        eklt_cost(obs, tmpl, ox, oy, xref, yref, cx, cy, half, qp, rotation, rp, scratch, False)
        eklt_cost(obs, tmpl, ox, oy, xref, yref, cx, cy, half, qm, rotation, rm, scratch, False)
        fd = (rp - rm) / (2 * h)
        assert np.allclose(J[:, a], fd, atol=1e-6 * np.abs(fd).max() + 1e-9), a


@pytest.mark.parametrize("rotation", [False, True])
def test_eklt_align_recovers_position_and_flow_direction(rotation):
    tmpl = _template(3)
    half, xref, yref = 6, 15.0, 15.0
    true = np.array([60.4, 30.7, 0.05, 2.0]) if rotation else np.array([60.4, 30.7, 2.0])
    cx, cy = 61, 31
    theta, phi = (true[2], true[3]) if rotation else (0.0, true[2])
    obs = predicted_patch(tmpl, xref, yref, cx, cy, half, true[0], true[1], theta, phi)
    q = true.copy()
    q[:2] += (0.8, -0.6)
    if rotation:
        q[2] = 0.0
    cost = eklt_align(obs, tmpl, 0.0, 0.0, xref, yref, cx, cy, half, q, rotation, True, 30)
    assert cost < 1e-6
    assert np.allclose(q[:2], true[:2], atol=0.01)
    assert abs((q[-1] - true[-1] + math.pi) % (2 * math.pi) - math.pi) < 0.01


def _icp_reference(ev: np.ndarray, model: np.ndarray, xy: np.ndarray, half: int, max_dist: float,
                   iters: int) -> tuple[np.ndarray, float]:
    """ICP by numpy broadcasting, the slow obvious way."""
    xy = xy.astype(np.float64).copy()
    q = 0.0
    for _ in range(iters):
        d = ev - xy
        d = d[(np.abs(d) <= half).all(axis=1)]
        dist = np.linalg.norm(d[:, None, :] - model[None], axis=2)
        nn = dist.argmin(axis=1)
        best = dist[np.arange(len(d)), nn]
        inl = best <= max_dist
        q = inl.sum() / len(d) * max(0.0, 1 - best[inl].mean() / max_dist)
        step = (d[inl] - model[nn[inl]]).mean(axis=0)
        xy += step
        if step @ step < 1e-6:
            break
    return xy, q


def test_icp_matches_a_slow_reference_and_recovers_a_shift():
    # an L-shaped corner: two edges 10 px long, and events on it shifted by (0.9, -0.7) px, with noise
    arm = np.arange(0, 11, dtype=np.float64)
    model = np.concatenate([np.stack([arm, np.zeros(11)], 1), np.stack([np.zeros(10), arm[1:]], 1)])
    rng = np.random.default_rng(4)
    pick = rng.integers(0, len(model), 80)
    feature = np.array([50.0, 40.0])
    ev = model[pick] + feature + (0.9, -0.7) + rng.normal(0, 0.15, (80, 2))
    xy = feature.copy()
    q = icp_align(ev[:, 0].copy(), ev[:, 1].copy(), 80, model, len(model), 12, xy, 2.0, 20)
    ref_xy, ref_q = _icp_reference(ev, model, feature, 12, 2.0, 20)
    assert np.allclose(xy, ref_xy, atol=1e-9) and math.isclose(q, ref_q, rel_tol=1e-9)
    assert np.allclose(xy - feature, (0.9, -0.7), atol=0.1) and q > 0.8


# -- accuracy on a simulated DAVIS ------------------------------------------------------------------


@lru_cache(maxsize=1)
def _davis() -> tuple[EventPacket, FramePacket, object]:
    return davis_rotation(SENSOR, DURATION, aps_rate_hz=20.0)


def _score(tracks: TrackPacket, truth: object, margin: float = 12.0) -> TrackScore:
    def truth_fn(t0: np.ndarray, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        return rotation_tracks(truth, t0, x0, t)  # type: ignore[arg-type]

    return score_tracks(tracks.t, tracks.id, np.stack([tracks.x, tracks.y], 1), truth_fn, DURATION, SENSOR,
                        margin=margin)


def _tracks(out: list) -> TrackPacket:
    tr = concat([q for q in out if len(q)])
    assert isinstance(tr, TrackPacket)
    return tr


def test_eklt_tracks_simulated_rotation_within_half_a_pixel():
    ev, frames, truth = _davis()
    op = FeatureTracker()
    tr = _tracks(feed_ports(op, {"events": [ev], "frames": [frames]}))
    s = _score(tr, truth)
    assert s.tracks >= 30
    assert s.median_error_px <= 0.35, s  # measured 0.26 px (0.44 without extrapolating the window's middle)
    assert s.median_age_ratio >= 0.8, s
    # rows: each id starts with its detection at a frame's time, quality 1
    first = np.unique(tr.id, return_index=True)[1]
    assert set(tr.t[first].tolist()) <= set(frames.t.tolist()) and np.all(tr.quality[first] == 1.0)
    assert op.counts["detected"] == len(first) and op.counts["updates"] > 20 * len(first)


def test_icp_tracks_simulated_rotation_within_a_pixel_and_a_half():
    ev, frames, truth = _davis()
    tr = _tracks(feed_ports(FeatureTracker(method="icp"), {"events": [ev], "frames": [frames]}))
    s = _score(tr, truth)
    assert s.tracks >= 30 and s.median_error_px <= 1.5 and s.median_age_ratio >= 0.35, s  # measured 1.02 px, 0.49


def test_without_redetect_only_the_first_frame_gives_features():
    ev, frames, _ = _davis()
    op = FeatureTracker(redetect=False)
    tr = _tracks(feed_ports(op, {"events": [ev], "frames": [frames]}))
    assert set(tr.t[np.unique(tr.id, return_index=True)[1]].tolist()) == {int(frames.t[0])}
    assert op.counts["images"] == len(frames)


def test_maps_of_a_reconstruction_replace_the_frames():
    ev, _, truth = _davis()
    p = tectum.Pipeline()
    cam = p.source(ListSource([ev]), id="cam")
    hp = p.op("map.high_pass", cam, window_us=10_000)
    ft = p.op("tracker.features", events=cam, maps=hp, redetect=False)
    sink = ListSink()
    p.sink(sink, ft)
    tectum.run(p)
    s = _score(_tracks(sink.packets), truth)
    assert s.tracks >= 10 and s.median_error_px <= 1.5 and s.median_age_ratio >= 0.8, s


def test_maps_without_an_image_are_named():
    from tectum import MapPacket

    ev, _, _ = _davis()
    depth = MapPacket([5000], depth=np.ones((1, SENSOR[1], SENSOR[0]), np.float32), t_start=0, t_end=10_000)
    with pytest.raises(ValueError, match="port 'maps' have no 'image'"):
        FeatureTracker().process_ports({"events": ev.slice_time(0, 10_000), "maps": depth})


@pytest.mark.parametrize("kw, match", [({"patch_px": 24}, "patch_px must be odd"),
                                        ({"min_events": 50, "max_events": 10}, "min_events <= max_events"),
                                        ({"update_fraction": 0.0}, "update_fraction"),
                                        ({"contrast": -1.0}, "contrast must be finite")])
def test_bad_parameters_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        FeatureTracker(**kw)


# -- the user's path ------------------------------------------------------------------------------------

_SCENE = """
[panorama]
texel_deg = 0.3515625
[panorama.texture]
kind = "noise"
size = 1024
blur = 1.5
contrast = 0.6
mean = 0.35
[motion]
angular_velocity = [0.1, 0.4, 0.05]
rotation_amplitude = [0.25, 0.35, 0.2]
rotation_freq_hz = [0.7, 0.5, 0.9]
[davis]
aps_rate_hz = 20.0
exposure_us = 2000.0
"""


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tectum", *args], capture_output=True, text=True)


def test_command_line_writes_tracks_csv_that_tectum_info_reopens(tmp_path):
    (tmp_path / "scene.toml").write_text(_SCENE)
    out = tmp_path / "tracks.csv"
    src = f"simulate:{tmp_path / 'scene.toml'}?davis=true&duration_us=150000&sensor=96x72"
    r = _cli("run", src, "--op", "tracker.features:max_tracks=20", "--sink", str(out))
    assert r.returncode == 0, r.stderr
    lines = out.read_text().splitlines()
    header = next(ln for ln in lines if not ln.startswith("#"))
    assert header == "t,id,x,y,quality"
    rows = np.array([[float(v) for v in ln.split(",")] for ln in lines[lines.index(header) + 1:]])
    assert len(rows) > 100 and len(np.unique(rows[:, 1])) >= 10
    assert np.all((rows[:, 2] >= 0) & (rows[:, 2] <= 95) & (rows[:, 3] >= 0) & (rows[:, 3] <= 71))
    info = _cli("info", str(out))
    assert info.returncode == 0, info.stderr
    assert f"tracks {len(rows):,}" in info.stdout


def test_no_frames_and_no_maps_is_an_error_at_validation(tmp_path):
    r = _cli("run", "simulate:rotation?duration_us=20000&sensor=48x36", "--op", "tracker.features", "--sink",
             str(tmp_path / "t.csv"))
    assert r.returncode == 1
    assert "no image to find corners on: connect the port 'frames'" in r.stderr and "'maps'" in r.stderr
    assert "Traceback" not in r.stderr and not (tmp_path / "t.csv").exists()
