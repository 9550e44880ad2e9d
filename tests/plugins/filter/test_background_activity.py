import numpy as np
import pytest

from tectum import EventPacket, concat
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


SPAN = 2**30  # µs: how far the int32 state's origin may lag behind a packet's end


def _across_the_span(t0: int, dt_us: int, sensor: tuple[int, int], spans: float, seed: int):
    """Events at random pixels every 0..2 dt_us µs (capped at 2^26 µs) from ``t0`` over ``spans`` x 2^30 µs, plus,
    at each origin ``b`` the filter takes (the first packet's start, then each ``b + 2^30``), events at
    ``b + 2^30 - 1``, ``b + 2^30``, ``b + 2^30 + 1`` and two neighbours exactly ``dt_us`` apart across it;
    and the packet cuts that end one packet exactly 2^30 µs after the origin (no move) and the next one
    µs past it (the origin moves to that packet's start, ``b + 2^30``)."""
    rng = np.random.default_rng(seed)
    w, h = sensor
    gap = min(2 * dt_us, 2**26)
    n = int(spans * SPAN / (gap / 2))
    t = [t0 + np.cumsum(rng.integers(0, gap, n))]
    x, y = [rng.integers(0, w, n)], [rng.integers(0, h, n)]
    cuts = [t0]
    b = t0
    while b + SPAN < t0 + spans * SPAN:
        e = b + SPAN
        t.append(np.array([e - dt_us, e - 1, e, e, e + 1]))
        x.append(np.array([1, 0, 2, *rng.integers(0, w, 2)]))
        y.append(np.array([1, 0, 1, *rng.integers(0, h, 2)]))
        cuts += [e - 1, e, e + 1]
        b = e
    tt, xx, yy = np.concatenate(t), np.concatenate(x), np.concatenate(y)
    inside = tt >= t0
    order = np.argsort(tt[inside], kind="stable")
    tt, xx, yy = tt[inside][order], xx[inside][order], yy[inside][order]
    ev = EventPacket.from_arrays(tt, xx, yy, rng.choice([-1, 1], len(tt)), sensor=sensor,
                                 t_start=t0, t_end=int(tt[-1]) + 1)
    return ev, [*cuts, ev.t_end]


@pytest.mark.parametrize("dt_us, sensor", [(1_000_000, (4, 3)), (2**32, (40, 30))])  # int32 state; int64
@pytest.mark.parametrize("packets", ["span", "one", "random"])
def test_output_around_each_move_of_the_origin(dt_us, sensor, packets):
    """Forty minutes of sparse events starting far from 0, cut into packets
    that end exactly on and one µs past each 2^30 µs span of the int32 state
    (or one packet, which the filter takes in parts, or random cuts): every
    event kept or dropped as the slow reference says, including those whose
    deciding neighbour fired before the origin moved (exactly dt_us before,
    too). With a dt_us beyond 2^31 µs (int64 state) a pixel that never fired
    stays "never"."""
    ev, cuts = _across_the_span(10**12 + 12_345, dt_us, sensor, 2.3, seed=5)
    if packets == "one":
        cuts = [ev.t_start, ev.t_end]
    elif packets == "random":
        rng = np.random.default_rng(6)
        cuts = [ev.t_start, *np.sort(rng.integers(ev.t_start, ev.t_end, 9)).tolist(), ev.t_end]
    pieces = [ev.slice_time(a, b) for a, b in zip(cuts, cuts[1:])]
    out = feed(BackgroundActivity(dt_us=dt_us), pieces)
    exp = reference(ev, dt_us)
    assert 0 < exp.sum() < len(ev)
    assert np.array_equal(np.concatenate([q.t for q in out]), ev.t[exp])
    assert np.array_equal(np.concatenate([q.x for q in out]), ev.x[exp])


def test_the_origin_moves_on_when_a_packet_ends_past_2_30_us():
    """The int32 state's origin (``base``, µs) is the first packet's start
    and moves to a packet's start once that packet ends more than 2^30 µs
    after it: not earlier (each move is a pass over the whole state), not
    later (relative times must fit in int32)."""
    t0 = 10**12 + 3
    op = BackgroundActivity(dt_us=500)
    for a, b, base in [(t0, t0 + 10, t0), (t0 + SPAN - 5, t0 + SPAN, t0), (t0 + SPAN, t0 + SPAN + 1, t0 + SPAN),
                       (t0 + 2 * SPAN - 3, t0 + 2 * SPAN, t0 + SPAN),
                       (t0 + 2 * SPAN, t0 + 2 * SPAN + 2, t0 + 2 * SPAN)]:
        op.process(EventPacket.from_arrays([b - 1], [1], [1], [1], sensor=(3, 3), t_start=a, t_end=b))
        assert op.base == base, (a - t0, b - t0)


