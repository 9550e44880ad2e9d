"""What a sink did not write, said plainly: one line per sink and reason on
stderr, ``out.raw: not written: 59 frames, 2,363 imu samples (EVT 2.0 holds
events only)``."""

from __future__ import annotations

from collections.abc import Mapping

from tectum import Kind, accepts
from tectum._stats import amounts

__all__ = ["unwritten_lines"]


def unwritten_lines(target: str, cls: type, counts: Mapping[str, int]) -> list[str]:
    """The lines for sink class ``cls`` writing ``target``, given what it did
    not write by kind (events or samples)."""
    by_reason: dict[str, dict[str, int]] = {}
    for kind, n in counts.items():
        if n:
            by_reason.setdefault(_why(cls, kind), {})[kind] = n
    return [f"{target}: not written: {amounts(c)} ({why})" for why, c in by_reason.items()]


def _why(cls: type, kind: str) -> str:
    title = getattr(cls, "title", "") or getattr(cls, "name", "") or cls.__name__
    consumes = tuple(getattr(cls, "consumes", ()))
    if accepts(consumes, Kind(kind)):  # taken, then left out by the sink itself
        holds = getattr(cls, "holds", "")
        return f"{title} holds {holds}" if holds else f"{title} does not store {kind}"
    kinds = [str(k) for k in consumes]
    listed = " and ".join([", ".join(kinds[:-1]), kinds[-1]]) if len(kinds) > 1 else "".join(kinds)
    return f"{title} holds {listed} only"
