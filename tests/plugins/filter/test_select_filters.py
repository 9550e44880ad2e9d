"""filter.mask, filter.polarity, filter.time_window, filter.rate_limit."""

import numpy as np
import pytest

from tectum import concat
from tectum.plugins.filter import Mask, Polarity, RateLimit, TimeWindow
from tectum.testing import assert_batch_invariant, feed


def test_mask_pixels_and_file(make_pattern, tmp_path):
    ev = make_pattern()
    f = tmp_path / "m.npy"
    m = np.zeros((16, 24), np.uint8)
    m[5, 7] = 1
    np.save(f, m)
    out = feed(Mask(pixels="1,2;3:4", path=str(f)), [ev])[0]
    bad = {(1, 2), (3, 4), (7, 5)}
    exp = np.array([(x, y) not in bad for x, y in zip(ev.x.tolist(), ev.y.tolist())])
    assert np.array_equal(out.t, ev.t[exp])
    only = feed(Mask(pixels="1,2", keep=True), [ev])[0]
    assert set(zip(only.x.tolist(), only.y.tolist())) <= {(1, 2)} and len(only)


def test_mask_text_file_and_errors(make_pattern, tmp_path):
    ev = make_pattern()
    f = tmp_path / "m.txt"
    f.write_text("0 0\n2 3\n")
    out = feed(Mask(path=str(f)), [ev])[0]
    assert not np.any((out.x == 2) & (out.y == 3))
    with pytest.raises(ValueError, match="outside"):
        feed(Mask(pixels="99,99"), [ev])
    with pytest.raises(ValueError):
        Mask(pixels="1,2,3")


def test_polarity(make_pattern):
    ev = make_pattern()
    on = feed(Polarity("on"), [ev])[0]
    off = feed(Polarity("off"), [ev])[0]
    assert np.all(on.p == 1) and np.all(off.p == -1) and len(on) + len(off) == len(ev)


def test_time_window(make_pattern):
    ev = make_pattern()
    out = concat(feed(TimeWindow(start_us=10_000, stop_us=30_000), list(ev.batches(100))))
    assert np.array_equal(out.t, ev.t[(ev.t >= 10_000) & (ev.t < 30_000)])
    assert (out.t_start, out.t_end) == (ev.t_start, ev.t_end)
    shifted = ev.with_interval(ev.t_start, ev.t_end)
    rel = concat(feed(TimeWindow(start_us=5000, relative=True), [shifted]))
    assert rel.t.min() >= ev.t_start + 5000


def rate_reference(t, rate_hz, burst):
    tokens, last, keep = float(burst), None, []
    for ti in t.tolist():
        if last is not None:
            tokens = min(float(burst), tokens + (ti - last) * rate_hz / 1e6)
        last = ti
        ok = tokens >= 1.0
        tokens -= ok
        keep.append(ok)
    return np.array(keep, bool)


def test_rate_limit_bound_and_counter(make_pattern):
    ev = make_pattern(noise_hz=500.0)
    rate, burst = 20_000.0, 50
    op = RateLimit(rate_hz=rate, burst=burst)
    out = concat(feed(op, list(ev.batches(64))))
    assert np.array_equal(out.t, ev.t[rate_reference(ev.t, rate, burst)])
    assert op.dropped == len(ev) - len(out) > 0
    # bound: any interval of T µs holds at most burst + rate T events
    for T in (100, 1000, 10_000):
        i = np.searchsorted(out.t, out.t + T, side="left") - np.arange(len(out))
        assert i.max() <= burst + rate * T / 1e6 + 1


def test_batch_invariance_of_selectors(make_pattern):
    ev = make_pattern(noise_hz=200.0)
    for factory in (lambda: Mask(pixels="1,2;5,5"), lambda: Polarity("off"),
                    lambda: TimeWindow(start_us=7000, stop_us=41_000),
                    lambda: RateLimit(rate_hz=30_000.0, burst=20)):
        assert_batch_invariant(factory, ev, max_examples=5)
