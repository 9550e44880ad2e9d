"""The plain functions (tonic style) against slow obvious references."""


import numpy as np
import pytest

from tectum.plugins import repr as R
from tectum.plugins.repr.kernels import NEVER

from helpers import bars


@pytest.fixture
def ev():
    return bars(duration_us=20_000, sensor="20x12", noise_hz=100.0, speed=300.0)


def loop(ev):
    return zip(ev.t.tolist(), ev.x.tolist(), ev.y.tolist(), ev.p.tolist())


def test_event_frame_accumulate_count(ev):
    h, w = 12, 20
    hist = np.zeros((h, w, 2), int)
    signed = np.zeros((h, w), int)
    for _, x, y, p in loop(ev):
        hist[y, x, 1 if p > 0 else 0] += 1
        signed[y, x] += p
    assert np.array_equal(R.event_frame(ev), hist)
    assert np.array_equal(R.accumulate(ev), signed)
    assert np.array_equal(R.count_image(ev), hist.sum(2))


def test_sae_and_time_surface(ev):
    ref = np.full((12, 20, 2), NEVER, np.int64)
    for t, x, y, p in loop(ev):
        ref[y, x, 1 if p > 0 else 0] = t
    assert np.array_equal(R.sae(ev), ref)
    t_ref, tau = int(ev.t[-1]), 3000.0
    ts = R.time_surface(ev, tau_us=tau, t_ref=t_ref)
    exp = np.where(ref == NEVER, 0.0, np.exp(-(t_ref - ref.astype(float)) / tau))
    assert ts.dtype == np.float32 and np.allclose(ts, exp, atol=1e-6)


def test_voxel_grid(ev):
    bins, t0, t1 = 4, int(ev.t[0]), int(ev.t[-1])
    ref = np.zeros((12, 20, bins))
    for t, x, y, p in loop(ev):
        u = (bins - 1) * (t - t0) / (t1 - t0)
        for b in range(bins):
            ref[y, x, b] += p * max(0.0, 1.0 - abs(u - b))
    vg = R.voxel_grid(ev, bins=bins)
    assert vg.dtype == np.float32 and np.allclose(vg, ref, atol=1e-4)
    # polarity is conserved
    assert np.allclose(vg.sum(2), R.accumulate(ev), atol=1e-4)


def test_color(ev):
    img = R.color(ev, on="#ff0000", off="#0000ff", background="#101010")
    last = {}
    for _, x, y, p in loop(ev):
        last[(x, y)] = p
    assert img.shape == (12, 20, 3) and img.dtype == np.uint8
    for (x, y), p in last.items():
        assert tuple(img[y, x]) == ((255, 0, 0) if p > 0 else (0, 0, 255))
    untouched = np.ones((12, 20), bool)
    for x, y in last:
        untouched[y, x] = False
    assert np.all(img[untouched] == 16)
    with pytest.raises(ValueError):
        R.parse_color("#12345")


def test_decay_kernel_matches_one_exp_per_event_and_any_split():
    """decay_kernel (an exp per 64 µs and a table, shared by runs of equal
    timestamps) gives the state of the obvious loop (one exp per event, in
    numba too so both use the same exp) within 1e-13 relative in float64
    and one ulp in float32, across a rebase and before the base; and the
    same bits however the events are split (inside a run too)."""
    from numba import njit

    from tectum.plugins.repr.kernels import decay_kernel, decay_table

    @njit
    def one_exp_per_event(t, x, y, p, v, base, tau_us, rebase_after):  # type: ignore[no-untyped-def]
        b = base[0]
        for i in range(t.shape[0]):
            if t[i] - b > rebase_after:
                v *= np.exp(-(t[i] - b) / tau_us)
                b = t[i]
            v[y[i], x[i], 1 if p[i] > 0 else 0] = np.exp((t[i] - b) * (1.0 / tau_us))
        base[0] = b

    rng = np.random.default_rng(3)
    n = 4000
    t = np.sort(rng.integers(0, 6000, n)).astype(np.int64) * 5  # runs of equal timestamps, steps of 5 µs to 400
    t[:3] = t[0]
    x, y = rng.integers(0, 9, n).astype(np.uint16), rng.integers(0, 7, n).astype(np.uint16)
    p = rng.choice(np.array([-1, 1], np.int8), n)
    tau, table = 2000.0, decay_table(2000.0)
    assert np.allclose(table, np.exp(np.arange(64) / tau), rtol=1e-15, atol=0)
    for dtype in (np.float64, np.float32):
        states = []
        for fn, splits in ((decay_kernel, (0, 1500, 1501, n)), (decay_kernel, (0, n)), (one_exp_per_event, (0, n))):
            v, base = np.zeros((7, 9, 2), dtype), np.array([t[0] + 7], np.int64)  # the first events before the base
            args = (tau, 8010, table) if fn is decay_kernel else (tau, 8010)
            for a, b in zip(splits[:-1], splits[1:]):
                fn(t[a:b], x[a:b], y[a:b], p[a:b], v, base, *args)
            states.append((v, base[0]))
        (split, b1), (whole, b2), (ref, b3) = states
        assert b1 == b2 == b3 > t[0]  # rebased
        assert np.array_equal(split, whole)
        if dtype is np.float64:
            assert np.allclose(whole, ref, rtol=1e-13, atol=0)
        else:
            assert np.abs(whole.view(np.int32) - ref.view(np.int32)).max() <= 1


def test_window_splits_is_searchsorted_right():
    """Every window edge's count of events at or before it, as numpy's
    search finds it: repeated times, edges before the first and after the
    last event, one event, none."""
    from tectum.plugins.repr.kernels import window_splits
    rng = np.random.default_rng(5)
    for n in (0, 1, 2, 3, 7, 64, 1000, 4097):
        for _ in range(20):
            t = np.sort(rng.integers(0, max(n, 2) * 3, n)).astype(np.int64)
            first, step, m = int(rng.integers(-10, 40)), int(rng.integers(1, 50)), int(rng.integers(0, 70))
            out = np.full(m, -7, np.int64)
            window_splits(t, first, step, out)
            assert np.array_equal(out, t.searchsorted(first + step * np.arange(m), "right")), (n, first, step)
