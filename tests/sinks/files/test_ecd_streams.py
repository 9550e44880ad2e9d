"""The issue's user path on a UZH event-camera-dataset folder (events.txt,
imu.txt, groundtruth.txt, calib.txt, generated here): ``tectum run
events.txt --sink traj.tum`` writes the ground-truth poses, ``--sink
imu.csv`` the IMU samples, and an operator making frames ``--sink mc.npz``
the frames; each file opens again in info, run and convert."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import tectum
from tectum import FramePacket, ImuPacket, Kind, PosePacket
from tectum.cli import main
from tectum.sources.files import open_file
from tectum.testing import assert_streams_equal


@pytest.fixture(scope="module")
def ecd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("ecd")
    rng = np.random.default_rng(3)
    n = 3000
    t = np.sort(rng.integers(0, 500_000, n))
    x, y, p = rng.integers(0, 240, n), rng.integers(0, 180, n), rng.integers(0, 2, n)
    (d / "events.txt").write_text("".join(f"{a / 1e6:.9f} {b} {c} {e}\n" for a, b, c, e in zip(t, x, y, p)))
    imu = rng.normal(size=(100, 6))
    (d / "imu.txt").write_text("".join(f"{k * 0.005:.6f} " + " ".join(map(repr, r.tolist())) + "\n"
                                       for k, r in enumerate(imu)))
    q = rng.normal(size=(40, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    pos = rng.normal(size=(40, 3))
    (d / "groundtruth.txt").write_text("".join(f"{k * 0.0125:.9f} " + " ".join(map(repr, [*a.tolist(), *b.tolist()]))
                                               + "\n" for k, (a, b) in enumerate(zip(pos, q))))
    (d / "calib.txt").write_text("199.1 198.8 120.5 90.2 -0.12 0.03 0.0001 -0.0002 0.0\n")
    return d


def _truth(ecd: Path) -> tuple[ImuPacket, PosePacket]:
    imu = np.loadtxt(ecd / "imu.txt")
    gt = np.loadtxt(ecd / "groundtruth.txt")
    return (ImuPacket(np.arange(100) * 5000, accel=imu[:, 1:4], gyro=imu[:, 4:7]),
            PosePacket(np.arange(40) * 12_500, position=gt[:, 1:4], orientation=gt[:, 4:8]))


def _read(path: Path) -> list[tectum.Packet]:
    return list(open_file(str(path)).packets())


def test_run_events_txt_to_tum_writes_the_ground_truth(ecd: Path, tmp_path: Path) -> None:
    out = tmp_path / "traj.tum"
    assert main(["run", str(ecd / "events.txt"), "--sink", str(out)]) == 0
    assert_streams_equal([_truth(ecd)[1]], _read(out))
    for ours, theirs in zip(out.read_text().splitlines()[1:], (ecd / "groundtruth.txt").read_text().splitlines()):
        assert ours.split()[1:] == theirs.split()[1:]  # the same digits: repr of the same float64
        assert ours.split()[0] == theirs.split()[0][:-3]  # seconds with 6 decimals, not 9


def test_run_events_txt_to_csv_writes_the_imu(ecd: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "imu.csv"
    assert main(["run", str(ecd / "events.txt"), "--sink", str(out)]) == 0
    assert_streams_equal([_truth(ecd)[0]], _read(out))
    named = tmp_path / "poses.csv"
    assert main(["run", str(ecd / "events.txt"), "--sink", f"{named}?kind=poses"]) == 0
    assert_streams_equal([_truth(ecd)[1]], _read(named))
    assert sorted(f.name for f in tmp_path.iterdir()) == ["imu.csv", "poses.csv"]
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    assert "imu 100" in capsys.readouterr().out
    again = tmp_path / "again.npz"
    assert main(["convert", str(out), str(again)]) == 0
    assert_streams_equal([_truth(ecd)[0]], _read(again))


def test_run_events_txt_through_a_frame_operator_to_npz_writes_frames(ecd: Path, tmp_path: Path) -> None:
    out = tmp_path / "count.npz"
    assert main(["run", str(ecd / "events.txt"), "--op", "repr.count:window_us=50000", "--sink", str(out)]) == 0
    frames = [q for q in _read(out) if q.kind == Kind.FRAMES]
    assert sum(len(q) for q in frames) == 10 and np.load(out)["frames_images"].shape == (10, 180, 240)
    total = sum(int(q.images.sum()) for q in frames if len(q))  # type: ignore[attr-defined]
    assert total == 3000  # every event counted once


def test_run_events_txt_motion_compensated_to_npz_writes_frames(ecd: Path, tmp_path: Path) -> None:
    if "repr.motion_compensated" not in tectum.get_registry().operators:
        pytest.skip("repr.motion_compensated is not registered yet")
    for name in ("events.txt", "groundtruth.txt", "calib.txt"):  # rotation from the poses (no imu.txt to choose)
        (tmp_path / name).write_bytes((ecd / name).read_bytes())
    out = tmp_path / "mc.npz"
    assert main(["run", str(tmp_path / "events.txt"), "--op", "repr.motion_compensated", "--sink", str(out)]) == 0
    frames = [q for q in _read(out) if isinstance(q, FramePacket)]
    assert sum(len(q) for q in frames) > 0
