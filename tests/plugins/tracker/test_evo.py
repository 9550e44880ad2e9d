"""``tracker.evo`` (the EVO macro): its expansion and wiring, the CLI with
both sinks (poses and maps) fed, and tracking after a bootstrap on a small
simulated scene, identical under ``tectum.run`` and :class:`tectum.Stepper`."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import tectum
from tectum import Kind, PosePacket
from tectum.cli import main as cli
from tectum.sources.simulate import make_simulator
from tectum.testing import ListSink, ListSource


def _calib(sensor: str) -> str:
    f, cx, cy = (float(v) for v in make_simulator("plane_6dof", 1000, sensor=sensor).truth["camera"])
    return f"{f};{f};{cx};{cy}"


def test_expansion_wires_the_loop_and_the_bootstrap() -> None:
    p = tectum.Pipeline()
    cam = p.source("pattern:", id="cam")
    gt = p.source(ListSource([PosePacket.empty(0, 10)], produces=[Kind.POSES]), id="gt")
    p.op("tracker.evo", events=cam, poses=gt, id="evo", calib="40;40;20;15", delay_us=3000, bootstrap_us=7,
         planes=20)
    plan = p.validate()
    tr, mp = plan.nodes["evo.tracker"], plan.nodes["evo.mapper"]
    assert tr.spec.name == "tracker.edge_align" and mp.spec.name == "map.emvs"
    assert dict(tr.ports) == {"events": "cam", "poses": "gt", "maps": "evo.mapper"}
    assert tr.delays == {"maps": 3000} and tr.feedback == {"maps"}
    assert dict(mp.ports) == {"events": "cam", "poses": "evo.tracker"}
    assert tr.params["bootstrap_us"] == 7 and mp.params["planes"] == 20 and mp.params["calib"] == "40;40;20;15"
    assert plan.nodes["evo"].inputs == ("evo.tracker", "evo.mapper")
    assert plan.loops == (("evo.tracker", "evo.mapper"),)


def test_the_gyro_goes_to_the_tracker() -> None:
    """A source's IMU feeds the tracker's ``imu`` port, with the gyro's
    parameters, and nothing of it the mapper."""
    p = tectum.Pipeline()
    cam = p.source("pattern:", id="cam")
    imu = p.source(ListSource([tectum.ImuPacket.empty(0, 10)], produces=[Kind.IMU]), id="imu")
    p.op("tracker.evo", events=cam, imu=imu, id="evo", calib="40;40;20;15", gyro_rad=1e-5,
         gyro_bias=(0.0, 0.01, 0.0), imu_rotation=(0.0, 3.14159, 0.0), imu_time_offset_us=-300)
    plan = p.validate()
    tr, mp = plan.nodes["evo.tracker"], plan.nodes["evo.mapper"]
    assert tr.ports["imu"] == "imu" and "imu" not in mp.ports
    assert {k: tr.params[k] for k in ("gyro_rad", "gyro_bias", "imu_rotation", "imu_time_offset_us")} == {
        "gyro_rad": 1e-5, "gyro_bias": (0.0, 0.01, 0.0), "imu_rotation": (0.0, 3.14159, 0.0),
        "imu_time_offset_us": -300}
    assert not set(mp.params) & {"gyro_rad", "gyro_bias", "imu_rotation", "imu_time_offset_us"}


def test_parameters_not_given_keep_each_operators_default() -> None:
    """The macro passes on only what it was given: the tracker's window and
    step are ``tracker.edge_align``'s own defaults, not numbers of the macro."""
    import inspect

    from tectum.plugins.tracker.edge_align import EdgeAlign

    p = tectum.Pipeline()
    cam = p.source("pattern:", id="cam")
    p.op("tracker.evo", events=cam, id="evo", calib="40;40;20;15", step_events=500, min_depth=0.5, overlap=2)
    plan = p.validate()
    tr, mp = plan.nodes["evo.tracker"].params, plan.nodes["evo.mapper"].params
    assert dict(tr) == {"calib": "40;40;20;15", "step_events": 500}
    assert dict(mp) == {"calib": "40;40;20;15", "min_depth": 0.5, "overlap": 2}
    op = plan.nodes["evo.tracker"].instantiate()
    assert op.window_events == inspect.signature(EdgeAlign).parameters["window_events"].default


