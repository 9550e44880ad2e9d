"""Windowing rules and batch invariance of the repr operators."""

import numpy as np
import pytest

import tectum
from tectum import EventPacket, concat
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
    lambda **w: R.EventFrame(dtype="uint8", **w), lambda **w: R.Accumulate(dtype="int8", **w),
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
        assert np.allclose(ts, exp, rtol=1.25e-7, atol=0)  # within one float32 ulp


def _hot(n_hot: int):
    """``n_hot`` events on pixel (3, 2), ON but for every third, among a
    few others, over 20 ms on a 16x10 sensor."""
    from tectum import EventPacket

    rng = np.random.default_rng(1)
    n = n_hot + 40
    x = np.r_[np.full(n_hot, 3), rng.integers(0, 16, 40)]
    y = np.r_[np.full(n_hot, 2), rng.integers(0, 10, 40)]
    p = np.r_[np.where(np.arange(n_hot) % 3, 1, -1), rng.choice([-1, 1], 40)]
    order = rng.permutation(n)
    return EventPacket.from_arrays(np.sort(rng.integers(0, 20_000, n)), x[order], y[order], p[order], sensor=(16, 10))


@pytest.mark.parametrize("make, dtype, n_hot", [(R.EventFrame, "uint8", 3000), (R.EventFrame, "int16", 70_000),
                                                (R.CountImage, "uint8", 3000), (R.Accumulate, "int8", 3000)])
def test_small_dtypes_saturate(make, dtype, n_hot):
    """Each event moves its pixel towards the dtype's limit and stops there
    (a signed sum comes back from it), in event order: a slow reference."""
    ev = _hot(n_hot)  # one window: every event before 20 ms
    # in pieces the window fills the operator's state; in one packet that ends after it, the frame directly
    out = concat(feed(make(window_us=25_000, dtype=dtype), list(ev.batches(997))))
    whole = concat(feed(make(window_us=25_000, dtype=dtype), [ev.with_interval(ev.t_start, 30_000)]))
    assert np.array_equal(whole.images, out.images)
    lo, hi = np.iinfo(dtype).min, np.iinfo(dtype).max
    ref = np.zeros(out.images.shape[1:], np.int64)
    stops = 0  # events the limit stopped
    for x, y, p in zip(ev.x.tolist(), ev.y.tolist(), ev.p.tolist()):
        at = (y, x, int(p > 0)) if make is R.EventFrame else (y, x)
        v = ref[at] + (p if make is R.Accumulate else 1)
        stops += not lo <= v <= hi
        ref[at] = min(max(v, lo), hi)
    assert out.images.dtype == np.dtype(dtype) and len(out) == 1
    assert np.array_equal(out.images[0], ref)
    assert stops > 100


@pytest.mark.parametrize("make, dtype, p, limit", [(R.CountImage, "uint8", 1, 255), (R.EventFrame, "uint8", 1, 255),
                                                  (R.Accumulate, "int8", 1, 127), (R.Accumulate, "int8", -1, -128)])
def test_limit_reached_across_packets(make, dtype, p, limit):
    """A window whose last packet alone cannot reach the dtype's limit, on
    top of what the earlier packets left in it, still stops at the limit
    (the kernel skips the compares only where no pixel can reach it)."""
    def hot(t0, n):
        return EventPacket.from_arrays(np.arange(t0, t0 + n, dtype=np.int64), np.full(n, 3), np.full(n, 2),
                                       np.full(n, p), sensor=(16, 10))
    first, last = hot(0, 200), hot(5000, 100)  # 300 events on one pixel, the last 100 close the window
    out = concat(feed(make(window_us=10_000, dtype=dtype), [first.with_interval(0, 5000),
                                                            last.with_interval(5000, 10_000)]))
    at = (0, 2, 3, int(p > 0)) if make is R.EventFrame else (0, 2, 3)
    assert len(out) == 1 and out.images[at] == limit and np.count_nonzero(out.images) == 1


def test_parameters_validated():
    for bad in ("float32", "int64", "nonsense"):
        with pytest.raises(ValueError, match="dtype"):
            R.EventFrame(dtype=bad)
    with pytest.raises(ValueError, match="signed"):
        R.Accumulate(dtype="uint8")
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


@pytest.mark.parametrize("make", [R.EventFrame, R.Accumulate, R.CountImage])
def test_frames_in_several_blocks(ev, make, monkeypatch):
    """A packet that completes many windows hands its frames out in blocks
    (one packet each, back to back): the same frames as in one block, batch
    invariant."""
    from tectum.plugins.repr import operators
    from tectum.testing import assert_stream_contract

    one = concat(feed(make(window_us=1000), [ev]))
    monkeypatch.setattr(operators, "BLOCK_BYTES", 16 * 10 * 8)  # 1 or 2 frames a block
    monkeypatch.setattr(operators, "MIN_FRAMES", 1)
    out = feed(make(window_us=1000), [ev])
    assert len(out) > 5
    assert_stream_contract(out)
    both = concat(out)
    assert np.array_equal(both.t, one.t) and np.array_equal(both.images, one.images)
    assert_batch_invariant(lambda: make(window_us=1000), ev, max_examples=4, event_by_event_check=False)


