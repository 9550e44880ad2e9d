"""repr.motion_compensated: events + gyro (or + poses) give sharper images
than plain event frames, land where the scene is at the window's end, and
the two rotation sources agree."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import tectum
from tectum import Pipeline, PipelineError, PosePacket
from tectum.camera import rot_to_quat, so3_exp
from tectum.plugins.repr import MotionCompensated
from tectum.plugins.repr.motion_compensated import _rotating_points
from tectum.testing import ListSink, ListSource, feed_ports

SENSOR, F, OMEGA = (120, 90), 100.0, (0.3, 10.0, 0.8)
CALIB = f"{F};{F};{SENSOR[0] / 2};{SENSOR[1] / 2}"


def _scene():
    return _rotating_points(duration_us=30_000, sensor=SENSOR, f=F, omega=OMEGA)


def _frames(streams, **kw):
    out = feed_ports(MotionCompensated(calib=CALIB, window_us=10_000, **kw), {k: [v] for k, v in streams.items()})
    return [q for q in out if len(q)]


def _sharpness(img):
    return float(np.var(img))


def test_compensated_images_are_sharper_than_plain_frames():
    streams = _scene()
    comp = _frames(streams)
    still = dict(streams, imu=streams["imu"].with_fields(gyro=np.zeros_like(streams["imu"].gyro)))
    plain = _frames(still)  # no rotation: the events where they fired
    assert len(comp) == len(plain) == 3
    for c, p in zip(comp, plain):
        assert 0.9 * p.images.sum() < c.images.sum() <= p.images.sum() + 1e-3  # the same events, moved (a few out)
        assert _sharpness(c.images[0]) > 3 * _sharpness(p.images[0])


def test_events_land_where_the_points_are_at_the_window_end():
    streams = _scene()
    comp = _frames(streams)[1]  # the window [10, 20) ms, warped to 19.999 ms
    ev = streams["events"].slice_time(19_900, 20_000)  # the points' positions at the window end
    img = comp.images[0]
    for x, y in zip(ev.x, ev.y):
        patch = img[max(y - 1, 0):y + 2, max(x - 1, 0):x + 2]
        assert patch.sum() > 30, (x, y)  # ~100 events of the point piled up within a pixel


def test_poses_give_the_same_image_as_the_gyro():
    streams = _scene()
    t = np.arange(0, 30_001, 2_000, dtype=np.int64)
    q = rot_to_quat(so3_exp(np.outer(t * 1e-6, OMEGA)))
    poses = PosePacket(t, position=np.zeros((len(t), 3)), orientation=q, t_start=0, t_end=30_001)
    by_imu = _frames(streams)
    by_poses = _frames({"events": streams["events"], "poses": poses})
    assert len(by_imu) == len(by_poses)
    for a, b in zip(by_imu, by_poses):
        assert np.abs(a.images - b.images).max() < 0.02 * a.images.max()


@pytest.mark.parametrize("ports", [{}])
def test_a_rotation_source_is_needed(ports):
    p = Pipeline()
    p.source(ListSource([_scene()["events"]]), id="cam")
    p.source(ListSource([_scene()["imu"]]), id="imu")
    p.source(ListSource([PosePacket([0], position=[[0, 0, 0]], orientation=[[0, 0, 0, 1]])]), id="gt")
    p.op("repr.motion_compensated", {"events": "cam", **ports}, id="mc", calib=CALIB)
    p.sink("null:", "mc")
    with pytest.raises(PipelineError, match="connect the port 'imu' \\(gyro\\) or 'poses'"):
        p.validate()


def _ecd_folder(tmp_path):
    s = _scene()
    ev, imu = s["events"], s["imu"]
    with open(tmp_path / "events.txt", "w") as f:
        for t, x, y, p in zip(ev.t, ev.x, ev.y, ev.p):
            f.write(f"{t / 1e6:.6f} {x} {y} {int(p > 0)}\n")
    with open(tmp_path / "imu.txt", "w") as f:
        for t, a, g in zip(imu.t, imu.accel, imu.gyro):
            f.write(f"{t / 1e6:.6f} {' '.join(map(str, a))} {' '.join(map(str, g))}\n")
    (tmp_path / "calib.txt").write_text(f"{F} {F} {SENSOR[0] / 2} {SENSOR[1] / 2} 0 0 0 0 0\n")
    return s


def test_on_an_ecd_folder_the_calibration_and_the_imu_come_from_the_recording(tmp_path):
    s = _ecd_folder(tmp_path)
    p = Pipeline()
    src = p.source(str(tmp_path / "events.txt"), sensor=f"{SENSOR[0]}x{SENSOR[1]}")
    p.op("repr.motion_compensated", src, id="mc", window_us=10_000)  # ports by kind, calib beside
    sink = ListSink()
    p.sink(sink, "mc")
    tectum.run(p)
    got = [q for q in sink.packets if len(q)]
    ref = _frames(s)
    assert len(got) == len(ref)
    for a, b in zip(got, ref):
        np.testing.assert_allclose(a.images, b.images, atol=1e-4)


def test_from_the_command_line(tmp_path):
    _ecd_folder(tmp_path)
    out = subprocess.run([sys.executable, "-m", "tectum", "run", str(tmp_path / "events.txt"), "--op",
                          "repr.motion_compensated:window_us=10000", "--sink", "null:", "--stats"],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "motion_compensated" in out.stdout + out.stderr


def test_with_both_the_gyro_is_used():
    s = _scene()
    t = np.arange(0, 30_001, 2_000, dtype=np.int64)
    wrong = PosePacket(t, position=np.zeros((len(t), 3)), orientation=np.tile([0, 0, 0, 1.0], (len(t), 1)),
                       t_start=0, t_end=30_001)  # a camera standing still: not what the gyro says
    both = _frames({"events": s["events"], "imu": s["imu"], "poses": wrong})
    for a, b in zip(both, _frames(s)):
        np.testing.assert_array_equal(a.images, b.images)


def test_windows_follow_the_events_not_a_longer_motion_stream():
    s = _scene()  # 30 ms of events
    t = np.arange(0, 200_001, 2_000, dtype=np.int64)  # 200 ms of poses
    q = rot_to_quat(so3_exp(np.outer(t * 1e-6, OMEGA)))
    long_poses = PosePacket(t, position=np.zeros((len(t), 3)), orientation=q, t_start=0, t_end=200_001)
    out = feed_ports(MotionCompensated(calib=CALIB, window_us=10_000),
                     {"events": [s["events"]], "poses": [long_poses]})
    assert [int(f.t[0]) for f in out] == [9_999, 19_999, 29_999]
