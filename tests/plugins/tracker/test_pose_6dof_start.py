"""``tracker.pose_6dof`` starting on a running sensor: the events before
the map tell each pixel's state (its last event, its interval) and that
no pixel starts at its reference level, as the pixels of a simulation
from rest do."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from tectum import MapPacket

from helpers import SLIDE

T_MAP = 40_000  # µs: the map's time, 40 ms into the run


def _simulated_slide(after_us: int = 100_000, t_map: int = T_MAP, sensor: str = "120x90", scene: dict[str, Any] = SLIDE,
                     **model: Any) -> tuple[Any, Any, MapPacket]:
    """The slide's events (``t_map + after_us`` µs), its truth and its map at ``t_map``."""
    from tectum.sources.simulate import simulate
    from tectum.sources.simulate.photomap import scene_map

    ev, truth = simulate(scene, t_map + after_us, sensor=sensor, **model)
    m = scene_map(scene, t_map, sensor=sensor)
    maps = MapPacket(np.array([t_map], np.int64), image=m["image"][None], depth=m["depth"][None], K=m["K"][None],
                     pose=m["pose"][None], t_start=t_map, t_end=t_map + 1)
    return ev.without_columns(*ev.columns), truth, maps


@pytest.fixture(scope="module")
def slide() -> tuple[Any, Any, MapPacket]:
    return _simulated_slide()


def _ate_mm(slide: tuple[Any, Any, MapPacket], before: bool, **params: Any) -> float:
    from tectum.evaluation.suites._pose_known_map import score, track

    ev, truth, maps = slide
    po, _, counts = track(ev.slice_time(T_MAP, None), maps, before=ev.slice_time(0, T_MAP) if before else None,
                          min_points=50, **params)
    assert counts["skipped_before_map"] == (int(np.searchsorted(ev.t, T_MAP)) if before else 0)
    s = score(po, truth["pose_t"], truth["pose_position"], truth["pose_orientation"])
    assert s["lost"] == 0
    return float(s["ate_m"]) * 1e3


def test_the_events_before_the_map_keep_a_mid_run_start_on_track(slide):
    # started 40 ms into the run without them, every pixel's first event counts a whole threshold that it had
    # partly crossed before: the camera lags by 4-5 mm; with them, about 1 mm (4 % of the 30 mm path)
    without, with_before = _ate_mm(slide, False), _ate_mm(slide, True)
    assert without > 3.0 and with_before < 1.5, (without, with_before)


def test_a_pixels_first_event_weighs_a_threshold_on_a_running_sensor():
    from tectum.plugins.tracker._generative import event_weights

    x, y = np.array([0, 0, 1], np.uint16), np.zeros(3, np.uint16)
    t, p = np.array([10, 20, 30], np.int64), np.array([1, 1, -1], np.int8)
    for first, want in ((1.5, [0.3, 0.2, -0.3]), (1.0, [0.2, 0.2, -0.2])):
        last, tlast, dtp, w = np.zeros((1, 2), np.int8), np.zeros((1, 2), np.int64), np.full((1, 2), -1), np.empty(3)
        event_weights(x, y, t, p, 0.2, last, tlast, dtp, w, first)
        assert np.allclose(w, want) and last[0].tolist() == [1, -1] and dtp[0].tolist() == [10, -1]


def test_the_residues_count_from_those_at_the_start(slide):
    # the increments count from the first tracked event: each pixel's sub-threshold residue there (from its events
    # before the map) is the base the later residues are taken from
    from tectum.plugins.tracker import Pose6Dof
    from tectum.plugins.tracker._generative import event_weights, residue_image

    ev, _, maps = slide
    before, after = ev.slice_time(0, T_MAP), ev.slice_time(T_MAP, T_MAP + 3000)
    op = Pose6Dof(min_points=50)
    op.process_ports({"events": before})
    op.process_ports({"events": after, "maps": maps})
    op.finish()
    assert op.counts["batches"] >= 1 and op.counts["references"] == 1
    last, tlast, dtp = np.zeros((90, 120), np.int8), np.zeros((90, 120), np.int64), np.full((90, 120), -1)
    event_weights(before.x, before.y, before.t, before.p, 0.2, last, tlast, dtp, np.empty(len(before)), 1.0)
    want = np.empty((90, 120))
    residue_image(last, tlast, dtp, int(after.t[0]), 0.2, np.zeros((90, 120)), want, np.empty((0, 0)))
    assert np.abs(want).max() > 0.05 and np.array_equal(op._dref, want)


@pytest.mark.slow
def test_a_running_sensors_unfired_pixels_bound_less():
    # on a running sensor a pixel without events had crossed an unknown part of its threshold before the start: its
    # silence counts for unseen_running (0.35) of a silent pixel's. The slide at 240x180 (DAVIS240-like focal length)
    # with the realistic sensor (threshold spread, photoreceptor, refractory period, jitter, noise), started 40 ms in:
    # measured 0.99 mm (1.87 % of the path), 1.22 mm counting them whole, 1.32 mm before (pixels past twice their
    # interval counted silent too)
    run = _simulated_slide(180_000, sensor="240x180", scene={**SLIDE, "focal_px": 2 * SLIDE["focal_px"]},
                           preset="realistic")
    ate = {share: _ate_mm(run, True, unseen_running=share) for share in (0.35, 1.0)}
    assert ate[0.35] < 1.1 and ate[0.35] < 0.9 * ate[1.0], ate


