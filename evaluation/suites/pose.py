"""The ``pose`` suite: 6-DoF camera tracking against ground truth, one part
per method: ``known_map`` (``tracker.pose_6dof`` against a known photometric
map on simulated planes and boxes at increasing speed, and on
``ecd/slider_depth``: ATE, RPE, position RMSE as % of the path, median
rotation error, events/s and pose updates/s) and ``failure``
(``tracker.pose_6dof``'s failure maps over speed, event noise, map error and
texture) and ``evo`` (``tracker.edge_align`` and ``map.emvs`` in a loop on
simulated planes and boxes and on ``ecd/slider_depth``: drift as % of the
path, ATE, RPE, events/s and real-time factor, the EVO map picture). Each
part is a module ``_pose_PART`` with ``run(out, quick) -> {"rows": ...,
"targets": ...}``; pictures go to ``out``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tectum.evaluation.harness import run_parts

PARTS = (
    "known_map",
    "failure",
    "evo",
)


def run(out: Path, quick: bool) -> dict[str, Any]:
    return run_parts("pose", PARTS, out, quick)
