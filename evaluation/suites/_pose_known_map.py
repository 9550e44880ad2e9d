"""Part ``known_map`` of the ``pose`` suite (being written: no rows yet)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def run(out: Path, quick: bool) -> dict[str, Any]:
    return {"rows": [], "targets": []}
