"""Every mistake a user can make on the command line ends with one line on
stderr and a non-zero exit status: never a Python traceback. Run as a user
runs it, in a subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

TECTUM = [sys.executable, "-m", "tectum"]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("bad")
    (d / "noise.bin").write_bytes(os.urandom(512))
    (d / "nosource.toml").write_text('[[sink]]\nuri = "out.npz"\ninput = "cam"\n')
    (d / "empty.toml").write_text("[pipeline]\nmax_events = 10\n")
    (d / "folder").mkdir()
    subprocess.run([*TECTUM, "run", "pattern:?duration_us=5000&sensor=16x16", "--sink", str(d / "ok.npz")],
                   check=True, capture_output=True)
    return d


BAD = {
    "info of a missing file": ["info", "{d}/missing.raw"],
    "convert of a missing file": ["convert", "{d}/missing.raw", "{d}/x.npz"],
    "run of a missing file": ["run", "{d}/missing.raw"],
    "a pipeline file without a source": ["run", "{d}/nosource.toml"],
    "a pipeline file without nodes": ["run", "{d}/empty.toml"],
    "info of random bytes": ["info", "{d}/noise.bin"],
    "info of a folder": ["info", "{d}/folder"],
    "info of a URL": ["info", "pattern:"],
    "an unknown output format": ["convert", "{d}/ok.npz", "{d}/out.xyz"],
    "an output folder that does not exist": ["convert", "{d}/ok.npz", "{d}/no/such/dir/out.raw"],
    "an option the format does not have": ["convert", "{d}/ok.npz", "{d}/o.raw", "--skip-bad"],
    "an unknown operator": ["run", "pattern:", "--op", "filter.nope"],
    "a bad parameter value": ["run", "pattern:?duration_us=soon"],
    "an unknown flag": ["run", "pattern:", "--bogus"],
    "a missing argument": ["convert", "{d}/ok.npz"],
    "a bad duration": ["simulate", "shapes", "--duration", "long"],
    "an unknown scene": ["simulate", "no_such_scene", "--duration", "10ms"],
    "an operator that refuses its parameters": ["run", "{d}/ok.npz", "--op", "filter.refractory:period_us=-5"],
    "an operator without the calibration it needs": ["run", "{d}/ok.npz", "--op", "tracker.angular_velocity"],
}


@pytest.mark.parametrize("what", list(BAD))
def test_bad_invocation_is_one_line_and_fails(what: str, files: Path) -> None:
    argv = [a.format(d=files) for a in BAD[what]]
    r = subprocess.run([*TECTUM, *argv], capture_output=True, text=True, timeout=120)
    lines = r.stderr.splitlines()
    assert r.returncode != 0, (what, r.stdout)
    assert "Traceback" not in r.stderr, r.stderr
    assert len(lines) == 1 and "error:" in lines[0], r.stderr


def test_a_parameter_of_two_kinds_names_both(files: Path) -> None:
    """A value fitting none of a parameter's kinds (``dt_us``: a number of
    µs or ``auto``) is refused in the user's words, not as a typing repr."""
    r = subprocess.run([*TECTUM, "run", str(files / "ok.npz"), "--op", "filter.background_activity:dt_us=fast"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr
    assert "parameter 'dt_us': expected int or 'auto', got 'fast'" in r.stderr, r.stderr


def test_a_closed_pipe_ends_quietly() -> None:
    """``tectum plugins --json | head``: the reader goes away before the
    output is written; tectum stops without a word on stderr."""
    read, write = os.pipe()
    os.close(read)  # the reader has gone before tectum writes a byte
    r = subprocess.run([*TECTUM, "plugins", "--json"], stdout=write, stderr=subprocess.PIPE, text=True, timeout=120)
    os.close(write)
    assert r.stderr == "" and r.returncode != 0, r.stderr
