"""The ``map`` suite: speed and accuracy of the map family against the
simulator's truth (and ``ecd/slider_depth`` where the shared data is
present), one part per method: ``reconstruction`` (``map.high_pass``,
``map.complementary``), ``mosaic`` (``map.poisson_mosaic``) and ``emvs``
(``map.emvs``). Each part is a module ``_map_PART`` with
``run(out, quick) -> {"rows": ..., "targets": ...}``; pictures go to ``out``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tectum.evaluation.harness import run_parts

PARTS = ("reconstruction", "mosaic", "emvs")


def run(out: Path, quick: bool) -> dict[str, Any]:
    return run_parts("map", PARTS, out, quick)
