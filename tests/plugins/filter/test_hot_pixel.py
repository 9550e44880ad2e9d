import numpy as np
import pytest

from tectum import EventPacket, concat
from tectum.plugins.filter import HotPixel
from tectum.testing import assert_batch_invariant, feed


def with_hot_pixels(ev, pixels, rate_hz=2000.0, seed=3):
    """``ev`` plus pixels firing at ``rate_hz`` (labelled noise)."""
    rng = np.random.default_rng(seed)
    dur = ev.t_end - ev.t_start
    ts, xs, ys = [ev.t], [ev.x], [ev.y]
    for x, y in pixels:
        n = rng.poisson(rate_hz * dur / 1e6)
        ts.append(rng.integers(ev.t_start, ev.t_end, n))
        xs.append(np.full(n, x))
        ys.append(np.full(n, y))
    t = np.concatenate(ts)
    order = np.argsort(t, kind="stable")
    n_extra = len(t) - len(ev)
    p = np.concatenate([ev.p, np.ones(n_extra, np.int8)])
    noise = np.concatenate([ev.columns["noise"], np.ones(n_extra, np.uint8)])
    return EventPacket.from_arrays(t[order], np.concatenate(xs)[order], np.concatenate(ys)[order], p[order],
                                   sensor=ev.sensor, t_start=ev.t_start, t_end=ev.t_end,
                                   columns={"noise": noise[order]})


def reference(ev, learn_us, factor, min_events):
    end = ev.t_start + learn_us
    counts = {}
    for x, y, t in zip(ev.x.tolist(), ev.y.tolist(), ev.t.tolist()):
        if t < end:
            counts[(x, y)] = counts.get((x, y), 0) + 1
    mean = sum(counts.values()) / len(counts)
    hot = {q for q, c in counts.items() if c >= min_events and c > max(min_events, factor * mean)}
    return np.array([t < end or (x, y) not in hot for x, y, t in zip(ev.x.tolist(), ev.y.tolist(), ev.t.tolist())])


def test_learns_and_masks_hot_pixels(make_pattern):
    ev = with_hot_pixels(make_pattern(noise_hz=5.0), [(3, 4), (20, 10)])
    op = HotPixel(learn_us=20_000, factor=5.0)
    out = concat(feed(op, [ev]))
    assert sorted(op.hot_list) == [(3, 4), (20, 10)]
    late = out.t >= 20_000
    assert not np.any((out.x[late] == 3) & (out.y[late] == 4))
    assert np.array_equal(out.t, ev.t[reference(ev, 20_000, 5.0, 5)])


def test_drop_while_learning(make_pattern):
    ev = make_pattern()
    out = concat(feed(HotPixel(learn_us=10_000, learning="drop"), [ev]))
    assert out.t.min() >= 10_000


def test_batch_invariant(make_pattern):
    ev = with_hot_pixels(make_pattern(noise_hz=5.0), [(3, 4)])
    assert_batch_invariant(lambda: HotPixel(learn_us=20_000, factor=5.0), ev, max_examples=8)


def test_rejects_bad_parameters():
    with pytest.raises(ValueError):
        HotPixel(learning="keep")  # type: ignore[arg-type]
