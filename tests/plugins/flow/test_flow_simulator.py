"""Accuracy regression on the simulator (translation_edges, realistic sensor).

Normal-flow methods are scored against the true normal speed 1e6/lifetime
along the true log-intensity gradient (from the simulator's truth frames),
not against the truth projected on the estimated direction. The bounds lock
today's figures with some margin (see ``tectum bench flow``): the plane fits
get the direction of the normal flow right but overestimate the speed of
these blurred edges, which fire several events per pixel crossing, unless
the surface keeps the first event of each crossing (``burst_us``).
"""

from __future__ import annotations

import numpy as np
import pytest

from tectum import concat
from tectum.evaluation.metrics import flow_errors, simulator_normal_truth
from tectum.plugins.flow import PlaneFit
from tectum.testing import feed

simulate_mod = pytest.importorskip("tectum.sources.simulate")


@pytest.fixture(scope="module")
def scene():
    ev, truth = simulate_mod.simulate("translation_edges", 200_000, seed=1, preset="realistic", sensor="160x120",
                                      truth_fps=2000.0)
    nvx, nvy = simulator_normal_truth(ev, truth["frame_t"], truth["frame_intensity"])
    return ev, nvx, nvy


def test_normal_truth_agrees_with_the_simulators_lifetime(scene):
    ev, nvx, nvy = scene
    ok = np.isfinite(nvx)
    assert ok[ev["noise"] == 0].mean() > 0.8 and not ok[ev["noise"] != 0].any()
    speed = np.hypot(nvx, nvy)[ok]
    # the normal flow is the projection of the full flow on the normal: |v . n| = normal speed
    proj = np.abs(ev["vx"][ok] * nvx[ok] + ev["vy"][ok] * nvy[ok]) / speed
    assert np.median(np.abs(proj / speed - 1)) < 0.01
    np.testing.assert_allclose(speed, 1e6 / ev["lifetime"][ok], rtol=1e-5)


def test_plane_fit_on_simulated_edges(scene):
    ev, nvx, nvy = scene
    out = concat(feed(PlaneFit(), [ev.without_columns("vx", "vy")]))
    e = flow_errors(out["vx"], out["vy"], out["valid"], nvx, nvy, (ev["noise"] != 0).astype(np.uint8))
    assert e["aae_deg"] < 8 and e["median_rel_pct"] < 50, e
    assert e["density"] > 0.15 and e["noise_valid"] < 0.05, e
    robust = concat(feed(PlaneFit(radius=3, robust=True), [ev.without_columns("vx", "vy")]))
    r = flow_errors(robust["vx"], robust["vy"], robust["valid"], nvx, nvy, (ev["noise"] != 0).astype(np.uint8))
    assert r["aae_deg"] < 10 and r["density"] > 0.5, r


def test_first_event_of_a_crossing_removes_the_speed_bias(scene):
    ev, nvx, nvy = scene
    noise = (ev["noise"] != 0).astype(np.uint8)
    plain = concat(feed(PlaneFit(), [ev.without_columns("vx", "vy")]))
    burst = concat(feed(PlaneFit(burst_us=10_000), [ev.without_columns("vx", "vy")]))
    p = flow_errors(plain["vx"], plain["vy"], plain["valid"], nvx, nvy, noise)
    b = flow_errors(burst["vx"], burst["vy"], burst["valid"], nvx, nvy, noise)
    assert b["median_rel_pct"] < 12 and b["median_rel_pct"] < p["median_rel_pct"] / 2, (p, b)
    assert b["density"] > p["density"] and b["aae_deg"] < 6 and b["noise_valid"] < 0.05, b
