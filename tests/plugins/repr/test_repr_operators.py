"""Windowing rules and batch invariance of the repr operators."""

import numpy as np
import pytest

import tectum
from tectum import concat
from tectum.plugins import repr as R
from tectum.testing import ListSink, ListSource, assert_batch_invariant, feed

from helpers import bars


@pytest.fixture
def ev():
    return bars(duration_us=30_000, sensor="16x10", noise_hz=100.0, speed=300.0)


ALL = [
    lambda **w: R.EventFrame(**w), lambda **w: R.Accumulate(**w), lambda **w: R.CountImage(**w),
    lambda **w: R.TimeSurface(tau_us=5000.0, **w), lambda **w: R.Sae(**w), lambda **w: R.VoxelGrid(bins=3, **w),
    lambda **w: R.Color(**w),
]


@pytest.mark.parametrize("make", ALL)
@pytest.mark.parametrize("window", [{"window_us": 7000}, {"count": 150}])
def test_batch_invariant(ev, make, window):
    assert_batch_invariant(lambda: make(**window), ev, max_examples=4, event_by_event_check=False)


@pytest.mark.parametrize("make", ALL[:3] + ALL[5:6])
def test_event_by_event(ev, make):
    assert_batch_invariant(lambda: make(window_us=5000), ev.slice_time(0, 12_000), max_examples=1)


def test_time_windows(ev):
    w = 7000
    out = concat(feed(R.EventFrame(window_us=w), list(ev.batches(50))))
    ends = np.arange(ev.t_start + w, ev.t_end + w, w)
    # every window [a, a+w) is stamped a+w-1; full windows plus the partial last one
    assert np.array_equal(out.t, ends - 1)
    for t, img in zip(out.t, out.images):
        sl = ev.slice_time(t + 1 - w, t + 1)
        assert np.array_equal(img, R.event_frame(sl))
    assert out.images.sum() == len(ev)
    no_partial = concat(feed(R.EventFrame(window_us=w, partial=False), [ev]))
    assert len(no_partial) == (ev.t_end - ev.t_start) // w


def test_empty_windows_are_emitted_on_ticks():
    from tectum import EventPacket

    tick = EventPacket.empty((8, 6), 0, 50_000)
    out = concat(feed(R.CountImage(window_us=10_000), [tick]))
    assert list(out.t) == [9999, 19_999, 29_999, 39_999, 49_999] and out.images.sum() == 0


def test_count_windows(ev):
    c = 150
    out = concat(feed(R.CountImage(count=c), list(ev.batches(37))))
    n_full = len(ev) // c
    assert len(out) == n_full + (1 if len(ev) % c else 0)
    for k in range(n_full):
        assert out.images[k].sum() == c
        assert out.t[k] == ev.t[(k + 1) * c - 1]
    # a voxel grid over a count window spans its first to last event
    vg = concat(feed(R.VoxelGrid(count=c, bins=4), [ev]))
    sl = ev.select(np.arange(len(ev)) < c)
    assert np.allclose(vg.images[0], R.voxel_grid(sl, bins=4), atol=1e-5)


def test_time_surface_persists_across_windows(ev):
    out = concat(feed(R.TimeSurface(window_us=5000, tau_us=2000.0), [ev]))
    sae = concat(feed(R.Sae(window_us=5000), [ev]))
    for t, ts, s in zip(out.t, out.images, sae.images):
        exp = np.where(s < -(10**15), 0.0, np.exp(-(t - s.astype(float)) / 2000.0))
        assert np.allclose(ts, exp, atol=1e-6)


def test_parameters_validated():
    with pytest.raises(ValueError):
        R.EventFrame(window_us=10, count=10)
    with pytest.raises(ValueError):
        R.TimeSurface(tau_us=0)
    with pytest.raises(ValueError):
        R.Color(on="red")


def test_in_a_pipeline(ev):
    p = tectum.Pipeline()
    s = p.source(ListSource([ev]))
    o = p.op("repr.color", s, window_us=10_000)
    sink = ListSink()
    p.sink(sink, o)
    tectum.run(p)
    frames = [q for q in sink.packets if q.kind == tectum.Kind.FRAMES and len(q)]
    imgs = np.concatenate([q.images for q in frames])
    assert imgs.shape == (3, 10, 16, 3) and imgs.dtype == np.uint8
