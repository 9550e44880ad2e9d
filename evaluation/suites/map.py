"""The ``map`` suite: speed and accuracy of the map family against the
simulator's truth (and ``ecd/slider_depth`` where the shared data is
present), one part per method: ``reconstruction`` (``map.high_pass``,
``map.complementary``), ``mosaic`` (``map.poisson_mosaic``) and ``emvs``
(``map.emvs``). Each part is a module ``_map_PART`` with
``run(out, quick) -> {"rows": ..., "targets": ...}``; pictures go to ``out``."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from tectum.evaluation.harness import targets_table

PARTS = ("reconstruction", "mosaic", "emvs")


def run(out: Path, quick: bool) -> dict[str, Any]:
    results: dict[str, Any] = {}
    targets: list[dict[str, Any]] = []
    for part in PARTS:
        print(f"\n== map: {part}")
        r: dict[str, Any] = importlib.import_module(f"tectum.evaluation.suites._map_{part}").run(out, quick)
        results[part] = r
        targets += r.get("targets", [])
    print("\n" + targets_table(targets))
    return {"parts": results, "targets": targets}
