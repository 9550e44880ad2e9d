"""The blink kernels against slow, obvious references."""

from __future__ import annotations

import numpy as np

from tectum import EventPacket
from tectum.calibration._blink import blobs, dominant_period, still_spans, transition_map


def reference_transitions(ev: EventPacket, period_us: float, duty: float = 0.5, tol: float = 0.25):
    w, h = ev.sensor
    trans, weight = np.zeros((h, w), int), np.zeros((h, w), int)
    on = duty * period_us
    for x in range(w):
        for y in range(h):
            sel = (ev.x == x) & (ev.y == y)
            last, burst = None, 0
            for t, p in zip(ev.t[sel], ev.p[sel], strict=True):
                if p > 0:
                    last = t if burst == 0 else last  # the burst's first ON event
                    burst += 1
                    continue
                if last is not None and (1 - tol) * on <= t - last <= (1 + tol) * on:
                    trans[y, x] += 1
                    weight[y, x] += burst
                last, burst = None, 0
    return trans, weight


def random_blinks(seed: int, n: int = 3000) -> EventPacket:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 200_000, n))
    # bursts: ON, then OFF about 2 ms later at the same pixel, among random noise
    x, y, p = rng.integers(0, 6, n), rng.integers(0, 5, n), np.where(rng.random(n) < 0.5, 1, -1)
    k = rng.integers(0, n - 40, 300)
    t2 = t.copy()
    t2[k + 30] = t2[k] + 2000
    order = np.argsort(t2, kind="stable")
    x[k + 30], y[k + 30], p[k], p[k + 30] = x[k], y[k], 1, -1
    return EventPacket.from_arrays(t2[order], x[order], y[order], p[order], sensor=(6, 5))


def test_transition_map_equals_reference() -> None:
    for seed in range(3):
        ev = random_blinks(seed)
        tr, wt = transition_map(ev, 4000.0)
        rt, rw = reference_transitions(ev, 4000.0)
        assert tr.sum() > 10
        np.testing.assert_array_equal(tr, rt)
        np.testing.assert_array_equal(wt, rw)


def square_blink(period: float, duration: int, pixels: list[tuple[int, int]], sensor=(20, 10),
                 on_events: int = 3, spread_us: float = 5.0) -> EventPacket:
    ts, xs, ys, ps = [], [], [], []
    for k in range(int(duration // period)):
        t0 = k * period
        for x, y in pixels:
            for e in range(on_events):
                ts += [t0 + spread_us * e, t0 + period / 2 + spread_us * e]
                xs += [x, x]
                ys += [y, y]
                ps += [1, -1]
    order = np.argsort(ts, kind="stable")
    return EventPacket.from_arrays(np.round(np.array(ts)[order]).astype(np.int64), np.array(xs)[order],
                                   np.array(ys)[order], np.array(ps)[order], sensor=sensor)


def test_dominant_period_and_blob_centroid() -> None:
    ev = square_blink(2_500.0, 100_000, [(3, 3), (4, 3), (4, 4), (12, 6)])
    assert abs(dominant_period(ev) - 2_500.0) < 5
    smeared = square_blink(4_000.0, 100_000, [(3, 3)], on_events=4, spread_us=300.0)  # bursts 900 µs long
    assert abs(dominant_period(smeared) - 4_000.0) < 10
    tr, wt = transition_map(ev, 2_500.0)
    assert tr[3, 3] == 40 and wt[3, 3] == 120
    b = blobs(tr, wt, 40, min_pixels=1)
    assert len(b) == 2
    np.testing.assert_allclose(b.xy[0], [(3 + 4 + 4) / 3, (3 + 3 + 4) / 3])
    np.testing.assert_array_equal(b.pixels, [3, 1])
    assert len(blobs(tr, wt, 40)) == 1  # one-pixel blobs are noise by default
    assert len(blobs(*transition_map(ev, 1_000.0), 100)) == 0  # the wrong period finds nothing


def test_still_spans_split_at_a_move() -> None:
    a = square_blink(2_000.0, 100_000, [(3, 3), (4, 3), (4, 4)])
    b = square_blink(2_000.0, 100_000, [(13, 6), (14, 6), (14, 7)])
    moved = EventPacket.from_arrays(np.concatenate([a.t, b.t + 120_000]), np.concatenate([a.x, b.x]),
                                    np.concatenate([a.y, b.y]), np.concatenate([a.p, b.p]), sensor=(20, 10))
    spans = still_spans(moved, 2_000.0)
    assert len(spans) == 2
    assert 0 <= spans[0][0] and spans[0][1] <= 100_000 and 120_000 <= spans[1][0] and spans[1][1] <= 220_000
