"""``tracker.evo`` with ``tracker="pose_6dof"``: the expansion (the
photometric tracker, the mapper and ``map.photometric`` in a loop, the
frames port), the parameters each tracker takes, and a short simulated
DAVIS run (events, poses for the bootstrap, APS frames) through
``tectum.run`` and the CLI, which write the same trajectory, near the truth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import tectum
from tectum import Kind, PosePacket
from tectum.cli import main as cli
from tectum.testing import ListSink, ListSource

#: the EVO bench's plane (a textured plane 2 m away, 6-DoF motion) seen by a DAVIS: 25 Hz APS frames, 5 ms exposure
SCENE = """
[[planes]]
center = [0, 0, 2.0]
texel_m = 0.03
texture = { kind = "noise", size = 512, contrast = 0.6 }
[motion]
position_amplitude = [0.3, 0.2, 0.3]
position_freq_hz = [0.5, 0.7, 0.4]
rotation_amplitude = [0.1, 0.1, 0.15]
rotation_freq_hz = [0.6, 0.4, 0.5]
[davis]
aps_rate_hz = 25.0
exposure_us = 5000.0
"""
SENSOR, DURATION, BOOT = "120x90", 500_000, 300_000
CALIB = "103.92304845;103.92304845;59.5;44.5"  # the simulator's pinhole at 120x90
#: the bench's mapper for the plane, one plane in the world, depth from focus
OPTS = ("tracker=pose_6dof,bootstrap_us=300000,batch_events=600,min_depth=1.0,max_depth=4.0,keyframe_baseline=0.05,focus=6,"
        f"surface=world_plane,calib={CALIB}")


def test_expansion_wires_the_photometric_loop() -> None:
    p = tectum.Pipeline()
    cam = p.source("pattern:", id="cam")
    gt = p.source(ListSource([PosePacket.empty(0, 10)], produces=[Kind.POSES]), id="gt")
    fr = p.source(ListSource([tectum.FramePacket.empty(0, 10)], produces=[Kind.FRAMES]), id="fr")
    p.op("tracker.evo", events=cam, poses=gt, frames=fr, id="evo", tracker="pose_6dof", calib="40;40;20;15",
         delay_us=3000, bootstrap_us=7, planes=20, batch_events=500, median_px=2)
    plan = p.validate()
    tr, mp, ph = plan.nodes["evo.tracker"], plan.nodes["evo.mapper"], plan.nodes["evo.photo"]
    assert (tr.spec.name, mp.spec.name, ph.spec.name) == ("tracker.pose_6dof", "map.emvs", "map.photometric")
    assert dict(tr.ports) == {"events": "cam", "poses": "gt", "maps": "evo.photo"}
    assert tr.delays == {"maps": 3000} and tr.feedback == {"maps"}
    assert dict(mp.ports) == {"events": "cam", "poses": "evo.tracker"}
    assert dict(ph.ports) == {"maps": "evo.mapper", "frames": "fr", "poses": "evo.tracker"}
    assert dict(tr.params) == {"calib": "40;40;20;15", "bootstrap_us": 7, "batch_events": 500}
    assert dict(ph.params) == {"median_px": 2} and dict(mp.params) == {"calib": "40;40;20;15", "planes": 20}
    assert plan.nodes["evo"].inputs == ("evo.tracker", "evo.mapper")
    assert len(plan.loops) == 1 and set(plan.loops[0]) == {"evo.tracker", "evo.mapper", "evo.photo"}
    # the default is the edge tracker's loop, two parts
    q = tectum.Pipeline()
    q.op("tracker.evo", events=q.source("pattern:", id="cam"), id="evo", calib="40;40;20;15")
    assert sorted(q.validate().nodes) == ["cam", "evo", "evo.mapper", "evo.tracker"]


@pytest.mark.parametrize("params, match", [
    ({"tracker": "pose_6dof"}, "needs bootstrap_us"),
    ({"tracker": "pose_6dof", "bootstrap_us": 1000, "window_events": 100}, "window_events not for tracker=pose_6dof"),
    ({"median_px": 2}, "median_px not for tracker=edge_align"),
    ({"tracker": "orb"}, "edge_align or pose_6dof"),
    ({"tracker": "pose_6dof", "bootstrap_us": 1000}, "needs intensity frames on port frames"),
])
def test_what_the_chosen_tracker_cannot_run_with_is_refused(params: dict[str, Any], match: str) -> None:
    p = tectum.Pipeline()
    cam = p.source("pattern:", id="cam")
    with pytest.raises((ValueError, tectum.PipelineError), match=match):
        p.op("tracker.evo", events=cam, id="evo", **params)
        p.validate()


def _truth() -> PosePacket:
    import tomllib

    from tectum.sources.simulate import make_simulator

    sim = make_simulator(tomllib.loads(SCENE), DURATION, sensor=SENSOR, seed=1)
    poses = [q for _, side in sim.windows(20_000) for q in side if isinstance(q, PosePacket)]
    truth = tectum.concat(poses)
    assert isinstance(truth, PosePacket)
    return truth


def _error(t: np.ndarray, position: np.ndarray, truth: PosePacket) -> tuple[float, float]:
    """RMS position error of the rows after the bootstrap, and the path over them, m."""
    from tectum.camera import interpolate_poses

    after = (t > BOOT) & (t <= truth.t[-1])
    p, _, _ = interpolate_poses(t[after], truth.t, truth.position, truth.orientation)
    keep = truth.t > BOOT
    path = float(np.linalg.norm(np.diff(truth.position[keep], axis=0), axis=1).sum())
    return float(np.sqrt(np.mean(np.sum((position[after] - p) ** 2, axis=1)))), path


def test_python_and_cli_track_a_simulated_davis(tmp_path: Path) -> None:
    scene = tmp_path / "plane.toml"
    scene.write_text(SCENE)
    src = f"simulate:{scene}?poses=true&davis=true&duration_us={DURATION}&sensor={SENSOR}&seed=1"
    truth = _truth()

    p = tectum.Pipeline()
    cam = p.source(f"simulate:{scene}", id="cam", poses=True, davis=True, duration_us=DURATION, sensor=SENSOR, seed=1)
    p.op("tracker.evo", cam, id="evo", **dict(kv.split("=") for kv in OPTS.split(",")))  # type: ignore[arg-type]
    sink = ListSink()
    p.sink(sink, "evo")
    tectum.run(p)
    est = tectum.concat([q for q in sink.packets if q.kind == Kind.POSES])
    assert isinstance(est, PosePacket)
    assert np.array_equal(est.t[est.t < BOOT], truth.t[truth.t < BOOT])  # the bootstrap's rows, handed on
    after = est.t > BOOT
    assert after.sum() >= 40 and not est.lost[after].any()
    rms, path = _error(est.t, est.position, truth)
    # measured 6.1 mm over 0.11 m (240x180 over 0.3 s, 1500 events a batch: 4.6 mm over 0.18 m, 2.5 %); standing
    # still at the bootstrap's end would be off by tens of mm
    assert rms < 0.15 * path, (rms, path)

    traj = tmp_path / "traj.tum"
    assert cli(["run", src, "--op", f"tracker.evo:{OPTS}", "--sink", str(traj)]) == 0
    rows = np.loadtxt(traj)
    t = np.rint(rows[:, 0] * 1e6).astype(np.int64)
    np.testing.assert_array_equal(t, est.t[~est.lost])  # the same run
    np.testing.assert_allclose(rows[:, 1:4], est.position[~est.lost], atol=1e-9)
