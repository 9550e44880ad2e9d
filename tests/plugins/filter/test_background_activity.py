import numpy as np
import pytest

from tectum.evaluation.metrics import binomial_pass
from tectum.plugins.filter import BackgroundActivity, background_activity_kernel
from tectum.plugins.filter._state import padded_timestamps
from tectum.testing import assert_batch_invariant, feed


def reference(ev, dt_us):
    """Slow and obvious: keep if one of the 8 neighbours fired in [t - dt, t]."""
    last = {}
    keep = []
    for t, x, y in zip(ev.t.tolist(), ev.x.tolist(), ev.y.tolist()):
        ok = any(t - last.get((x + dx, y + dy), -10**18) <= dt_us
                 for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy)
        keep.append(ok)
        last[(x, y)] = t
    return np.array(keep, bool)


@pytest.mark.parametrize("dt_us", [0, 300, 2000])
def test_matches_reference(make_pattern, dt_us):
    stream = make_pattern()
    out = feed(BackgroundActivity(dt_us=dt_us), [stream])[0]
    exp = stream.select(reference(stream, dt_us))
    assert np.array_equal(out.t, exp.t) and np.array_equal(out.x, exp.x) and np.array_equal(out.y, exp.y)
    assert np.array_equal(out.columns["noise"], exp.columns["noise"])


def test_batch_invariant(make_pattern):
    stream = make_pattern()
    assert_batch_invariant(lambda: BackgroundActivity(dt_us=1000), stream, max_examples=10)


def test_poisson_pass_fraction_matches_binomial(make_noise):
    rate, dt = 20.0, 10_000
    ev = make_noise((48, 48), rate, 1_000_000, seed=1)
    keep = np.empty(len(ev), bool)
    background_activity_kernel(ev.t, ev.x, ev.y, padded_timestamps(ev.sensor), dt, keep)
    # interior pixels (8 real neighbours) after the first dt (neighbours' history filled)
    interior = (ev.x > 0) & (ev.x < 47) & (ev.y > 0) & (ev.y < 47) & (ev.t >= dt)
    frac = keep[interior].mean()
    expected = binomial_pass(rate, dt, k=1)
    assert abs(frac - expected) < 0.015, (frac, expected)


def test_default_keeps_signal_and_rejects_most_noise(make_pattern):
    ev = make_pattern(sensor="64x32", duration_us=200_000, noise_hz=2.0, speed=200.0)
    out = BackgroundActivity().process(ev)[0]
    noise = ev.columns["noise"] == 1
    kept_sig = (out.columns["noise"] == 0).sum() / (~noise).sum()
    assert kept_sig > 0.9
    assert binomial_pass(2.0, BackgroundActivity().dt_us, 1) < 0.1


def test_rejects_negative_dt():
    with pytest.raises(ValueError):
        BackgroundActivity(dt_us=-1)


@pytest.mark.parametrize("dt_us", [500, 2**29])  # int32 state with a moving origin; int64 state
def test_streams_longer_than_the_int32_span(dt_us):
    """Hours of events with gaps of 2^29..2^31 µs and packets spanning more
    than 2^29 µs: the state's origin moves on and the output is the slow
    reference's."""
    from tectum import EventPacket

    rng = np.random.default_rng(3)
    n = 4000
    steps = rng.integers(0, 400, n)
    steps[rng.choice(n, 12, replace=False)] = rng.choice([2**29, 2**30 + 7, 2**31 + 11], 12)
    t = np.cumsum(steps).astype(np.int64) + 2**40
    ev = EventPacket.from_arrays(t, rng.integers(0, 6, n), rng.integers(0, 5, n), rng.choice([-1, 1], n),
                                 sensor=(6, 5))
    cuts = [ev.t_start, int(t[1000]), int(t[1001]) + 1, int(t[3000]), ev.t_end]
    pieces = [ev.slice_time(a, b) for a, b in zip(cuts, cuts[1:])]
    assert max(q.duration for q in pieces) > 2**30
    out = np.concatenate([q.t for q in feed(BackgroundActivity(dt_us=dt_us), pieces)])
    exp = reference(ev, dt_us)
    assert 0 < exp.sum() < n and np.array_equal(out, ev.t[exp])
