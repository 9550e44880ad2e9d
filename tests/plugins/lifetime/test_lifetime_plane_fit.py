"""lifetime.plane_fit: accuracy against 1/|normal speed|, frames, invariance."""

from __future__ import annotations

import numpy as np

from tectum import FramePacket, concat
from tectum.evaluation.metrics import lifetime_errors
from tectum.evaluation.scenes import translating_edges
from tectum.plugins.lifetime import PlaneFitLifetime
from tectum.testing import assert_batch_invariant, feed


def _edges(speed, duration_us=60_000, noise_hz=1.0):
    v = speed * np.array([0.8, 0.6])
    return translating_edges((64, 64), duration_us, v[0], v[1], angles_deg=(37,), spacing_px=16,
                             contrast=(0.5, 0.5), threshold=0.5, blur_px=0, jitter_us=300, noise_hz=noise_hz, seed=1)


def test_lifetime_is_time_to_cross_one_pixel():
    for speed in (300.0, 1000.0):
        pkt = _edges(speed)
        out = PlaneFitLifetime().process(pkt.without_columns("lifetime"))[0]
        e = lifetime_errors(out["lifetime"], pkt["lifetime"], pkt["noise"])
        assert e["median_rel_pct"] < 10 and e["density"] > 0.8, (speed, e)
        assert e["noise_valid"] < 0.2


def test_lifetime_frames_show_events_while_alive():
    pkt = _edges(300.0, duration_us=40_000, noise_hz=0.0).without_columns("lifetime")
    outs = feed(PlaneFitLifetime(frame_us=10_000), [pkt])
    frames = [q for q in outs if isinstance(q, FramePacket)]
    ev = concat([q for q in outs if not isinstance(q, FramePacket)])
    f = concat(frames)
    assert f.t.tolist() == [0, 10_000, 20_000, 30_000, 40_000]
    # brute force: a pixel shows the polarity of its latest valid event still alive at T
    for T, img in zip(f.t.tolist(), f.images):
        exp = np.zeros_like(img)
        m = (ev.t < T) & np.isfinite(ev["lifetime"])
        for t, x, y, p, life in zip(ev.t[m], ev.x[m], ev.y[m], ev.p[m], ev["lifetime"][m]):
            exp[y, x] = p if t + np.ceil(life) > T else 0
        np.testing.assert_array_equal(img, exp)
    assert np.abs(f.images[2]).sum() > 100


def test_batch_invariance_with_frames():
    pkt = _edges(500.0, duration_us=20_000, noise_hz=20.0).without_columns("lifetime")
    pkt = pkt.select((pkt.x < 32) & (pkt.y < 24))
    assert_batch_invariant(lambda: PlaneFitLifetime(frame_us=3000), pkt, max_examples=5)


def test_first_event_of_a_crossing_fixes_blurred_edges():
    """Blurred edges and a low threshold: several events per pixel crossing.
    The surface of last events lags behind the edge (lifetimes far too
    short); keeping each crossing's first event (burst_us) removes that."""
    pkt = translating_edges((64, 64), 60_000, 400.0, 300.0, angles_deg=(37,), spacing_px=16, contrast=(0.6, 0.8),
                            threshold=0.1, blur_px=1.5, jitter_us=100, noise_hz=1.0, seed=1)
    plain = PlaneFitLifetime().process(pkt.without_columns("lifetime"))[0]
    burst = PlaneFitLifetime(burst_us=2000).process(pkt.without_columns("lifetime"))[0]
    p = lifetime_errors(plain["lifetime"], pkt["lifetime"], pkt["noise"])
    b = lifetime_errors(burst["lifetime"], pkt["lifetime"], pkt["noise"])
    assert p["median_rel_pct"] > 30 and b["median_rel_pct"] < 5 and b["density"] > 0.9, (p, b)
    assert b["noise_valid"] < 0.25


def test_batch_invariance_with_bursts():
    pkt = translating_edges((32, 24), 20_000, 400.0, 300.0, angles_deg=(37,), spacing_px=10, contrast=(0.6, 0.8),
                            threshold=0.1, blur_px=1.5, jitter_us=100, noise_hz=20.0, seed=2).without_columns("lifetime")
    assert_batch_invariant(lambda: PlaneFitLifetime(burst_us=2000), pkt, max_examples=4)
