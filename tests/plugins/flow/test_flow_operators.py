"""Flow operators: accuracy against analytic truth, graceful failure, batch
invariance of non-default settings, pipelines and output names."""

from __future__ import annotations

import numpy as np
import pytest

import tectum
from tectum import concat
from tectum.evaluation.metrics import flow_errors
from tectum.evaluation.scenes import translating_edges
from tectum.plugins.flow import ContrastMax, EdgeSpeed, LucasKanade, PlaneFit
from tectum.testing import ListSink, ListSource, assert_batch_invariant, feed


def _edges(speed=1000.0, angle=30.0, noise_hz=1.0, jitter_us=300.0, duration_us=60_000, sensor=(64, 64), seed=1):
    """The reference scene: straight edges (16 px apart), one event per pixel crossing."""
    v = speed * np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    return translating_edges(sensor, duration_us, v[0], v[1], angles_deg=(angle,), spacing_px=16,
                             contrast=(0.5, 0.5), threshold=0.5, blur_px=0, jitter_us=jitter_us,
                             noise_hz=noise_hz, seed=seed)


def _score(op, pkt, normal=True):
    out = concat(feed(op, [pkt.without_columns("vx", "vy")]))
    tx, ty = (pkt["nvx"], pkt["nvy"]) if normal else (pkt["vx"], pkt["vy"])
    return flow_errors(out["vx"], out["vy"], out["valid"], tx, ty, pkt["noise"]), out


def test_robust_plane_fit_beats_naive_on_noisy_jittered_edges():
    pkt = _edges()
    naive, _ = _score(PlaneFit(radius=2, n_iter=0, reject_us=1e12, max_rms=1e12), pkt)
    robust, _ = _score(PlaneFit(radius=3, robust=True), pkt)
    assert naive["median_rel_pct"] > 15  # the plain 5x5 least-squares fit is poor here
    assert robust["median_rel_pct"] < 10
    assert robust["density"] > 0.8
    assert robust["noise_valid"] < 0.2


@pytest.mark.parametrize("angle", [0.0, 45.0, 110.0])
def test_normal_flow_methods_follow_edge_orientation(angle):
    pkt = _edges(speed=300.0, angle=angle, jitter_us=50.0, duration_us=100_000)
    for op in (EdgeSpeed(), PlaneFit(), PlaneFit(radius=3, robust=True)):
        e, _ = _score(op, pkt)
        assert e["median_rel_pct"] < 15, (op, e)
        assert e["aae_deg"] < 10, (op, e)


def test_lucas_kanade_normal_flow_has_the_right_direction():
    pkt = _edges(speed=500.0, angle=37.0, jitter_us=50.0, duration_us=80_000)
    e, _ = _score(LucasKanade(radius=3, dt_us=4000, min_explained=0.0), pkt)
    assert e["density"] > 0.5 and e["aae_deg"] < 10
    assert e["median_rel_pct"] < 40  # the count-image derivatives are crude: magnitude is rough


def test_contrast_max_recovers_full_flow_of_texture_and_refuses_lone_edges():
    v = (800.0, 600.0)
    tex = translating_edges((64, 64), 40_000, *v, angles_deg=(0, 60, 120), spacing_px=12, jitter_us=100,
                            noise_hz=1.0, seed=2)
    e, _ = _score(ContrastMax(window_us=10_000, patch_px=32), tex, normal=False)
    assert e["density"] > 0.8 and e["median_rel_pct"] < 5
    lone = translating_edges((64, 64), 40_000, *v, angles_deg=(37,), spacing_px=16, jitter_us=100, seed=2)
    e, _ = _score(ContrastMax(window_us=10_000, patch_px=32), lone, normal=False)
    assert e["density"] < 0.05  # aperture problem: full flow undetermined, so invalid


def _slow_texture(duration_us=120_000, seed=3):
    """Texture at 70 px/s: 0.7 px per 10 ms window, too little to measure in one."""
    return translating_edges((64, 64), duration_us, 56.0, 42.0, angles_deg=(0, 60, 120), spacing_px=10,
                             jitter_us=100, noise_hz=1.0, seed=seed)


