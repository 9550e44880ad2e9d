"""Files a sink writes get the permissions the user's umask gives any new
file (0o644 under umask 022), not the 0o600 of a private temporary file:
every registered sink with an extension, so a new one is covered (fed
events, or a tick of the kind it takes)."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

import tectum
from tectum import Kind, packet_class
from tectum.testing import ListSource


def _file_sinks() -> list[tuple[str, str]]:
    return [(e.name, e.cls.extensions[0]) for e in tectum.get_registry().sinks.values() if e.cls.extensions]


@pytest.fixture(params=[0o022, 0o077], ids=["umask022", "umask077"])
def umask(request: pytest.FixtureRequest) -> Iterator[int]:
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


@pytest.mark.parametrize("name, ext", _file_sinks(), ids=lambda v: v)
def test_output_honours_the_umask(name: str, ext: str, umask: int, tmp_path: Path) -> None:
    out = tmp_path / f"out{ext}"
    p = tectum.Pipeline()
    cls = tectum.get_registry().sinks[name].cls
    if tectum.accepts(cls.consumes, Kind.EVENTS):
        src = p.source("pattern:", sensor="32x24", duration_us=100_000)
    else:  # a sink of another kind (poses, points ...): a tick of it
        src = p.source(ListSource([packet_class(cls.consumes[0]).empty(0, 10)]))
    p.sink(str(out), src)
    tectum.run(p)
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~umask, (name, oct(out.stat().st_mode))
    assert sorted(f.name for f in tmp_path.iterdir()) == [out.name]  # no temporary file left beside it
