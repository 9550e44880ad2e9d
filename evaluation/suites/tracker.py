"""The ``tracker`` suite: speed, latency and accuracy of the tracker family,
one part per method: ``angular`` (``tracker.angular_velocity`` against the
simulator's truth and the IMU of real recordings) and ``ladder`` (``tracker.ego_motion``:
the model ladder's confusion matrix), ``features`` (``tracker.features``:
EKLT and ICP against the rotation truth and KLT), ``clusters``
(``tracker.clusters`` on simulated moving objects) and ``leds``
(``tracker.led_markers`` on a simulated LED body: ids, positions, pose). Each part is a module
``_tracker_PART`` with ``run(out, quick) -> {"rows": ..., "targets": ...}``;
pictures go to ``out``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tectum.evaluation.harness import run_parts

PARTS = ("angular", "ladder", "features", "clusters", "leds")


def run(out: Path, quick: bool) -> dict[str, Any]:
    return run_parts("tracker", PARTS, out, quick)
