"""The demo's picture explains itself: a title, a caption over each panel
with its counts, a legend of the colours and a scale bar, around the two
enlarged panels."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from tectum.cli import main
from tectum.cli.demo import NOISE, OFF, ON, SCALE


def _text_pixels(band: np.ndarray) -> int:
    return int((band.min(axis=2) > 200).sum())  # light grey text on the dark page


def test_demo_picture_has_title_captions_legend_and_scale(tmp_path: Path) -> None:
    assert main(["demo", "--out", str(tmp_path), "--duration-us", "60000"]) == 0
    img = cv2.imread(str(tmp_path / "before_after.png"))
    report = json.loads((tmp_path / "report.json").read_text())
    h, w = img.shape[:2]
    assert w >= 2 * 346 * SCALE and h >= 260 * SCALE  # two enlarged 346x260 panels
    half = w // 2
    assert _text_pixels(img[:30, :half // 2]) > 50  # the title
    assert _text_pixels(img[30:60, :half // 2]) > 50 and _text_pixels(img[30:60, half:half + half // 2]) > 50
    legend = img[-60:]
    for colour in (ON, OFF, NOISE):  # a swatch of each colour in the legend
        assert (np.abs(legend.astype(int) - colour).sum(axis=2) == 0).sum() >= 100, colour
    white = legend.min(axis=2) > 200
    runs = [np.diff(np.flatnonzero(np.diff(np.r_[0, row, 0]))) for row in white.astype(np.int8)]
    assert any(50 * SCALE in r[::2] or 50 * SCALE + 1 in r[::2] for r in runs)  # the 50 px scale bar
    assert report["events_in"] > report["events_out"] > 0
    assert "noise in yellow" in (tmp_path / "report.md").read_text()