def test_contrast_max_grows_its_span_for_slow_patches():
    tex = _slow_texture()
    fixed, _ = _score(ContrastMax(window_us=10_000, patch_px=32, max_window_us=10_000), tex, normal=False)
    grown, out = _score(ContrastMax(window_us=10_000, patch_px=32), tex, normal=False)
    assert fixed["density"] < 0.2  # one window: no gain over no motion, refused
    assert grown["density"] > 0.6 and grown["median_rel_pct"] < 10 and grown["aae_deg"] < 5, grown
    with pytest.raises(ValueError):
        ContrastMax(window_us=10_000, max_window_us=25_000)


def _pure_noise(rate_hz=50.0):
    rng = np.random.default_rng(5)
    n = int(rate_hz * 64 * 64 * 0.05)
    t = np.sort(rng.integers(0, 50_000, n))
    return tectum.EventPacket.from_arrays(t, rng.integers(0, 64, n), rng.integers(0, 64, n),
                                          rng.integers(0, 2, n), sensor=(64, 64), t_start=0, t_end=50_000)


@pytest.mark.parametrize("make", [EdgeSpeed, PlaneFit, lambda: PlaneFit(radius=3, robust=True), LucasKanade,
                                  lambda: LucasKanade(mode="full"), ContrastMax])
def test_pure_noise_gives_few_valid_outputs(make):
    out = concat(feed(make(), [_pure_noise()]))
    assert out["valid"].mean() < 0.1
    assert np.isnan(out["vx"][~out["valid"]]).all()


def test_degrades_gracefully_when_speed_is_out_of_reach():
    # 5000 px/s with 300 µs jitter (1.5 px of jitter): few valid flows, and those not wild
    pkt = _edges(speed=5000.0, duration_us=12_000)
    e, _ = _score(PlaneFit(radius=3, robust=True), pkt)
    assert e["density"] < 0.5
    assert not e["n_scored"] or e["median_rel_pct"] < 60


@pytest.mark.parametrize("make", [lambda: PlaneFit(radius=3, robust=True), lambda: PlaneFit(burst_us=3000),
                                  lambda: LucasKanade(mode="full"),
                                  lambda: ContrastMax(window_us=5000, patch_px=16, min_events=10)])
def test_batch_invariance_of_other_settings(make):
    v = (600.0, 300.0)
    pkt = translating_edges((32, 24), 20_000, *v, angles_deg=(0, 70), spacing_px=8, jitter_us=100,
                            noise_hz=20.0, seed=4).without_columns("vx", "vy")
    assert_batch_invariant(make, pkt, max_examples=5)


def test_contrast_max_span_growth_is_batch_invariant():
    pkt = _slow_texture(duration_us=50_000, seed=5).without_columns("vx", "vy")
    pkt = pkt.select((pkt.x < 32) & (pkt.y < 32))
    assert_batch_invariant(lambda: ContrastMax(window_us=5000, patch_px=16, min_events=10, max_window_us=20_000),
                           pkt, max_examples=4)


def test_truth_columns_survive_with_other_output_names():
    pkt = _edges(speed=300.0, jitter_us=50.0, duration_us=50_000)
    out = PlaneFit(out_vx="est_vx", out_vy="est_vy", out_valid="est_ok").process(pkt)[0]
    np.testing.assert_array_equal(out["vx"], pkt["vx"])
    e = flow_errors(out["est_vx"], out["est_vy"], out["est_ok"], pkt["nvx"], pkt["nvy"], pkt["noise"])
    assert e["median_rel_pct"] < 15
    with pytest.raises(ValueError):
        PlaneFit(out_vx="x")


@pytest.mark.parametrize("name", ["flow.edge_speed", "flow.plane_fit", "flow.lucas_kanade", "flow.contrast_max"])
def test_runs_in_a_pipeline_by_name(name):
    pkt = _edges(speed=300.0, jitter_us=50.0, duration_us=40_000).without_columns("vx", "vy")
    p = tectum.Pipeline()
    s = p.source(ListSource(list(pkt.batches(500))))
    o = p.op(name, s, out_vx="fx", out_vy="fy")
    sink = ListSink()
    p.sink(sink, o)
    tectum.run(p)
    got = sink.events()
    assert len(got) == len(pkt) and {"fx", "fy", "valid"} <= set(got.column_names)