def test_joined_runs_span_about_a_cache_of_frames():
    """The engine joins small packets before an image operator into runs of
    as many windows as a block of its frames holds on a JOIN_PIXELS sensor:
    about BLOCK_BYTES of frames, at least MIN_FRAMES windows within
    MAX_BLOCK_BYTES (8 windows of 8-byte pixels, 16 of 1-byte ones); a
    time surface, about JOIN_BYTES of frames and state (4 windows of its
    8-byte frames and 8-byte state: 8 MiB), so what a call sweeps is still
    in cache when the next reuses it; count windows and the operators without
    a frame size state no limit."""
    from tectum.plugins.repr import _window, operators

    per_px = {R.EventFrame(window_us=7000): 8, R.CountImage(window_us=7000, dtype="uint8"): 1,
              R.Accumulate(window_us=7000, dtype="int16"): 2}
    for op, px in per_px.items():
        fb = px * _window.JOIN_PIXELS
        want = max(1, min(operators.MAX_BLOCK_BYTES // fb, max(operators.MIN_FRAMES, operators.BLOCK_BYTES // fb)))
        assert op.join_us() == 7000 * want
    assert R.EventFrame(window_us=7000).join_us() == 56_000 and R.CountImage(dtype="uint8").join_us() == 160_000
    assert R.TimeSurface(window_us=7000).join_us() == 7000 * max(1, _window.JOIN_BYTES // (16 * _window.JOIN_PIXELS))
    assert R.TimeSurface(window_us=7000).join_us() == 28_000
    for op in (R.EventFrame(count=100), R.Sae(window_us=7000), R.Color(window_us=7000)):
        assert op.join_us() is None


class _SpansSeen(R.EventFrame):
    name = "repr.event_frame_spans_test"

    def process(self, packet):
        self.spans = [*getattr(self, "spans", []), packet.t_end - packet.t_start]
        return super().process(packet)


def test_in_a_pipeline_of_small_packets_each_call_gets_eight_windows(ev):
    pieces = [ev.slice_time(a, a + 500) for a in range(ev.t_start, ev.t_end, 500)]
    op, sink = _SpansSeen(window_us=2000), ListSink()
    p = tectum.Pipeline()
    p.sink(sink, p.op(op, p.source(ListSource(pieces))))
    tectum.run(p)
    assert max(op.spans) == 16_000 and len(op.spans) < len(pieces) // 12
    want = concat(feed(R.EventFrame(window_us=2000), [ev]))
    got = concat([q for q in sink.packets if q.kind == tectum.Kind.FRAMES])
    assert np.array_equal(got.t, want.t) and np.array_equal(got.images, want.images)


@pytest.mark.parametrize("make", [R.EventFrame, R.Accumulate, R.CountImage])
def test_the_window_in_progress_is_made_only_when_events_stay_in_it(ev, make):
    """Packets cut on the window edges fill their frames directly: the
    state image of the window in progress is never made (no zeroed 720 kB
    per run at 346x260); a cut inside a window makes it, and both give the
    frames of one array."""
    want = concat(feed(make(window_us=1000), [ev]))
    edges = [ev.slice_time(a, a + 1000) for a in range(ev.t_start, ev.t_end, 1000)]
    op = make(window_us=1000)
    got = [q for pk in edges[:-1] for q in op.process(pk)]
    assert op._flat.shape[0] == 0 and len(got) == len(edges) - 1
    got += feed(op, edges[-1:])  # the last ends at the stream's end, inside a window
    inside = [ev.slice_time(a, a + 700) for a in range(ev.t_start, ev.t_end, 700)]
    op2 = make(window_us=1000)
    got2 = feed(op2, inside)
    assert op2._flat.shape[0] == 16 * 10 * (2 if make is R.EventFrame else 1)
    for out in (concat(got), concat(got2)):
        assert np.array_equal(out.t, want.t) and np.array_equal(out.images, want.images)


def test_image_blocks_hold_at_least_eight_frames_within_8_mib():
    """A block of frames costs the same whatever it holds: an image
    operator's blocks hold what BLOCK_BYTES does, at least MIN_FRAMES
    frames within MAX_BLOCK_BYTES (346x260: 8 int32 x 2 frames, 23 of
    uint8; 640x480: 3 int32 x 2 frames; one, however big)."""
    from tectum.plugins.repr import operators

    assert operators._per_block(346 * 260 * 8) == 8 and operators._per_block(346 * 260) == 23
    assert operators._per_block(640 * 480 * 8) == 3 and operators._per_block(50_000_000) == 1
    ev = EventPacket(np.array([5, 1500], np.int64), np.array([1, 2], np.uint16), np.array([3, 4], np.uint16),
                     np.array([1, -1], np.int8), sensor=(346, 260), t_start=0, t_end=2000)
    op = R.EventFrame(window_us=1000)
    op.process(ev)
    assert op._pool.per_block == 8
