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


def test_the_only_pixel_that_fired_can_be_hot():
    """With a factor below 1 the one active pixel exceeds factor x the mean
    (its own count): hot when it has more than ``min_events``, not otherwise."""
    from tectum.plugins.filter.hot_pixel import hot_pixels

    counts = np.zeros((3, 4), np.int64)
    counts[1, 2] = 6
    assert hot_pixels(counts, 0.5, 5).tolist() == (counts > 0).tolist()
    assert not hot_pixels(counts, 0.5, 6).any()


def test_parameter_bounds_are_inclusive():
    """learn_us 0, any positive factor (below 1 too) and min_events 1 are
    accepted; one value outside its range is enough to be refused."""
    op = HotPixel(learn_us=0, factor=0.5, min_events=1)
    assert (op.learn_us, op.factor, op.min_events) == (0, 0.5, 1)
    for kw in ({"learn_us": -1}, {"factor": 0.0}, {"factor": -1.0}, {"min_events": 0}):
        with pytest.raises(ValueError, match="need learn_us >= 0, factor > 0 and min_events >= 1"):
            HotPixel(**kw)


def test_learned_once_a_packet_ends_after_learn_us():
    """``learned`` is False (and ``hot_list`` empty) while the stream is
    inside ``learn_us``; a packet that ends after it makes the mask, even
    when all its events came before."""
    op = HotPixel(learn_us=1000, factor=0.5, min_events=1)
    op.process(EventPacket.from_arrays([10, 20], [1, 1], [1, 1], [1, 1], sensor=(4, 3), t_start=0, t_end=999))
    assert op.learned is False and op.hot_list == []
    op.process(EventPacket.from_arrays([999], [2], [0], [1], sensor=(4, 3), t_start=999, t_end=1500))
    assert op.learned is True and op.hot_list == [(1, 1)]
