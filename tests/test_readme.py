"""Every code block of the README runs as written, so an example can never
drift from the code.

In order, in one scratch folder: ```python blocks run in one shared
namespace (a later block may use what an earlier one defined), ```sh blocks
run in bash with this environment's ``tectum`` and ``python3`` first on the
PATH, ```toml blocks must parse. The folder holds the recordings the
examples name (``recording.raw``, ``in.raw`` ...), written by tectum itself.
An HTML comment on the line before a block tells this test what to do
with it instead:

* ``<!-- test: skip REASON -->`` does not run it (installs, the test suite
  itself: use sparingly);
* ``<!-- test: file NAME -->`` saves it as NAME in the folder, for a later
  block to use.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
_BLOCK = re.compile(r"(?:<!--\s*test:\s*(?P<marker>[^>]*?)\s*-->\n)?```(?P<lang>\w*)\n(?P<code>.*?)```", re.S)
#: Inputs the examples name, each made by ``tectum run`` from a pattern (2.5 s, so time ranges fit).
INPUTS = ("recording.raw", "recording.npz", "in.raw", "in.aedat4")


@dataclass
class Block:
    lang: str
    code: str
    marker: str
    line: int

    @property
    def where(self) -> str:
        return f"README.md line {self.line} ({self.lang})"


def blocks(text: str) -> list[Block]:
    return [Block(m["lang"], m["code"], m["marker"] or "", text.count("\n", 0, m.start("code")))
            for m in _BLOCK.finditer(text)]


def test_markers_are_understood() -> None:
    found = blocks(README.read_text())
    assert {b.lang for b in found} <= {"python", "sh", "toml"}, "a block in a language this test does not run"
    for b in found:
        assert not b.marker or re.fullmatch(r"(skip \S.*|file [\w.-]+)", b.marker), f"{b.where}: {b.marker!r}"
    skipped = [b for b in found if b.marker.startswith("skip")]
    assert len(skipped) <= len(found) // 3, "most examples must run"


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("readme")
    sinks = [a for name in INPUTS for a in ("--sink", str(d / name))]
    subprocess.run([sys.executable, "-m", "tectum", "run", "pattern:?duration_us=2500000&sensor=64x48", *sinks],
                   check=True, capture_output=True)
    return d


# every block in turn, each sh block a fresh process compiling its kernels: from an empty numba cache on a
# loaded machine that took more than the suite's 300 s per test; a block that hangs still fails after 300 s
@pytest.mark.timeout(1800)
def test_every_block_runs(folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(folder)
    env = dict(os.environ, PATH=os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]))
    namespace: dict[str, object] = {"__name__": "readme"}
    ran = 0
    for b in blocks(README.read_text()):
        if b.marker.startswith("skip"):
            continue
        if b.marker.startswith("file "):
            (folder / b.marker.split(" ", 1)[1]).write_text(b.code)
        elif b.lang == "python":
            exec(compile("\n" * b.line + b.code, str(README), "exec"), namespace)
        elif b.lang == "sh":
            r = subprocess.run(["bash", "-euo", "pipefail", "-c", b.code], env=env, capture_output=True, text=True,
                               timeout=300)
            assert r.returncode == 0, f"{b.where}:\n{b.code}\n{r.stderr[-2000:]}"
        else:
            tomllib.loads(b.code)
        ran += 1
    assert ran >= 8
