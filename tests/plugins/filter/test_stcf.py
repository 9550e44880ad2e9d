import numpy as np
import pytest

from tectum.evaluation.metrics import binomial_pass
from tectum.plugins.filter import SpatioTemporalCorrelation, stcf_kernel
from tectum.plugins.filter._state import padded_timestamps
from tectum.testing import assert_batch_invariant, feed


def reference(ev, dt_us, k, polarity):
    """Slow and obvious: count neighbours (of the same polarity) that fired in [t - dt, t]."""
    last = {}
    keep = []
    for t, x, y, p in zip(ev.t.tolist(), ev.x.tolist(), ev.y.tolist(), ev.p.tolist()):
        c = p if polarity else 0
        n = sum(t - last.get((x + dx, y + dy, c), -10**18) <= dt_us
                for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy)
        keep.append(n >= k)
        last[(x, y, c)] = t
    return np.array(keep, bool)


@pytest.mark.parametrize("dt_us,k,polarity", [(1000, 1, False), (3000, 2, False), (3000, 3, True), (0, 1, False)])
def test_matches_reference(make_pattern, dt_us, k, polarity):
    ev = make_pattern()
    out = feed(SpatioTemporalCorrelation(dt_us=dt_us, k=k, polarity=polarity), [ev])[0]
    exp = ev.select(reference(ev, dt_us, k, polarity))
    assert np.array_equal(out.t, exp.t) and np.array_equal(out.x, exp.x) and np.array_equal(out.p, exp.p)


@pytest.mark.parametrize("polarity", [False, True])
def test_batch_invariant(make_pattern, polarity):
    assert_batch_invariant(lambda: SpatioTemporalCorrelation(dt_us=3000, k=2, polarity=polarity), make_pattern(),
                           max_examples=8)


@pytest.mark.parametrize("k,polarity", [(1, False), (2, False), (3, False), (2, True)])
def test_poisson_pass_fraction_matches_binomial(make_noise, k, polarity):
    rate, dt = 20.0, 10_000
    ev = make_noise((48, 48), rate, 1_000_000, seed=k)
    keep = np.empty(len(ev), bool)
    stcf_kernel(ev.t, ev.x, ev.y, ev.p, padded_timestamps(ev.sensor, 2 if polarity else 1), dt, k, polarity, keep)
    interior = (ev.x > 0) & (ev.x < 47) & (ev.y > 0) & (ev.y < 47) & (ev.t >= dt)
    frac = keep[interior].mean()
    expected = binomial_pass(rate / 2 if polarity else rate, dt, k)
    # about 37 000 interior events: binomial standard error < 0.003
    assert abs(frac - expected) < 0.015, (frac, expected)


def test_k1_equals_background_activity(make_pattern):
    from tectum.plugins.filter import BackgroundActivity

    ev = make_pattern()
    a = SpatioTemporalCorrelation(dt_us=2000, k=1).process(ev)[0]
    b = BackgroundActivity(dt_us=2000).process(ev)[0]
    assert np.array_equal(a.t, b.t) and np.array_equal(a.x, b.x)


@pytest.mark.parametrize("kw", [{"k": 0}, {"k": 9}, {"dt_us": -5}])
def test_rejects_bad_parameters(kw):
    with pytest.raises(ValueError):
        SpatioTemporalCorrelation(**kw)
