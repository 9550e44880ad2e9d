"""``tectum run`` over time shards and over file patterns, as a user runs it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from shards import recording

TECTUM = [sys.executable, "-m", "tectum"]


def cli(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([*TECTUM, *args], capture_output=True, text=True)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def main(capsys: pytest.CaptureFixture[str], *args: str, status: int = 0) -> tuple[str, str]:
    """The command in this process (the process pool forks it): stdout, stderr."""
    from tectum.cli import main as tectum_main

    assert tectum_main(list(args)) == status
    out = capsys.readouterr()
    return out.out, out.err


def one_run(rec: Path, out: Path) -> None:
    """The reference: the chain over ``rec`` in one sequential run."""
    import tectum

    p = tectum.Pipeline()
    node = p.source(str(rec))
    node = p.op("filter.background_activity", node, dt_us=4000)
    p.sink(str(out), p.op("flow.plane_fit", node, window_us=20_000))
    tectum.run(p)


def same_npz(a: Path, b: Path) -> None:
    x, y = np.load(a), np.load(b)
    assert x.files == y.files
    for k in x.files:
        assert np.array_equal(x[k], y[k], equal_nan=x[k].dtype.kind == "f"), k


CHAIN = ["--op", "filter.background_activity:dt_us=4000", "--op", "flow.plane_fit:window_us=20000"]


@pytest.mark.slow
def test_shards_on_dask_equal_one_run(tmp_path):
    """The command in a subprocess, on a LocalCluster of worker processes."""
    pytest.importorskip("distributed", reason="dask.distributed is not installed (pip install '.[dask]')")
    rec = recording(tmp_path / "rec.dat")
    one_run(rec, tmp_path / "one.npz")
    r = cli("run", str(rec), *CHAIN, "--sink", str(tmp_path / "four.npz"), "--executor", "dask", "--shards", "4",
            "--workers", "2", "--stats")
    assert "out of 4 shard(s)" in r.stdout and "#3 [" in r.stdout
    same_npz(tmp_path / "one.npz", tmp_path / "four.npz")
    assert sorted(os.listdir(tmp_path)) == ["four.npz", "one.npz", "rec.dat"]  # no scratch left


def test_a_pattern_runs_each_file_and_resumes(tmp_path, capsys):
    corpus = tmp_path / "corpus" / "day1"
    corpus.mkdir(parents=True)
    for i in range(3):
        recording(corpus / f"r{i}.dat", duration_us=60_000 + 20_000 * i)
    pattern = str(tmp_path / "corpus" / "**" / "*.dat")
    out = str(tmp_path / "out" / "{parent}-{stem}.npz")
    stdout, _ = main(capsys, "run", pattern, *CHAIN, "--sink", out)
    assert "out of 3 file(s)" in stdout
    made = sorted((tmp_path / "out").iterdir())
    assert [p.name for p in made] == ["day1-r0.npz", "day1-r1.npz", "day1-r2.npz"]
    for i in range(3):  # each as one run of its file gives it
        one_run(corpus / f"r{i}.dat", tmp_path / f"ref{i}.npz")
        same_npz(tmp_path / f"ref{i}.npz", made[i])
    _, stderr = main(capsys, "run", pattern, *CHAIN, "--sink", out)  # all done: nothing runs
    assert "nothing to do: the outputs of all 3 file(s) exist" in stderr
    before = {p.name: p.stat().st_mtime_ns for p in made}
    made[1].unlink()  # as if stopped before the second file was written
    stdout, _ = main(capsys, "run", pattern, *CHAIN, "--sink", out, "--shards", "2")
    assert "out of 1 file(s) (2 done before, skipped)" in stdout
    same_npz(tmp_path / "ref1.npz", made[1])
    assert made[0].stat().st_mtime_ns == before["day1-r0.npz"]
    assert made[2].stat().st_mtime_ns == before["day1-r2.npz"]


def test_pattern_errors_are_one_line(tmp_path, capsys):
    recording(tmp_path / "a.dat", duration_us=20_000)
    recording(tmp_path / "b.dat", duration_us=20_000)
    _, err = main(capsys, "run", str(tmp_path / "*.dat"), "--sink", str(tmp_path / "o.npz"), status=1)
    assert err.count("\n") == 1 and "each file needs its own output: put {stem}" in err
    _, err = main(capsys, "run", str(tmp_path / "*.nothing"), "--sink", str(tmp_path / "{stem}.npz"), status=1)
    assert "no file matches" in err
    _, err = main(capsys, "run", str(tmp_path / "*.dat"), "--sink", str(tmp_path / "{nope}.npz"), status=1)
    assert "--sink: bad placeholder 'nope' (known: {stem}, {name}, {parent})" in err
    _, err = main(capsys, "run", str(tmp_path / "a.dat"), "--op", "filter.refractory", "--shards", "2", status=1)
    assert err.count("\n") == 1 and "cannot be split in time" in err
