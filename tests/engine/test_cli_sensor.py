"""Where a sensor size came from, when the file does not say it: ``info``
names the source of the size, and ``convert`` says so when it writes a size
read off the coordinates into a file that records one (a subprocess, as a
user runs them)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

TECTUM = [sys.executable, "-m", "tectum"]
#: events whose largest coordinates are (39, 29): a 40x30 extent
LINES = "0.000001 3 4 1\n0.000002 39 0 0\n0.000003 0 29 1\n"


def _tectum(*args: str) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([*TECTUM, *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r


def _sensor_line(info: str) -> str:
    return next(line.split(":", 1)[1].strip() for line in info.splitlines() if line.strip().startswith("sensor:"))


def test_info_says_where_a_size_the_file_does_not_say_came_from(tmp_path: Path) -> None:
    f = tmp_path / "events.txt"
    f.write_text(LINES)
    assert _sensor_line(_tectum("info", str(f)).stdout) == (
        "40x30 (from the extent of the coordinates: the file does not say; --sensor gives the camera's)")
    assert _sensor_line(_tectum("info", "--sensor", "64x48", str(f)).stdout) == "64x48 (from the sensor option)"
    cv2.imwrite(str(tmp_path / "frame.png"), np.zeros((48, 64), np.uint8))
    (tmp_path / "images.txt").write_text("0.000001 frame.png\n")
    assert _sensor_line(_tectum("info", str(f)).stdout) == (
        "64x48 (from the first image of images.txt: the file does not say)")
    out = tmp_path / "out.aedat4"
    _tectum("convert", str(f), str(out))
    assert _sensor_line(_tectum("info", str(out)).stdout) == "64x48"  # the file says it now


def test_convert_says_when_it_writes_a_size_read_off_the_coordinates(tmp_path: Path) -> None:
    f = tmp_path / "events.txt"
    f.write_text(LINES)
    for name in ("a.aedat4", "a.h5", "a.raw", "a.dat", "a.es"):
        r = _tectum("convert", str(f), str(tmp_path / name))
        assert r.stderr == (f"{tmp_path / name}: sensor 40x30 written, from the extent of the coordinates: the "
                            "input does not say (--sensor WIDTHxHEIGHT gives the camera's)\n"), name
        assert _sensor_line(_tectum("info", str(tmp_path / name)).stdout) == "40x30", name
    for args in (("convert", str(f), str(tmp_path / "b.txt")),  # text records no sensor size
                 ("convert", "--sensor", "64x48", str(f), str(tmp_path / "b.aedat4"))):
        assert _tectum(*args).stderr == "", args
    assert _sensor_line(_tectum("info", str(tmp_path / "b.aedat4")).stdout) == "64x48"
