"""The EVO spread measurement (docs/evo.md): one scored row per start, the
tracker alone against maps from the true poses tracks the plane, bad mode."""

from __future__ import annotations

import math

import pytest

from tectum.evaluation.suites._pose_evo_spread import spread


def test_alone_gives_one_tracked_row_per_start() -> None:
    rows = spread("alone", starts_s=(0.2,), tracked_us=150_000, duration_us=350_000)
    assert [round(r["start_s"], 6) for r in rows] == [0.2]
    r = rows[0]
    # the tracker's own rows after its 0.1 s bootstrap (a pose per 3,000 events at 1.2 Mev/s, not the true
    # poses at 1 kHz), a few cm off over 13 cm of path
    assert 40 <= r["poses"] <= 80 and 0.08 < r["path_m"] < 0.2
    assert 0.0 < r["ate_m"] < 0.06 and math.isfinite(r["pos_pct"]) and r["lost"] < 0.2


def test_mode_is_checked() -> None:
    with pytest.raises(ValueError, match="'loop' or 'alone'"):
        spread("both")
