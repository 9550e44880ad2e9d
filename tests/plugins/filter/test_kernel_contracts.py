"""What the filter kernels promise in their docstrings, checked at the edges
the stream tests rarely hit (mutants of these lines survived them, see
docs/mutation.md): each returns the number it kept, and a neighbour that
fired exactly ``dt_us`` before counts, in every one of the 8 positions.
"""

from __future__ import annotations

import numpy as np
import pytest

from tectum.plugins.filter._state import NEVER, padded_timestamps
from tectum.plugins.filter.background_activity import background_activity_kernel
from tectum.plugins.filter.hot_pixel import mask_kernel
from tectum.plugins.filter.rate_limit import token_bucket_kernel
from tectum.plugins.filter.refractory import refractory_kernel
from tectum.plugins.filter.stcf import stcf_kernel

NEIGHBOURS = [(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dx or dy]


def _stream(n: int = 400, seed: int = 0) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 20_000, n)).astype(np.int64)
    x, y = rng.integers(0, 12, n).astype(np.uint16), rng.integers(0, 9, n).astype(np.uint16)
    return t, x, y, rng.choice(np.array([-1, 1], np.int8), n)


@pytest.mark.parametrize("kernel", ["stcf", "background_activity", "refractory", "token_bucket", "mask"])
def test_returns_the_number_kept(kernel: str) -> None:
    t, x, y, p = _stream()
    keep = np.zeros(len(t), np.bool_)
    if kernel == "stcf":
        n = stcf_kernel(t, x, y, p, padded_timestamps((12, 9), 2), 1500, 2, True, keep)
    elif kernel == "background_activity":
        n = background_activity_kernel(t, x, y, padded_timestamps((12, 9)), 800, keep)
    elif kernel == "refractory":
        n = refractory_kernel(t, x, y, np.full((9, 12), NEVER, np.int64), 1000, keep)
    elif kernel == "token_bucket":
        n = token_bucket_kernel(t, np.array([5.0, 0.0, 0.0]), 0.01, 5.0, keep)
    else:
        n = mask_kernel(x, y, np.random.default_rng(1).random((9, 12)) < 0.3, keep)
    assert 0 < n < len(t) and n == int(keep.sum())


@pytest.mark.parametrize("dx, dy", NEIGHBOURS)
@pytest.mark.parametrize("late", [0, 1])
def test_a_neighbour_exactly_dt_before_counts(dx: int, dy: int, late: int) -> None:
    """Pixel (5, 4) fires at 10 000 µs after one neighbour fired at
    10 000 - dt (kept: the window is inclusive) or one µs earlier (dropped);
    STCF with k = 1 and the BA filter, same answer."""
    dt = 300
    t = np.array([10_000 - dt - late, 10_000], np.int64)
    x, y = np.array([5 + dx, 5], np.uint16), np.array([4 + dy, 4], np.uint16)
    p = np.array([1, 1], np.int8)
    for run in ("stcf", "ba"):
        keep = np.zeros(2, np.bool_)
        if run == "stcf":
            stcf_kernel(t, x, y, p, padded_timestamps((12, 9)), dt, 1, False, keep)
        else:
            background_activity_kernel(t, x, y, padded_timestamps((12, 9)), dt, keep)
        assert keep.tolist() == [False, late == 0], run


def test_the_last_whole_token_passes_an_event() -> None:
    """A bucket holding exactly one token lets one event through, not two."""
    keep = np.zeros(2, np.bool_)
    assert token_bucket_kernel(np.array([0, 0], np.int64), np.array([1.0, 0.0, 0.0]), 0.0, 1.0, keep) == 1
    assert keep.tolist() == [True, False]


def test_parameter_bounds_are_inclusive() -> None:
    """The documented ranges hold at both ends: STCF k in 1..8, a rate limit
    of any positive rate (below 1 Hz too) with a burst of one event."""
    from tectum.plugins.filter import RateLimit, SpatioTemporalCorrelation

    for k in (1, 8):
        assert SpatioTemporalCorrelation(k=k).k == k
    assert RateLimit(rate_hz=0.5, burst=1).burst == 1
    for kw in ({"rate_hz": 0.0}, {"rate_hz": -1.0}, {"burst": 0}, {"rate_hz": 0.0, "burst": 5}):
        with pytest.raises(ValueError, match="need rate_hz > 0 and burst >= 1"):
            RateLimit(**kw)


def test_hot_pixels_equal_the_rule() -> None:
    """``hot_pixels``: a pixel is hot with at least ``min_events`` events and
    more than ``factor`` times the mean count of the pixels that fired;
    small counts make every boundary (>= min_events, > limit) come up.
    ``count_kernel`` counts one per event."""
    from tectum.plugins.filter.hot_pixel import count_kernel, hot_pixels

    rng = np.random.default_rng(7)
    for _ in range(300):
        x, y = rng.integers(0, 4, 12).astype(np.uint16), rng.integers(0, 3, 12).astype(np.uint16)
        counts = np.zeros((3, 4), np.int64)
        count_kernel(x, y, counts)
        want = np.zeros((3, 4), np.int64)
        for xi, yi in zip(x.tolist(), y.tolist()):
            want[yi, xi] += 1
        assert np.array_equal(counts, want)
        factor, min_events = float(rng.choice([0.5, 1.0, 1.5, 2.0])), int(rng.integers(1, 4))
        fired = [c for c in want.ravel().tolist() if c > 0]
        limit = max(min_events, factor * sum(fired) / len(fired))
        rule = [[c >= min_events and c > limit for c in row] for row in want.tolist()]
        assert hot_pixels(counts, factor, min_events).tolist() == rule
    assert not hot_pixels(np.zeros((3, 4), np.int64), 1.0, 1).any()
