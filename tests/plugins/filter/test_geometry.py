import numpy as np
import pytest

from tectum.plugins.filter import Downsample, Flip, Roi, Rotate
from tectum.testing import assert_batch_invariant, feed


def test_roi_crop_and_select(make_pattern):
    ev = make_pattern()
    out = feed(Roi(x0=4, y0=2, width=10, height=5), [ev])[0]
    sel = (ev.x >= 4) & (ev.x < 14) & (ev.y >= 2) & (ev.y < 7)
    assert out.sensor == (10, 5)
    assert np.array_equal(out.x, ev.x[sel] - 4) and np.array_equal(out.y, ev.y[sel] - 2)
    out.validate()
    nocrop = feed(Roi(x0=4, y0=2, width=10, height=5, crop=False), [ev])[0]
    assert nocrop.sensor == ev.sensor and np.array_equal(nocrop.x, ev.x[sel])
    with pytest.raises(ValueError):
        feed(Roi(x0=30), [ev])


def test_flip(make_pattern):
    ev = make_pattern()
    out = feed(Flip(horizontal=True, vertical=True), [ev])[0]
    assert np.array_equal(out.x, 23 - ev.x.astype(int)) and np.array_equal(out.y, 15 - ev.y.astype(int))
    sig = ev.columns["noise"] == 0
    assert np.allclose(out.columns["vx"][sig], -ev.columns["vx"][sig])
    twice = feed(Flip(), feed(Flip(), [ev]))[0]
    assert np.array_equal(twice.x, ev.x)


@pytest.mark.parametrize("deg", [90, 180, 270])
def test_rotate_quarters(make_pattern, deg):
    ev = make_pattern()
    out = feed(Rotate(deg), [ev])[0]
    out.validate()
    w, h = ev.sensor
    x, y = ev.x.astype(int), ev.y.astype(int)
    exp = {90: (h - 1 - y, x), 180: (w - 1 - x, h - 1 - y), 270: (y, w - 1 - x)}[deg]
    assert np.array_equal(out.x, exp[0]) and np.array_equal(out.y, exp[1])
    assert out.sensor == ((h, w) if deg % 180 else (w, h))
    # four quarter turns are the identity
    back = [ev]
    for _ in range(4):
        back = feed(Rotate(90), back)
    assert np.array_equal(back[0].x, ev.x) and np.array_equal(back[0].y, ev.y)


def test_rotate_any_angle(make_pattern):
    ev = make_pattern()
    out = feed(Rotate(30.0), [ev])[0]
    out.validate()
    assert 0 < len(out) < len(ev)
    cx, cy = 11.5, 7.5
    a = np.radians(30.0)
    exp_x, exp_y = [], []
    for x, y in zip(ev.x.tolist(), ev.y.tolist()):
        nx = round(np.cos(a) * (x - cx) - np.sin(a) * (y - cy) + cx)
        ny = round(np.sin(a) * (x - cx) + np.cos(a) * (y - cy) + cy)
        if 0 <= nx < 24 and 0 <= ny < 16:
            exp_x.append(nx)
            exp_y.append(ny)
    assert np.array_equal(out.x, exp_x) and np.array_equal(out.y, exp_y)


def test_downsample(make_pattern):
    ev = make_pattern()
    out = feed(Downsample(5), [ev])[0]
    out.validate()
    assert out.sensor == (5, 4) and np.array_equal(out.x, ev.x // 5) and np.array_equal(out.y, ev.y // 5)


def test_batch_invariant(make_pattern):
    ev = make_pattern()
    for f in (lambda: Roi(x0=3, y0=1, width=9), lambda: Flip(), lambda: Rotate(90), lambda: Rotate(15),
              lambda: Downsample(3)):
        assert_batch_invariant(f, ev, max_examples=4)
