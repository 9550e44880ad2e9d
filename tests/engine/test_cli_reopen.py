"""Every file tectum writes opens again through ``tectum info``, ``tectum
convert`` and ``tectum run``: one way of choosing a source (the registry's),
so a format written by a sink is never "unrecognised".

Parametrised over the registry's sinks with an extension, so a new file sink
is covered as soon as it registers: an event sink gets moving bars, a sink of
another kind (poses, points ...) a stream of the first kind it takes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from sink_inputs import BARS, sink_kind, write_input

import tectum
from tectum import Kind
from tectum.cli import main
from tectum.sources.files import open_file
from tectum.testing import assert_streams_equal

#: Sinks with an extension that write pictures, not streams: nothing to reopen.
PICTURES = {"video", "png"}


def _file_sinks() -> list[tuple[str, str, Kind]]:
    sinks = tectum.get_registry().sinks
    assert PICTURES <= set(sinks), "a picture sink was renamed: update PICTURES"
    return [(e.name, e.cls.extensions[0], sink_kind(e.cls)) for e in sinks.values()
            if e.cls.extensions and e.name not in PICTURES]


def _stream(path: Path, kind: Kind) -> list[tectum.Packet]:
    return [q for q in open_file(str(path)).packets() if q.kind == kind]


@pytest.mark.parametrize("name, ext, kind", _file_sinks(), ids=lambda v: str(v))
def test_written_file_reopens_in_info_convert_and_run(name: str, ext: str, kind: Kind, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    ref, f = tmp_path / "ref.npz", tmp_path / f"out{ext}"
    if kind == Kind.EVENTS:
        assert main(["run", BARS, "--sink", str(ref)]) == 0
    else:
        write_input(ref, kind)
    assert main(["run", str(ref), "--sink", str(f)]) == 0
    want = _stream(ref, kind)
    n = sum(len(q) for q in want)
    sensor = ["--sensor", "32x24"] if kind == Kind.EVENTS else []
    capsys.readouterr()
    assert main(["info", str(f), "--json", *sensor]) == 0, name
    info = json.loads(capsys.readouterr().out)
    assert info["streams"].get(str(kind)) == n, info
    if kind == Kind.EVENTS:
        assert info["events"] == n and tuple(info["sensor"]) == (32, 24), info
    assert main(["info", str(f), *sensor]) == 0  # the table form too
    assert f"{n:,}" in capsys.readouterr().out
    conv, again = tmp_path / "converted.npz", tmp_path / "run.npz"
    assert main(["convert", str(f), str(conv), *sensor]) == 0
    assert main(["run", str(f), "--sink", str(again)]) == 0
    for back in (conv, again):
        got = _stream(back, kind)
        if kind == Kind.EVENTS:  # formats differ in what else they keep (extra columns, the sensor size)
            a, b = tectum.concat(want), tectum.concat(got)
            assert all(np.array_equal(getattr(a, c), getattr(b, c)) for c in "txyp"), name
        else:
            assert_streams_equal(want, got, f"{kind} via {name}")
