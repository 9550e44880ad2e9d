"""``tectum bench pose``, part ``evo``: the rows its targets judge, each
the mean of a loop's runs from several starts (docs/evo.md)."""

from __future__ import annotations

import pytest

from tectum.evaluation.suites._pose_evo import _mean_of


def test_a_judged_row_is_the_mean_of_its_starts_with_the_worst_start_beside_it() -> None:
    per = [{"start_s": s, "pos_pct": p, "drift_pct": d, "rot_median_deg": r, "lost": lo}
           for s, p, d, r, lo in ((0.0, 3.6, 9.1, 0.46, 0.01), (0.15, 2.1, 2.0, 0.32, 0.01),
                                  (0.3, 2.1, 2.7, 0.31, 0.02))]
    row = _mean_of("boxes", per)
    assert row["case"] == "boxes" and row["starts"] == "0 0.15 0.3"
    assert row["pos_pct"] == pytest.approx(7.8 / 3) and row["drift_pct"] == pytest.approx(13.8 / 3)
    assert row["pos_median_pct"] == pytest.approx(2.1) and row["pos_max_pct"] == pytest.approx(3.6)
    assert row["drift_max_pct"] == pytest.approx(9.1)  # the worst start is shown, not hidden by the mean
    assert row["rot_median_deg"] == pytest.approx(1.09 / 3) and row["lost"] == pytest.approx(0.04 / 3)
    assert row["per_start"] is per