def test_cli_writes_poses_and_maps(tmp_path: Any) -> None:
    """Bootstrapped over the whole run from the simulator's poses: the
    trajectory is the truth, the mapper makes maps from it, and each sink
    gets its stream."""
    traj, maps = tmp_path / "traj.tum", tmp_path / "maps.npz"
    rc = cli(["run", "simulate:plane_6dof?poses=true&duration_us=300000&sensor=120x90", "--op",
              f"tracker.evo:bootstrap_us=300000,planes=30,calib={_calib('120x90')}", "--sink", str(traj),
              "--sink", str(maps)])
    assert rc == 0
    rows = np.loadtxt(traj)
    assert len(rows) == 300 and np.allclose(rows[1, 0], 0.001)
    with np.load(maps) as z:
        assert any(k.startswith("maps") for k in z.files), z.files


def test_a_bootstrap_without_poses_is_a_one_line_error(tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    """The user's path without poses: a simulation written to a file holds
    the events (its truth is beside it), so the bootstrap gets no pose. The
    run ends with one line naming the missing poses and a non-zero exit, not
    an empty trajectory and exit 0."""
    ev = tmp_path / "plane.npz"
    assert cli(["simulate", "plane_6dof", "--duration", "60ms", "--sensor", "120x90", "--out", str(ev), "-q"]) == 0
    capsys.readouterr()
    rc = cli(["run", str(ev), "--op", f"tracker.evo:bootstrap_us=20000,calib={_calib('120x90')}", "--sink",
              str(tmp_path / "traj.tum"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert "bootstrap_us=20000 but no pose came on port 'poses'" in err[-1] and "Traceback" not in "".join(err)


def test_a_gyro_without_an_imu_is_a_one_line_error(tmp_path: Any, capsys: pytest.CaptureFixture[str]) -> None:
    """``gyro_rad`` asked for on a source without an IMU: one line naming
    the missing gyro and a non-zero exit, not a run that quietly went
    without it."""
    rc = cli(["run", "simulate:plane_6dof?poses=true&duration_us=60000&sensor=120x90", "--op",
              f"tracker.evo:bootstrap_us=20000,gyro_rad=0.0001,calib={_calib('120x90')}", "--sink",
              str(tmp_path / "traj.tum"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert "gyro_rad=0.0001 but no gyro sample came on port 'imu'" in err[-1] and "Traceback" not in "".join(err)


#: a textured plane 2 m away, the camera moving in 6 DoF (slow and smooth)
PLANE: dict[str, Any] = {
    "planes": [{"center": [0, 0, 2.0], "texture": {"kind": "noise", "size": 512, "contrast": 0.6},
                "texel_m": 0.03}],
    "motion": {"position_amplitude": [0.3, 0.2, 0.3], "position_freq_hz": [0.5, 0.7, 0.4],
               "rotation_amplitude": [0.1, 0.1, 0.15], "rotation_freq_hz": [0.6, 0.4, 0.5]},
}


def _simulate(duration_us: int, sensor: str) -> tuple[tectum.EventPacket, PosePacket, str]:
    """``PLANE``'s events, true poses and inline intrinsics (seed 1)."""
    sim = make_simulator(PLANE, duration_us, sensor=sensor, seed=1)
    evs, poses = [], []
    for ev, side in sim.windows(20_000):
        evs.append(ev.without_columns(*ev.columns))
        poses += [q for q in side if isinstance(q, PosePacket)]
    ev, truth = tectum.concat(evs), tectum.concat(poses)
    assert isinstance(ev, tectum.EventPacket) and isinstance(truth, PosePacket)
    f, cx, cy = (float(v) for v in sim.truth["camera"])
    return ev, truth, f"{f};{f};{cx};{cy}"


@pytest.mark.slow
def test_tracks_after_the_bootstrap_and_is_deterministic() -> None:
    ev, truth, calib = _simulate(800_000, "240x180")
    boot = 600_000

    def pipeline() -> tuple[tectum.Pipeline, ListSink]:
        p = tectum.Pipeline()
        cam = p.source(ListSource([ev]), id="cam")
        gt = p.source(ListSource([truth]), id="gt")
        p.op("tracker.evo", events=cam, poses=gt, id="evo", calib=calib, bootstrap_us=boot)
        sink = ListSink()
        p.sink(sink, "evo")
        return p, sink

    p, sink = pipeline()
    tectum.run(p)
    est = tectum.concat([q for q in sink.packets if q.kind == Kind.POSES])
    assert isinstance(est, PosePacket)
    assert sum(len(q) for q in sink.packets if q.kind == Kind.MAPS) >= 1
    after = (est.t > boot) & (est.t <= truth.t[-1]) & ~est.lost
    # 200 ms after the bootstrap at ~0.3 Mev/s: a pose per step of edge_align's default 3000 events (~55)
    assert after.sum() > 40 and est.lost[est.t > boot].mean() < 0.2
    true_p, _, _ = tectum.camera.interpolate_poses(est.t[after], truth.t, truth.position, truth.orientation)
    err = np.linalg.norm(est.position[after] - true_p, axis=1)
    path = float(np.linalg.norm(np.diff(truth.position[truth.t > boot], axis=0), axis=1).sum())
    assert np.sqrt(np.mean(err ** 2)) < 0.5 * path, (np.sqrt(np.mean(err ** 2)), path)

    q, sink2 = pipeline()
    with tectum.Stepper(q) as st:
        for a in range(0, ev.t_end, 7_000):  # other packets, other interleaving
            b = min(a + 7_000, ev.t_end)
            st.push(truth.slice_time(max(a, truth.t_start), max(b, truth.t_start)), into="gt")
            st.push(ev.slice_time(a, b), into="cam")
        st.end("gt")
        st.end("cam")
    est2 = tectum.concat([q for q in sink2.packets if q.kind == Kind.POSES])
    np.testing.assert_array_equal(est2.t, est.t)
    np.testing.assert_array_equal(est2.position, est.position)


def test_the_mapper_leaves_out_the_rows_a_tracker_flags_lost() -> None:
    """EVO's mapper gets every tracker pose: rows flagged lost (garbage here)
    are not used, so the maps equal those made without them."""
    from tectum.plugins.map.emvs import Emvs
    from tectum.testing import assert_streams_equal, feed_ports

    stream = Emvs.conformance_stream()
    poses = stream["poses"]
    assert isinstance(poses, PosePacket)
    n = len(poses)
    lost = np.zeros(n, bool)
    lost[5::7] = True
    flagged = PosePacket(poses.t, position=np.where(lost[:, None], 50.0, poses.position),
                         orientation=poses.orientation, lost=lost, t_start=poses.t_start, t_end=poses.t_end)
    kept = poses.take(np.flatnonzero(~lost))
    op = Emvs(**Emvs.conformance_params)
    got = feed_ports(op, {"events": [stream["events"]], "poses": [flagged]})
    want = feed_ports(Emvs(**Emvs.conformance_params), {"events": [stream["events"]], "poses": [kept]})
    assert sum(len(q) for q in want if q.kind == Kind.MAPS) >= 1
    assert_streams_equal(want, got, "lost rows left out")
    assert op.counts["lost_poses"] == int(lost.sum())


def test_a_tracker_without_a_map_after_the_bootstrap_gets_one() -> None:
    """The bootstrap ends before the mapper's first reference view is done
    (keyframe_baseline far off): the tracker has no map and sends lost rows;
    the mapper takes them as a gap and hands the map in progress on at once,
    so tracking starts (before, neither waited out the other: all lost)."""
    ev, truth, calib = _simulate(300_000, "120x90")
    boot = 150_000
    p = tectum.Pipeline()
    cam = p.source(ListSource([ev]), id="cam")
    gt = p.source(ListSource([truth]), id="gt")
    p.op("tracker.evo", events=cam, poses=gt, id="evo", calib=calib, bootstrap_us=boot, window_events=3000, step_events=1000, planes=40, min_depth=1.0, max_depth=4.0, keyframe_baseline=0.5)
    sink = ListSink()
    p.sink(sink, "evo")
    tectum.run(p)
    est = tectum.concat([q for q in sink.packets if q.kind == Kind.POSES])
    assert isinstance(est, PosePacket)
    maps = [q for q in sink.packets if q.kind == Kind.MAPS]
    assert maps and int(maps[0].t[0]) <= boot  # the bootstrap's map
    after = (est.t > boot + 60_000) & (est.t <= truth.t[-1])
    assert after.sum() > 10 and est.lost[after].mean() < 0.5