def test_unseen_running_is_a_share_and_needs_a_running_sensor():
    # from rest (no events before the map) every pixel starts at its reference level: the bound is exact and the share
    # is not used (the same poses); a share outside [0, 1] is refused
    from tectum.plugins.tracker import Pose6Dof

    ev, _, maps = _simulated_slide(40_000, t_map=0)
    rows = []
    for share in (0.0, 1.0):
        op = Pose6Dof(min_points=50, unseen_running=share)
        rows.append(op.process_ports({"events": ev, "maps": maps}) + op.finish())
    assert np.array_equal(rows[0][0].position, rows[1][0].position)
    with pytest.raises(ValueError, match="unseen_running must be in"):
        Pose6Dof(unseen_running=1.5)


def test_a_refractory_pixels_events_stand_for_the_change_its_hold_lost():
    # refractory 500 us: an ON event 1000 us after the last stands for 1000 / 500 = 2 thresholds, one 550 us after for
    # at most 4; the residue grows at the same rate (half-way to the next event: 1 C, 0.5 C beyond event_weights' C/2)
    from tectum.plugins.tracker._generative import event_weights, residue_image

    x, y = np.zeros(4, np.uint16), np.zeros(4, np.uint16)
    t, p = np.array([0, 1000, 2000, 2550], np.int64), np.ones(4, np.int8)
    last, tlast, dtp, w = np.zeros((1, 1), np.int8), np.zeros((1, 1), np.int64), np.full((1, 1), -1), np.empty(4)
    event_weights(x[:3], y[:3], t[:3], p[:3], 0.2, last, tlast, dtp, w[:3], 1.5, 500.0)
    assert np.allclose(w[:3], [0.3, 0.4, 0.4])
    out = np.empty((1, 1))
    residue_image(last, tlast, dtp, 2500, 0.2, np.zeros((1, 1)), out, np.empty((0, 0)), 1.0, 500.0)
    assert out[0, 0] == pytest.approx(0.2 * (0.5 * 2 - 0.5))
    event_weights(x[3:], y[3:], t[3:], p[3:], 0.2, last, tlast, dtp, w[3:], 1.5, 500.0)
    assert w[3] == pytest.approx(0.8)


def test_refractory_us_keeps_a_refractory_sensor_on_track():
    # the slide (120x90) seen by an ideal sensor with a 2.5 ms refractory period: counting each event as one threshold
    # misses the change the hold lost, and the camera lags (measured ATE 2.97 mm); with refractory_us=2500 1.54 mm
    from tectum.plugins.tracker import Pose6Dof

    run = _simulated_slide(refractory_us=2500.0)
    ate = {r: _ate_mm(run, True, refractory_us=r) for r in (0.0, 2500.0)}
    assert ate[2500.0] < 2.0 and ate[2500.0] < 0.7 * ate[0.0], ate
    with pytest.raises(ValueError, match="refractory_us must be >= 0"):
        Pose6Dof(refractory_us=-1.0)


def test_an_off_threshold_weighs_the_off_events_and_their_residues():
    # C_on 0.2, C_off 0.1 (off = 0.5): an ON event 0.2, an OFF one -0.1, the half thresholds of the new and the last
    # polarity each its own (an OFF event after an ON: -0.1 - 0.05 - 0.1); a pixel whose last event was OFF holds
    # half as much residue
    from tectum.plugins.tracker._generative import event_weights, residue_image

    x, y = np.zeros(4, np.uint16), np.zeros(4, np.uint16)
    t, p = np.array([0, 100, 200, 300], np.int64), np.array([1, 1, -1, -1], np.int8)
    last, tlast, dtp, w = np.zeros((1, 1), np.int8), np.zeros((1, 1), np.int64), np.full((1, 1), -1), np.empty(4)
    event_weights(x, y, t, p, 0.2, last, tlast, dtp, w, 1.0, 0.0, 0.5)
    assert np.allclose(w, [0.2, 0.2, -0.1 - 0.05 - 0.1, -0.1])
    out = np.empty((1, 1))
    residue_image(last, tlast, dtp, 375, 0.2, np.zeros((1, 1)), out, np.empty((0, 0)), 1.0, 0.0, 0.5)
    assert out[0, 0] == pytest.approx(-0.1 * (0.75 - 0.5))


def test_contrast_off_keeps_an_asymmetric_sensor_on_track():
    # the slide (120x90) seen by an ideal sensor whose OFF threshold is 0.14 (ON 0.2): one threshold for both
    # over-counts the OFF events and the camera lags (measured ATE 1.83 mm); with contrast_off=0.14 0.71 mm
    from tectum.plugins.tracker import Pose6Dof

    run = _simulated_slide(c_off=0.14)
    ate = {c: _ate_mm(run, True, contrast_off=c) for c in (0.0, 0.14)}
    assert ate[0.14] < 0.8 * ate[0.0], ate
    with pytest.raises(ValueError, match="contrast_off must be >= 0"):
        Pose6Dof(contrast_off=-0.1)
