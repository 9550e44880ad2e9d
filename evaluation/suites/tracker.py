"""The ``tracker`` suite: speed, latency and accuracy of the tracker family,
one part per method: ``angular`` (``tracker.angular_velocity`` against the
simulator's truth and the IMU of real recordings, beside reference
implementations where they install) and ``ladder`` (``tracker.ego_motion``:
the model ladder's confusion matrix). Each part is a module
``_tracker_PART`` with ``run(out, quick) -> {"rows": ..., "targets": ...}``;
pictures go to ``out``."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from tectum.evaluation.harness import targets_table

PARTS = ("angular", "ladder")


def run(out: Path, quick: bool) -> dict[str, Any]:
    results: dict[str, Any] = {}
    targets: list[dict[str, Any]] = []
    for part in PARTS:
        print(f"\n== tracker: {part}")
        r: dict[str, Any] = importlib.import_module(f"tectum.evaluation.suites._tracker_{part}").run(out, quick)
        results[part] = r
        targets += r.get("targets", [])
    print("\n" + targets_table(targets))
    return {"parts": results, "targets": targets}
