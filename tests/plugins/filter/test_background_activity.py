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
