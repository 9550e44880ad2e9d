"""Feature-track metrics: error over the valid rows, age until the error
first exceeds 5 px, the truth's length in the image, one-row tracks
counted as unmoved."""

from __future__ import annotations

import numpy as np
import pytest

from tectum.evaluation.metrics.tracks import score_tracks, truth_length

SENSOR = (100, 80)


def _drift(t0: np.ndarray, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Truth: every pixel moves at +100 px/s in x."""
    return x0 + np.stack([(t - t0) * 1e-4, np.zeros(len(t))], axis=1)


def test_truth_length_ends_at_the_border_minus_the_margin_or_the_recording():
    # from x = 50 at 100 px/s the truth reaches x = 99 after 490 ms, x = 89 (margin 10) after 390 ms
    assert truth_length(_drift, 0.0, np.array([50.0, 40.0]), 1e6, SENSOR) == pytest.approx(490_000, abs=1000)
    assert truth_length(_drift, 0.0, np.array([50.0, 40.0]), 1e6, SENSOR, margin=10) == pytest.approx(390_000,
                                                                                                       abs=1000)
    assert truth_length(_drift, 0.0, np.array([50.0, 40.0]), 200_000, SENSOR) == 200_000


def test_a_perfect_track_and_a_drifting_one():
    t = np.arange(0, 200_001, 10_000)
    x = 50 + t * 1e-4
    # id 0 follows the truth; id 1 drifts 1 px per 10 ms behind it (error > 5 px from 60 ms on)
    lag = np.arange(len(t)) * 1.0
    rows_t = np.concatenate([t, t])
    ids = np.repeat([0, 1], len(t))
    xy = np.concatenate([np.stack([x, np.full(len(t), 40.0)], 1), np.stack([x - lag, np.full(len(t), 40.0)], 1)])
    s = score_tracks(rows_t, ids, xy, _drift, 200_000, SENSOR)
    assert s.tracks == 2 and s.unmoved == 0
    assert s.age_ratios[0] == pytest.approx(1.0) and s.age_ratios[1] == pytest.approx(50_000 / 200_000)
    # errors: id 0's 20 zeros, id 1's 1..5 px (rows 1-5; row 6 at 6 px ends it)
    assert sorted(s.errors.tolist()) == pytest.approx([0.0] * 20 + [1.0, 2.0, 3.0, 4.0, 5.0])


def test_one_row_tracks_are_unmoved_and_not_scored():
    s = score_tracks(np.array([0, 0, 10_000]), np.array([7, 8, 8]), np.array([[10.0, 10], [20, 20], [21, 20]]),
                     _drift, 100_000, SENSOR)
    assert s.tracks == 1 and s.unmoved == 1