@pytest.mark.parametrize("dt_us, dtype", [(0, np.int32), (2**29 - 1, np.int32), (2**29, np.int64)])
def test_the_state_is_one_int32_per_pixel_below_2_29_us(dt_us, dtype):
    """The memory the class promises: one int32 per pixel plus a one-pixel
    border and a second border row below (the kernel's vector loads read
    one cell past the first), (W + 2) x (H + 3) of them; int64 from a
    dt_us of 2^29 µs."""
    op = BackgroundActivity(dt_us=dt_us)
    op.process(EventPacket.from_arrays([5], [1], [2], [1], sensor=(7, 4)))
    assert op.last is not None and op.last.dtype == dtype and op.last.shape == (1, 7, 9)


def _dense_then_sparse(seed: int) -> EventPacket:
    """A 9x7 sensor: 3000 events 0..4 µs apart (nearly all pass a 300 µs
    window), then 600 events 0..200 µs apart (most are dropped), then
    dense again, then 1000 dense events on one column (nearly all pass,
    by the pixels above and below); then every pixel in turn, the corners
    and the last row and column included; pixels refire throughout."""
    rng = np.random.default_rng(seed)
    steps = np.concatenate([rng.integers(0, 5, 3000), rng.integers(0, 200, 600), rng.integers(0, 5, 4000),
                            np.full(63, 3)])
    n = len(steps)
    x, y = rng.integers(0, 9, n), rng.integers(0, 7, n)
    x[-1063:-63] = 4
    x[-63:], y[-63:] = np.arange(63) % 9, np.arange(63) // 9
    return EventPacket.from_arrays(np.cumsum(steps) + 10**9, x, y, rng.choice([-1, 1], n), sensor=(9, 7))


def _plain_keep(ev: EventPacket, dt_us: int) -> np.ndarray:
    """The plain kernel's verdicts (one read of a neighbour-time map and 8
    writes per event, no vectors, no copy)."""
    keep = np.empty(len(ev), np.bool_)
    background_activity_kernel(ev.t, ev.x, ev.y, padded_timestamps(ev.sensor), dt_us, keep)
    return keep


