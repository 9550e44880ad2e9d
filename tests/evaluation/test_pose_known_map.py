"""``tectum bench pose`` part ``known_map``: the APS frames' time offset
against the events (``frame_event_offset``), on simulated frames whose
stamps are shifted by a known amount."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from tectum.evaluation.suites import _pose_known_map as K

#: a camera sliding sideways at 0.3 m/s past two boxes before a wall (slider_depth-like, small)
SLIDE: dict[str, Any] = {
    "name": "slide", "focal_px": 111.0,
    "planes": [{"center": [0, 0, 2.3], "texel_m": 0.02,
                "texture": {"kind": "noise", "size": 256, "contrast": 0.5, "blur": 2.0, "seed": 1}}],
    "boxes": [{"center": [-0.15, 0.05, 0.8], "size": [0.2, 0.25, 0.2], "orientation": [0, 0.3, 0], "texel_m": 0.006,
               "texture": {"kind": "noise", "size": 256, "contrast": 0.5, "blur": 2.0, "seed": 2}}],
    "motion": {"position": [0, 0, 0], "velocity": [0.3, 0, 0]}}


def _run(**model: float) -> tuple[Any, np.ndarray, np.ndarray]:
    from tectum.sources.simulate import simulate

    ev, truth = simulate(SLIDE, 150_000, sensor="80x60", truth_fps=100, **model)
    return ev.without_columns(*ev.columns), np.asarray(truth["frame_t"], np.int64), np.log(
        truth["frame_intensity"] + 1e-3)


@pytest.fixture(scope="module")
def run() -> tuple[Any, np.ndarray, np.ndarray]:
    return _run()


@pytest.mark.parametrize("late_us", [6000, -4000])
def test_frame_event_offset_finds_how_late_the_frames_show_their_stamps(run, late_us):
    # frames stamped late_us µs before the light they show: the offset grows by late_us; stamped right, it is
    # within 0.7 ms of 0 (the simulator's events come up to half a millisecond late on this scene)
    ev, t, log = run
    at_stamps = K.frame_event_offset(ev, t, log, span_us=8000)
    assert abs(at_stamps) < 700
    assert K.frame_event_offset(ev, t - late_us, log, span_us=8000) - at_stamps == pytest.approx(late_us, abs=150)


def test_frame_event_offset_sees_events_that_lag_the_light():
    # a slow photoreceptor (30 Hz cut-off) delays the events: the frames look early, the offset is > 0
    ev, t, log = _run(lowpass_hz=30.0, lowpass_min_hz=30.0)
    assert 1000 < K.frame_event_offset(ev, t, log, span_us=8000) < 6000


def test_frame_event_offset_refuses_frames_it_cannot_use(run):
    ev, t, log = run
    with pytest.raises(ValueError, match="one \\(H, W\\)"):
        K.frame_event_offset(ev, t, log[:, :10])
    with pytest.raises(ValueError, match="no two consecutive frames"):
        K.frame_event_offset(ev, t[:2], log[:2], span_us=8000)


def test_the_rate_counts_the_tracked_stretch_alone_and_times_the_warm_up_apart(monkeypatch):
    # a clock that the (stand-in) tracker advances by 1 s per event it sees: the tracked stretch's CPU is its
    # events' and the map's, the warm-up's those before the map (the real-data row's rate divides the tracked
    # events by the first; counting the warm-up in it made that row look slower per event than it is)
    from tectum import EventPacket, PosePacket

    clock = [0.0]

    class Tracker:
        counts: dict[str, int] = {}

        def __init__(self, **params: Any) -> None:
            pass

        def warmup(self) -> None:
            clock[0] += 1000.0  # outside both

        def process_ports(self, ports: dict[str, Any]) -> list[Any]:
            clock[0] += len(ports["events"]) + (100.0 if "maps" in ports else 0.0)
            return [PosePacket(np.array([int(ports["events"].t[-1])], np.int64), position=np.zeros((1, 3)),
                               orientation=np.array([[0, 0, 0, 1.0]]))]

        def finish(self) -> list[Any]:
            clock[0] += 10.0
            return []

    monkeypatch.setattr(K, "Pose6Dof", Tracker)
    monkeypatch.setattr(K.time, "thread_time", lambda: clock[0])

    def events(t0: int, n: int) -> EventPacket:
        return EventPacket(np.arange(t0, t0 + n, dtype=np.int64), np.zeros(n, np.uint16), np.zeros(n, np.uint16),
                           np.ones(n, np.int8), sensor=(8, 8))

    rows, cpu, cpu_before, _ = K.track_timed(events(1000, 7), None, before=events(0, 30))
    assert (cpu, cpu_before) == (7 + 100 + 10, 30)
    assert len(rows) == 2
    assert K.track(events(1000, 7), None, before=events(0, 30))[1] == 7 + 100 + 10
    assert K.track_timed(events(1000, 7), None)[1:3] == (117, 0)
