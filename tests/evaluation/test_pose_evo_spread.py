"""The EVO spread measurement (docs/evo.md): one scored row per start, the
tracker alone against maps from the true poses tracks the plane, the boxes
with their own settings, bad mode and scene."""

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


def test_the_boxes_run_with_their_own_settings(monkeypatch: pytest.MonkeyPatch) -> None:
    """``scene="boxes_3d"`` simulates the boxes and maps them with the bench's
    boxes mapper (their first map from the true poses comes only after 1.1 s:
    too long a run for a test, so the mapper is stopped as it is made)."""
    from tectum.evaluation.suites import _pose_evo_spread as S

    seen: dict[str, object] = {}

    class Stop(Exception):
        pass

    def fake_simulate(scene: object, duration_us: int) -> tuple[None, None, str]:
        seen["scene"], seen["duration_us"] = scene, duration_us
        return None, None, "200;200;119.5;89.5"

    def fake_emvs(**kw: object) -> None:
        seen["mapper"] = kw
        raise Stop

    monkeypatch.setattr(S, "simulate", fake_simulate)
    monkeypatch.setattr(S, "Emvs", fake_emvs)
    with pytest.raises(Stop):
        spread("alone", scene="boxes_3d", mapper={"overlap": 2})
    assert seen["scene"] == "boxes_3d" and seen["duration_us"] == 2_600_000  # the last start 1.9 s + 0.7 s
    assert seen["mapper"] == {"calib": "200;200;119.5;89.5", **S.MAPPERS["boxes_3d"], "overlap": 2}


def test_scene_is_checked() -> None:
    with pytest.raises(ValueError, match="scene is one of"):
        spread("loop", scene="cube")


def test_the_mean_line_says_which_starts_it_leaves_out() -> None:
    """A start lost from its first step has no score (NaN): the line's means
    are over the others and it says so (the bench's mean is NaN, missed);
    with every start scored it says nothing more."""
    from tectum.evaluation.suites._pose_evo_spread import mean_line

    def row(pos: float) -> dict[str, float]:
        return {"pos_pct": pos, "drift_pct": pos, "rot_median_deg": pos / 2}

    assert mean_line([row(4.0), row(8.0)]) == ("mean: position RMSE 6.0 % of the path (median 6.0 %), final 6.0 %, "
                                               "rotation median 3.00 deg")
    lost = mean_line([row(4.0), row(float("nan")), row(8.0)])
    assert lost.startswith("mean: position RMSE 6.0 % of the path") and "over 2 of 3 starts (1 lost" in lost
    assert "none of 2 starts tracked" in mean_line([row(float("nan"))] * 2)