@pytest.mark.parametrize("vector", [True, False])
@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_select_kernel_keeps_what_the_plain_kernel_keeps(vector, dtype):
    """The kernel (the 8 neighbours as three vector compares; the copy by
    vector compress or by keep bit) on dense and sparse stretches cut into
    packets of 0..40 events (tails shorter than 16, whole blocks, packets
    that keep every event): per packet the plain kernel's keep flags, its
    count, and its events copied in order."""
    from tectum.plugins.filter.background_activity import background_activity_select

    ev = _dense_then_sparse(seed=11)
    exp = _plain_keep(ev, 300)
    assert np.array_equal(exp, reference(ev, 300))
    assert 0.05 < exp[3000:3600].mean() < 0.5 and exp[:3000].mean() > 0.95
    base = ev.t_start if dtype == np.int32 else 0
    last = np.full((1, 10, 11), np.iinfo(dtype).min // (1 if dtype == np.int32 else 2), dtype)
    cuts = np.cumsum(np.random.default_rng(4).integers(0, 41, len(ev)))
    cuts = [0, *cuts[cuts < len(ev)].tolist(), len(ev)]
    full = 0
    for i, j in zip(cuts, cuts[1:]):
        t, x, y, p, m = ev.t[i:j], ev.x[i:j], ev.y[i:j], ev.p[i:j], j - i
        keep = np.empty(m, np.bool_)
        ot, ox, oy = np.empty(m + 1, np.int64), np.empty(m + 1, np.uint16), np.empty(m + 1, np.uint16)
        op = np.empty(m + 1, np.int8)
        n = background_activity_select(t, x, y, p, last, base, 300, keep, ot, ox, oy, op, vector)
        assert np.array_equal(keep, exp[i:j]) and n == exp[i:j].sum()
        full += 0 < n == m
        if n < m:
            for got, col in ((ot, t), (ox, x), (oy, y), (op, p)):
                assert np.array_equal(got[:n], col[exp[i:j]])
    assert full > 10 and np.all(last[0, -1] == last[0, -1, 0])  # packets kept whole; the slack row never written


@pytest.mark.parametrize("packet_events", [1, 50, 10_000])
def test_operator_keeps_what_the_plain_kernel_keeps(packet_events):
    """Through ``process``: packets of one, 50 or all events, the output
    (and an extra column, gathered by the keep flags) the plain kernel's."""
    ev = _dense_then_sparse(seed=12)
    ev = ev.with_columns(index=np.arange(len(ev), dtype=np.int64))
    cuts = [int(t) for t in ev.t[::packet_events]] + [ev.t_end]
    pieces = [ev.slice_time(a, b) for a, b in zip(cuts, cuts[1:])]
    out = concat(feed(BackgroundActivity(dt_us=300), pieces))
    exp = _plain_keep(ev, 300)
    assert np.array_equal(out.columns["index"], np.flatnonzero(exp))
    assert np.array_equal(out.t, ev.t[exp]) and np.array_equal(out.x, ev.x[exp]) and np.array_equal(out.p, ev.p[exp])


def test_packets_past_one_kernel_call():
    """A packet of over 2^16 events is filtered in kernel calls of 2^16:
    the first call keeps all (not copied until the second drops some), the
    third and fourth keep all again (copied after the drop); a big packet
    kept whole comes back as itself. The plain kernel's events."""
    from tectum.plugins.filter.background_activity import _CALL_EVENTS

    rng = np.random.default_rng(7)
    dense = [rng.integers(0, 3, k) for k in (70_000, 130_000)]  # ~1 event/µs on 63 pixels: all pass 1000 µs
    steps = np.concatenate([np.ones(63, np.int64), dense[0], np.full(50, 3000), dense[1]])
    x, y = rng.integers(0, 9, len(steps)), rng.integers(0, 7, len(steps))
    x[:63], y[:63] = np.arange(63) % 9, np.arange(63) // 9  # every pixel once first
    ev = EventPacket.from_arrays(np.cumsum(steps) + 10**6, x, y, rng.choice([-1, 1], len(steps)), sensor=(9, 7))
    exp = _plain_keep(ev, 1000)
    calls = [exp[63 + a:63 + a + _CALL_EVENTS] for a in range(0, len(ev) - 63, _CALL_EVENTS)]
    assert len(calls) == 4 and calls[0].all() and not calls[1].all() and calls[2].all() and calls[3].all()
    op = BackgroundActivity(dt_us=1000)
    cut = int(ev.t[63])
    op.process(ev.slice_time(None, cut))
    out = op.process(ev.slice_time(cut, None))[0]
    assert np.array_equal(out.t, ev.t[63:][exp[63:]]) and np.array_equal(out.y, ev.y[63:][exp[63:]])
    assert np.array_equal(out.p, ev.p[63:][exp[63:]])
    whole = BackgroundActivity(dt_us=1000)
    whole.process(ev.slice_time(None, cut))
    first = ev.slice_time(cut, int(ev.t[63 + 70_000]))
    assert len(first) > _CALL_EVENTS and whole.process(first)[0] is first


def test_select_kernel_on_strided_columns():
    """Columns that are every other element of their arrays (not a public
    packet's, but the kernel's arguments allow them): the vector
    compresses give way to the plain loop, and the plain kernel's events
    come out."""
    from tectum.plugins.filter.background_activity import background_activity_select

    ev = _dense_then_sparse(seed=13)
    t, x, y, p = (np.repeat(c, 2)[::2] for c in (ev.t, ev.x, ev.y, ev.p))
    keep = np.empty(2 * len(ev), np.bool_)[::2]
    assert not t.flags.c_contiguous and not keep.flags.c_contiguous
    last = np.full((1, 10, 11), np.iinfo(np.int32).min, np.int32)
    out = [np.empty(len(ev) + 1, d) for d in (np.int64, np.uint16, np.uint16, np.int8)]
    n = background_activity_select(t, x, y, p, last, ev.t_start, 300, keep, *out, True)
    exp = _plain_keep(ev, 300)
    assert np.array_equal(keep, exp) and n == exp.sum()
    for got, col in zip(out, (ev.t, ev.x, ev.y, ev.p)):
        assert np.array_equal(got[:n], col[exp])


# -- dt_us="auto": the window learned from the stream --------------------------------
def _signal_noise(ev, out):
    noise = ev.columns["noise"] == 1
    kept = out.columns["noise"]
    return (kept == 0).sum() / (~noise).sum(), (kept == 1).sum() / noise.sum()


def test_auto_keeps_a_slow_scene_that_the_fixed_default_loses(make_pattern):
    """Bars at 100 px/s (10 ms a pixel, past the fixed 6 ms): the learned
    window keeps 90 % of the signal, and still drops most of the noise."""
    ev = make_pattern(sensor="64x48", duration_us=600_000, noise_hz=1.0, speed=100.0, seed=2)
    fixed = _signal_noise(ev, BackgroundActivity().process(ev)[0])
    op = BackgroundActivity(dt_us="auto")
    auto = _signal_noise(ev, op.process(ev)[0])
    assert fixed[0] < 0.8 and auto[0] > 0.9, (fixed, auto)
    assert auto[1] < 0.5 and 10_000 < op.dt_us < 25_000, (auto, op.dt_us)


def test_auto_window_follows_a_fast_scene(make_pattern):
    """Bars at 400 px/s (2.5 ms a pixel): a window near 3-4 ms, shorter than
    the fixed default's, so less noise passes at the same signal kept."""
    ev = make_pattern(sensor="128x96", duration_us=300_000, noise_hz=2.0, speed=400.0, seed=3)
    fixed = _signal_noise(ev, BackgroundActivity().process(ev)[0])
    op = BackgroundActivity(dt_us="auto")
    auto = _signal_noise(ev, op.process(ev)[0])
    assert auto[0] > 0.95 and auto[1] < fixed[1] - 0.05, (fixed, auto)
    assert 2_500 < op.dt_us < 6_000, op.dt_us


@pytest.mark.parametrize("sensor", [(128, 96), (64, 48)])  # 64x48: 8 % of the pixels on the border
def test_auto_on_noise_alone_keeps_the_fixed_default(make_noise, sensor):
    """Poisson noise and no motion: the noise's exponential share is taken
    out of the histogram, no signal is left, the window stays the fixed
    default's 6 ms and passes what that passes (border pixels, with fewer
    neighbours, stay out of the histogram: their slower noise would bend
    the fit). Not in the first 0.2 s or so: there the intervals are cut
    short by the stream's age, none reaches the tail yet and the window
    goes up to 50 ms."""
    ev = make_noise(sensor, 10.0, 1_000_000, seed=4)
    op = BackgroundActivity(dt_us="auto")
    windows = []
    for a in range(0, 1_000_000, 50_000):
        op.process(ev.slice_time(a, a + 50_000))
        windows.append(op.dt_us)
    assert set(windows[10:]) == {6000} and max(windows) > 6000, windows
    idx = ev.with_columns(index=np.arange(len(ev)))
    keep = np.zeros(len(ev), bool)
    keep[np.concatenate([q.columns["index"] for q in feed(BackgroundActivity(dt_us="auto"), [idx])])] = True
    interior = (ev.x > 0) & (ev.x < sensor[0] - 1) & (ev.y > 0) & (ev.y < sensor[1] - 1) & (ev.t >= 500_000)
    assert abs(keep[interior].mean() - binomial_pass(10.0, 6000, k=1)) < 0.02


def test_auto_batch_invariant(make_pattern):
    """The histogram, its tail sums and counters carry from packet to packet:
    bars at 100 px/s in 5 Hz/px noise, where the window moves from 6 ms to
    about 15 ms and the noise fit matters."""
    stream = make_pattern(sensor="64x48", duration_us=400_000, noise_hz=5.0, speed=100.0, seed=5)
    op = BackgroundActivity(dt_us="auto")
    op.process(stream)
    assert len(stream) > 40 * 256 and op.dt_us > 10_000  # the window was recomputed and moved
    assert_batch_invariant(lambda: BackgroundActivity(dt_us="auto"), stream, max_examples=10)
    split = BackgroundActivity(dt_us="auto")  # and the estimator's state ends the same
    feed(split, [stream.slice_time(a, a + 7_000) for a in range(stream.t_start, stream.t_end, 7_000)])
    for mine, theirs in ((split._hist, op._hist), (split._weight, op._weight), (split._state, op._state)):
        assert np.array_equal(mine, theirs)


def test_auto_parameter_and_memory():
    from tectum._operator import coerce_param

    assert coerce_param(BackgroundActivity, "dt_us", "auto") == "auto"
    assert coerce_param(BackgroundActivity, "dt_us", "3000") == 3000
    assert BackgroundActivity(dt_us="auto").memory_us() is None  # learned from the whole stream
    assert BackgroundActivity(dt_us=3000).memory_us() == 3000
    with pytest.raises(ValueError, match="auto"):
        BackgroundActivity(dt_us="fast")  # type: ignore[arg-type]
