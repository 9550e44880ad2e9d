"""The ``calibrate`` suite: ``tectum.calibrate`` against the blinking-board
simulator's known camera. Parts: ``accuracy`` (intrinsics and distortion
errors, reprojection RMS, clean, with noise and with mains flicker; the
targets; a picture) and ``failure`` (noise, number of views, board tilt,
blink frequency against timestamp jitter). Each part is a module
``_calibrate_PART`` with ``run(out, quick) -> {"rows": ..., "targets": ...}``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tectum.evaluation.harness import run_parts

PARTS = ("accuracy", "failure")


def run(out: Path, quick: bool) -> dict[str, Any]:
    return run_parts("calibrate", PARTS, out, quick)
