import numpy as np
import pytest

from tectum.plugins.filter import Refractory
from tectum.testing import assert_batch_invariant, feed


def reference(ev, period):
    last = {}
    keep = []
    for t, x, y in zip(ev.t.tolist(), ev.x.tolist(), ev.y.tolist()):
        ok = (x, y) not in last or t - last[(x, y)] >= period
        if ok:
            last[(x, y)] = t
        keep.append(ok)
    return np.array(keep, bool)


@pytest.mark.parametrize("period", [0, 1000, 20_000])
def test_matches_reference(make_pattern, period):
    ev = make_pattern()
    out = feed(Refractory(period_us=period), [ev])[0]
    assert np.array_equal(out.t, ev.t[reference(ev, period)])


def test_batch_invariant(make_pattern):
    assert_batch_invariant(lambda: Refractory(period_us=5000), make_pattern(), max_examples=8)
