"""Every event file tectum writes opens again through ``tectum info``,
``tectum convert`` and ``tectum run``: one way of choosing a source (the
registry's), so a format written by a sink is never "unrecognised".

Parametrised over the registry's sinks, so a new file sink is covered as
soon as it registers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import tectum
from tectum.cli import main

#: Sinks with an extension that write pictures, not events: nothing to reopen.
PICTURES = {"video", "png"}
SOURCE = "pattern:?duration_us=20000&sensor=32x24&noise_hz=2"


def _file_sinks() -> list[tuple[str, str]]:
    sinks = tectum.get_registry().sinks
    assert PICTURES <= set(sinks), "a picture sink was renamed: update PICTURES"
    return [(e.name, e.cls.extensions[0]) for e in sinks.values() if e.cls.extensions and e.name not in PICTURES]


def _events(path: Path) -> tectum.EventPacket:
    from tectum.sources.npz import read_npz

    return read_npz(str(path))


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "ref.npz"
    assert main(["run", SOURCE, "--sink", str(out)]) == 0
    return out


@pytest.mark.parametrize("name, ext", _file_sinks(), ids=lambda v: v)
def test_written_file_reopens_in_info_convert_and_run(name: str, ext: str, reference: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    ref = _events(reference)
    f = tmp_path / f"out{ext}"
    assert main(["run", SOURCE, "--sink", str(f)]) == 0
    sensor = ["--sensor", "32x24"]
    capsys.readouterr()
    assert main(["info", str(f), "--json", *sensor]) == 0, name
    info = json.loads(capsys.readouterr().out)
    assert info["events"] == len(ref) and tuple(info["sensor"]) == (32, 24), info
    assert main(["info", str(f), *sensor]) == 0  # the table form too
    assert f"{len(ref):,}" in capsys.readouterr().out
    conv = tmp_path / "converted.npz"
    assert main(["convert", str(f), str(conv), *sensor]) == 0
    again = tmp_path / "run.npz"
    assert main(["run", str(f), "--sink", str(again)]) == 0
    for got in (_events(conv), _events(again)):
        for c in "txyp":
            assert np.array_equal(getattr(got, c), getattr(ref, c)), (name, c)
