"""Helpers for the test suite: generated streams and the shared recordings.

Import as ``from helpers import bars, shared_data`` (``tests`` is on the path).
"""

from __future__ import annotations

import os
from pathlib import Path

from tectum import EventPacket, concat

ROOT = Path(__file__).resolve().parents[1]


def shared_data() -> Path | None:
    """The folder of real recordings (../shared/data beside the project), or None."""
    env = os.environ.get("TECTUM_SHARED_DATA")
    p = Path(env) if env else ROOT.parent / "shared" / "data"
    return p if p.is_dir() else None


def bars(duration_us: int = 30_000, sensor: str = "64x48", **kw: object) -> EventPacket:
    """A small moving-bars stream with labelled noise, as one packet."""
    from tectum.sources.pattern import PatternSource

    return concat(list(PatternSource(sensor=sensor, duration_us=duration_us, **kw).packets()))  # type: ignore[arg-type,return-value]
