import numpy as np
import pytest

from tectum import EventPacket
from tectum.evaluation.metrics import binomial_pass
from tectum.plugins.filter import BackgroundActivity, background_activity_kernel
from tectum.plugins.filter._state import padded_timestamps
from tectum.testing import assert_batch_invariant, feed


def reference(ev, dt_us, rows=(-1, 0, 1)):
    """Slow and obvious: keep if one of the 8 neighbours fired in [t - dt, t]
    (of the neighbours on these rows, relative to the event's)."""
    last = {}
    keep = []
    for t, x, y in zip(ev.t.tolist(), ev.x.tolist(), ev.y.tolist()):
        ok = any(t - last.get((x + dx, y + dy), -10**18) <= dt_us
                 for dx in (-1, 0, 1) for dy in rows if dx or dy)
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
    border, (W + 2) x (H + 2) of them; int64 from a dt_us of 2^29 µs."""
    op = BackgroundActivity(dt_us=dt_us)
    op.process(EventPacket.from_arrays([5], [1], [2], [1], sensor=(7, 4)))
    assert op.last is not None and op.last.dtype == dtype and op.last.shape == (1, 6, 9)


def _dense_then_sparse(seed: int) -> EventPacket:
    """A 9x7 sensor: 3000 events 0..4 µs apart (nearly all pass a 300 µs
    window), then 600 events 0..200 µs apart (most are dropped), then
    dense again, then 1000 dense events on one column (nearly all pass,
    by the pixels above and below: none by its own row); pixels on every
    border too."""
    rng = np.random.default_rng(seed)
    steps = np.concatenate([rng.integers(0, 5, 3000), rng.integers(0, 200, 600), rng.integers(0, 5, 4000)])
    n = len(steps)
    x = rng.integers(0, 9, n)
    x[-1000:] = 4
    return EventPacket.from_arrays(np.cumsum(steps) + 10**9, x, rng.integers(0, 7, n), rng.choice([-1, 1], n),
                                   sensor=(9, 7))


@pytest.mark.parametrize("row_first", [False, True])
@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_select_kernel_either_way_keeps_what_the_reference_keeps(row_first, dtype):
    """The fused kernel, reading all 8 neighbours or its own row first, on
    dense and sparse stretches: the reference's events, in order, and
    their indices; reading its own row first, also how many a neighbour on
    their own row keeps."""
    from tectum.plugins.filter.background_activity import background_activity_select

    ev = _dense_then_sparse(seed=11)
    exp = reference(ev, 300)
    assert 0.05 < exp[3000:3600].mean() < 0.5 and exp[:3000].mean() > 0.95
    base = ev.t_start if dtype == np.int32 else 0
    last = np.full((1, 9, 11), np.iinfo(dtype).min // (1 if dtype == np.int32 else 2), dtype)
    m = len(ev)
    ot, ox, oy = np.empty(m + 1, np.int64), np.empty(m + 1, np.uint16), np.empty(m + 1, np.uint16)
    op, idx = np.empty(m + 1, np.int8), np.empty(m + 1, np.intp)
    n, by_row = background_activity_select(ev.t, ev.x, ev.y, ev.p, last, base, 300, ot, ox, oy, op, idx, True,
                                           row_first)
    assert n == exp.sum() and by_row == (reference(ev, 300, rows=(0,)).sum() if row_first else 0)
    for got, col in ((ot, ev.t), (ox, ev.x), (oy, ev.y), (op, ev.p), (idx, np.arange(m))):
        assert np.array_equal(got[:n], col[exp])


def test_the_own_row_is_read_first_after_a_packet_that_kept_most():
    """The operator reads each event's own row first on the packet after
    one that kept over 75 %, for as long as over 75 % pass by their own
    row; after a packet that did not, it reads all 8 neighbours for 16
    packets before it tries again. The reference's events across the
    switches."""
    from tectum.plugins.filter.background_activity import _ROW_FIRST_RETRY

    ev = _dense_then_sparse(seed=12)
    cuts = [int(t) for t in ev.t[::50]] + [ev.t_end]
    pieces = [ev.slice_time(a, b) for a, b in zip(cuts, cuts[1:])]
    op = BackgroundActivity(dt_us=300)
    modes, out = [], []
    for q in pieces:
        out += op.process(q)
        modes.append(op._row_first)
    exp, by_row = reference(ev, 300), reference(ev, 300, rows=(0,))
    assert np.array_equal(np.concatenate([q.t for q in out]), ev.t[exp])
    want, row_first, retry = [], False, 0
    for a, b in zip(cuts, cuts[1:]):
        i, j = np.searchsorted(ev.t, [a, b])
        if j > i:
            if row_first:
                row_first = by_row[i:j].mean() > 0.75
                retry = 0 if row_first else _ROW_FIRST_RETRY
            else:
                retry = max(retry - 1, 0)
                row_first = not retry and exp[i:j].mean() > 0.75
        want.append(row_first)
    assert modes == want
    # the column: nearly all kept, none by their own row: row_first tried once, then again 16 packets later
    assert exp[-1000:].mean() > 0.9 and sum(modes[-17:]) <= 1 and True in modes[:60]
    assert any(modes[k - 17] and not any(modes[k - 16:k]) and modes[k] for k in range(17, len(modes)))
