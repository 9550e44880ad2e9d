"""The pixels' references at t = 0 (``ref_spread``) and the burst a common
reset level gives when a periodic motion comes back to its start."""

from __future__ import annotations

import numpy as np
import pytest

from tectum.sources.simulate import simulate
from tectum.sources.simulate.noise import start_references

PERIOD_US = 10_000


def _swinging_plane() -> dict:
    """A noise-textured plane 2 m ahead; the camera turns back and forth at
    100 Hz (about 4 px of swing on 64x48), so at t = 10 ms it is back at its
    start pose, moving at its fastest."""
    return {"name": "swing", "fov_deg": 90.0,
            "planes": [{"center": [0, 0, 2.0], "texture": {"kind": "noise", "size": 256, "contrast": 0.5,
                                                          "blur": 2.0}, "texel_m": 0.02}],
            "motion": {"rotation_amplitude": [0.06, 0.1, 0.04], "rotation_freq_hz": [100.0, 100.0, 100.0]}}


def _worst_2us_bin(ref_spread: float) -> tuple[int, float, int]:
    """``(largest 2 µs bin, median bin, its start µs)`` over 0.5-1.5 periods."""
    ev, _ = simulate(_swinging_plane(), int(1.5 * PERIOD_US), sensor="64x48", ref_spread=ref_spread)
    t = ev.t[(ev.t >= PERIOD_US // 2)] - PERIOD_US // 2
    bins = np.bincount(t // 2)
    k = int(bins.argmax())
    return int(bins[k]), float(np.median(bins)), PERIOD_US // 2 + 2 * k


def test_a_common_start_level_bursts_after_one_period_a_spread_one_does_not() -> None:
    """With every reference at L(0) (the default, a sensor reset at t = 0)
    and equal thresholds, the references stay on ``L(0) + k C``: back at the
    start pose every pixel with one net event is exactly on a threshold, and
    they fire together at t = one period (the ideal model's exact answer).
    References spread within the thresholds (a running sensor) fire as
    everywhere else: no 2 µs bin above a few times the median."""
    worst, median, at = _worst_2us_bin(0.0)
    assert worst > 20 * median and abs(at - PERIOD_US) <= 2, (worst, median, at)
    worst, median, at = _worst_2us_bin(1.0)
    assert worst < 4 * median, (worst, median, at)


def test_start_references_lie_within_the_thresholds() -> None:
    rng = np.random.default_rng(0)
    L = rng.normal(size=1000)
    c_on, c_off = np.full(1000, 0.2), np.full(1000, 0.3)
    assert np.array_equal(start_references(L, c_on, c_off, 0.0, 1), L)
    d = L - start_references(L, c_on, c_off, 1.0, 1)
    assert d.min() > -0.3 and d.max() < 0.2 and d.min() < -0.25 and d.max() > 0.15
    assert np.allclose(L - start_references(L, c_on, c_off, 0.5, 1), 0.5 * d)
    with pytest.raises(ValueError, match="ref_spread"):
        start_references(L, c_on, c_off, 1.5, 1)
