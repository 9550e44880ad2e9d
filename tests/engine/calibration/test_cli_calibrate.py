"""The user's path: ``tectum calibrate`` on a recording in a file, then
``tectum run ... --op filter.undistort:calib=...`` with what it wrote."""

from __future__ import annotations

import numpy as np
import pytest
from calibration_recordings import CAMERA, Recording, record, write_events

from tectum import EventPacket
from tectum.calibration import read_recording
from tectum.calibration._blink import transition_map
from tectum.camera import read_calibration
from tectum.cli import main
from tectum.sources.simulate.blink_board import Board


def centroids_near(events: EventPacket, span: np.ndarray, points: np.ndarray, r: float = 3.0) -> np.ndarray:
    """Centroid of the ON events at ON→OFF transitions (250 Hz) within ``r``
    px of each of ``points``, in the middle of a view's ``span`` (undistorted
    dots have holes where the lookup table spreads them, so no blobs)."""
    t0, t1 = (int(v) for v in span)
    _, wt = transition_map(events.slice_time(t0 + 10_000, t1 - 10_000), 4000.0)
    vv, uu = np.indices(wt.shape)
    out = []
    for x, y in points:
        w = np.where((uu - x) ** 2 + (vv - y) ** 2 <= r * r, wt, 0)
        out.append([(w * uu).sum() / w.sum(), (w * vv).sum() / w.sum()])
    return np.array(out)


@pytest.mark.parametrize("out, fmt", [("calib.yaml", None), ("calib.txt", None), ("camera_info.yaml", "ros")])
def test_calibrate_then_undistort(dots: Recording, dots_file, tmp_path, capsys, out, fmt) -> None:
    calib = tmp_path / out
    argv = ["calibrate", str(dots_file), "--grid", "7x5", "--spacing", "0.03", "--out", str(calib)]
    assert main(argv + (["--format", fmt] if fmt else [])) == 0
    said = capsys.readouterr()
    assert "views: 8 still (8 used)" in said.out and "reprojection RMS" in said.out
    cam = read_calibration(calib)
    assert abs(cam.fx / CAMERA.fx - 1) < 0.01 and abs(cam.cx - CAMERA.cx) < 1.5
    if fmt is None and out.endswith(".yaml"):
        assert cam.size == (128, 96)
    # the dots of the first view, undistorted by filter.undistort, lie where a lens-free camera puts them
    undistorted = tmp_path / "undistorted.npz"
    assert main(["run", str(dots_file), "--op", f"filter.undistort:calib={calib}", "--sink", str(undistorted)]) == 0
    ev, _ = read_recording(str(undistorted))
    assert ev is not None
    ideal = [CAMERA.undistort_points(px) for px in dots.truth.pixels]  # K, no distortion
    k = int(np.argmax([np.median(np.linalg.norm(px - q, axis=1)) for px, q in zip(dots.truth.pixels, ideal)]))
    assert np.median(np.linalg.norm(dots.truth.pixels[k] - ideal[k], axis=1)) > 1.5  # the lens moved them that much
    inside = ideal[k][np.all((ideal[k] > 3) & (ideal[k] < np.array([124, 92])), axis=1)]  # not cut by the image
    assert len(inside) > 20
    found = centroids_near(ev, dots.truth.spans[k], inside)
    assert np.median(np.linalg.norm(found - inside, axis=1)) < 0.5


def test_stereo_pair_from_two_files(tmp_path, capsys) -> None:
    board = Board()
    left = record(board, 6, seed=11, tilt_deg=25)
    # the right camera: the same camera 5 cm to the right (x_right = x_left - (0.05, 0, 0))
    right = record(board, camera=CAMERA, R=left.truth.R, t=left.truth.t - np.array([0.05, 0, 0]), seed=12)
    lf, rf = write_events(left.events, tmp_path / "l.npz"), write_events(right.events, tmp_path / "r.npz")
    out = tmp_path / "stereo.yaml"
    code = main(["calibrate", str(lf), str(rf), "--grid", "7x5", "--spacing", "0.03", "--out", str(out),
                 "--min-views", "4"])
    said = capsys.readouterr()
    if code != 0:
        pytest.fail(said.err)
    assert "baseline 0.05" in said.out
    assert main(["run", str(lf), "--op", f"filter.undistort:calib={out},side=left", "--sink",
                 str(tmp_path / "rl.npz")]) == 0
    assert main(["run", str(rf), "--op", f"filter.undistort:calib={out},side=right", "--sink",
                 str(tmp_path / "rr.npz")]) == 0
    ys = []
    for name, rec, side in (("rl.npz", left, "left"), ("rr.npz", right, "right")):
        ev, _ = read_recording(str(tmp_path / name))
        assert isinstance(ev, EventPacket)
        cam = read_calibration(out, side)  # type: ignore[arg-type]
        where = cam.undistort_points(rec.truth.pixels[0], P=cam.P, R=cam.R)
        ys.append(centroids_near(ev, rec.truth.spans[0], where)[:, 1])
    assert np.median(np.abs(ys[0] - ys[1])) < 0.5  # rectified: each dot on the same row in both


def test_bad_input_one_line_no_file(tmp_path, capsys) -> None:
    rec = record(Board(), 2, seed=13)
    src = write_events(rec.events, tmp_path / "two_views.npz")
    out = tmp_path / "calib.yaml"
    code = main(["calibrate", str(src), "--grid", "7x5", "--spacing", "0.03", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and not out.exists()
    assert err.count("\n") == 1
    assert "2 still views found at 250.0 Hz, 2 with the whole 7x5 grid; need at least 5 views" in err
    code = main(["calibrate", str(src), "--grid", "7", "--spacing", "0.03", "--out", str(out)])
    assert code == 1 and "expected COLSxROWS" in capsys.readouterr().err and not out.exists()
