"""The engine suite's "fast operator beside a slow offloaded one" target is
judged from interleaved rounds: every case once a round in varied orders,
each case's median p99 and spread, the ratio of the medians; one noisy run
does not flip the verdict."""

from __future__ import annotations

from tectum.evaluation.harness import target_row
from tectum.evaluation.suites.engine import SIDE_CASES, fast_beside_slow, side_ratio

NAMES = {v: k for k, v in SIDE_CASES.items()}


def _scripted(p99s: dict[str, list[float]]):
    """A run_case giving each case's p99s in turn (warm-up runs: 1 µs), and the calls it saw."""
    calls: list[tuple[str, float]] = []
    left = {k: list(v) for k, v in p99s.items()}

    def run_case(slow, duration_s):
        k = NAMES[slow]
        calls.append((k, duration_s))
        p99 = left[k].pop(0) if duration_s == 0.5 else 1.0
        return {"p50": p99 / 2, "p90": p99 / 1.5, "p99": p99, "max": p99 * 2}

    return run_case, calls


def test_cases_are_interleaved_in_varied_orders_after_a_warm_up():
    run_case, calls = _scripted({k: [10.0] * 6 for k in SIDE_CASES})
    fast_beside_slow(2e5, 0.5, 1000, 400.0, rounds=6, run_case=run_case)
    assert sorted(k for k, _ in calls[:3]) == sorted(SIDE_CASES) and all(d == 0.2 for _, d in calls[:3])
    rounds = [tuple(k for k, _ in calls[i:i + 3]) for i in range(3, len(calls), 3)]
    assert len(rounds) == 6 and all(sorted(r) == sorted(SIDE_CASES) for r in rounds)
    assert len(set(rounds)) >= 3  # not the same order every round


def test_one_noisy_run_does_not_flip_the_verdict():
    # alone ~50 µs; offloaded ~55 µs but one run 950 µs (a burst of other work), and one alone run 500 µs
    p99s = {"alone": [50.0, 48.0, 500.0, 52.0, 49.0], "offloaded_slow_beside": [55.0, 950.0, 54.0, 56.0, 53.0],
            "inline_slow_beside": [430.0, 420.0, 440.0, 425.0, 435.0]}
    run_case, _ = _scripted(p99s)
    side = fast_beside_slow(2e5, 0.5, 1000, 400.0, rounds=5, run_case=run_case)
    assert side["alone"]["p99"] == 50.0 and side["offloaded_slow_beside"]["p99"] == 55.0
    assert (side["offloaded_slow_beside"]["p99_min"], side["offloaded_slow_beside"]["p99_max"]) == (53.0, 950.0)
    assert side["offloaded_slow_beside"]["p99s"] == p99s["offloaded_slow_beside"]  # round order
    rec = side_ratio(side)
    assert rec["met"] and abs(rec["value"] - 1.1) < 1e-9
    # the spread of the rounds' own ratios is shown beside the verdict
    assert abs(rec["ratio_max"] - 950.0 / 48.0) < 1e-9 and abs(rec["ratio_min"] - 54.0 / 500.0) < 1e-9
    assert target_row(rec)["value"] == "1.1 (0.108-19.8)"


def test_a_rise_in_most_rounds_misses():
    p99s = {"alone": [50.0] * 5, "offloaded_slow_beside": [60.0, 70.0, 40.0, 80.0, 66.0],
            "inline_slow_beside": [400.0] * 5}
    run_case, _ = _scripted(p99s)
    rec = side_ratio(fast_beside_slow(2e5, 0.5, 1000, 400.0, rounds=5, run_case=run_case))
    assert not rec["met"] and abs(rec["value"] - 66.0 / 50.0) < 1e-9


def test_a_real_round_measures_every_case():
    side = fast_beside_slow(2e5, 0.05, 1000, 400.0, rounds=1)
    for k in SIDE_CASES:
        assert side[k]["p99"] > 0 and len(side[k]["p99s"]) == 1
