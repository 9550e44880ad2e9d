"""Feature-track accuracy, the field's protocol (Gehrig et al., EKLT, IJCV
2020; the event-camera feature-tracking benchmarks after it).

Each track is scored against a *truth track* started from the same place
at the same time: its first row (the detection: time ``t0``, position
``x0``) is handed to a truth function ``truth(t0, x0, t) -> x`` (the
simulator's rotation truth, or KLT on frames for real recordings). Then:

* tracking error: ``|x - x_true|`` (px) at every row while the track is
  valid, i.e. up to (not including) the first row whose error exceeds
  ``max_error`` (5 px);
* feature age: the time from ``t0`` to the last valid row (µs); the *age
  ratio* divides it by the truth track's length: the time the truth stays
  in the image (and within the truth's span) after ``t0``, capped at the
  end of the recording. A tracker that follows a corner as long as it is
  visible scores 1.

Summaries: the median error over the valid rows of all tracks, and the
median age ratio over the tracks. A track with one row (its start, never
updated: no events reached it, e.g. a static part of the scene) says
nothing about accuracy: it is counted as ``unmoved``, not scored.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["TrackScore", "score_tracks", "truth_length"]

#: ``truth(t0 (n,) µs, x0 (n, 2) px, t (n,) µs) -> (n, 2) px``, NaN where unknown.
TruthFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class TrackScore:
    """Scores of a set of tracks (see the module doc)."""

    tracks: int                #: tracks scored
    unmoved: int               #: tracks with one row, not scored
    median_error_px: float     #: over the valid rows of all tracks
    mean_error_px: float
    median_age_ratio: float    #: over the tracks
    mean_age_us: float
    errors: np.ndarray         #: per valid row, px
    age_ratios: np.ndarray     #: per track


def truth_length(truth: TruthFn, t0: float, x0: np.ndarray, t_end: float, sensor: tuple[int, int],
                 margin: float = 0.0, step_us: float = 1000.0) -> float:
    """How long (µs) the truth track from ``x0`` at ``t0`` stays known and
    at least ``margin`` px inside the ``sensor`` (w, h) image, up to
    ``t_end``, sampled every ``step_us``."""
    ts = np.arange(t0, t_end + step_us, step_us)
    ts[-1] = min(ts[-1], t_end)
    xy = truth(np.full(len(ts), t0), np.tile(np.asarray(x0, np.float64), (len(ts), 1)), ts)
    w, h = sensor
    with np.errstate(invalid="ignore"):
        inside = np.isfinite(xy).all(axis=1) & (xy[:, 0] >= margin) & (xy[:, 0] <= w - 1 - margin) \
            & (xy[:, 1] >= margin) & (xy[:, 1] <= h - 1 - margin)
    out = np.flatnonzero(~inside)
    last = ts[out[0] - 1] if out.size and out[0] > 0 else (t0 if out.size else ts[-1])
    return float(last - t0)


def score_tracks(t: np.ndarray, ids: np.ndarray, xy: np.ndarray, truth: TruthFn, t_end: float,
                 sensor: tuple[int, int], max_error: float = 5.0, margin: float = 0.0,
                 min_truth_us: float = 1.0) -> TrackScore:
    """Score track rows (``t`` µs, ``ids``, ``xy`` (n, 2) px, sorted by time
    within each id) against ``truth``; the recording ends at ``t_end`` µs;
    a truth track ends ``margin`` px from the border (a tracker's patch
    leaves the image there). Tracks whose truth length is under
    ``min_truth_us`` are not scored."""
    t = np.asarray(t, np.int64)
    ids = np.asarray(ids)
    xy = np.asarray(xy, np.float64)
    errors, ratios, ages = [], [], []
    unmoved = 0
    order = np.argsort(ids, kind="stable")
    bounds = np.flatnonzero(np.diff(ids[order])) + 1
    for rows in np.split(order, bounds) if len(order) else []:
        tt, pp = t[rows], xy[rows]
        if len(tt) < 2:
            unmoved += 1
            continue
        length = truth_length(truth, float(tt[0]), pp[0], t_end, sensor, margin)
        if length < min_truth_us:
            continue
        ref = truth(np.full(len(tt), float(tt[0])), np.tile(pp[0], (len(tt), 1)), tt.astype(np.float64))
        err = np.linalg.norm(pp - ref, axis=1)
        bad = np.flatnonzero(~(err <= max_error))  # NaN (truth unknown) ends the track too
        valid = bad[0] if bad.size else len(tt)
        errors.append(err[1:valid])  # the first row is the start itself (error 0)
        age = float(tt[valid - 1] - tt[0]) if valid else 0.0
        ages.append(age)
        ratios.append(min(age / length, 1.0))
    e = np.concatenate(errors) if errors else np.empty(0)
    r = np.asarray(ratios)
    return TrackScore(len(r), unmoved, float(np.median(e)) if e.size else float("nan"),
                      float(e.mean()) if e.size else float("nan"), float(np.median(r)) if r.size else float("nan"),
                      float(np.mean(ages)) if ages else float("nan"), e, r)
