"""The command line, run as a user would (a subprocess)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

import tectum

TECTUM = [sys.executable, "-m", "tectum"]


def cli(*args, check=True):
    r = subprocess.run([*TECTUM, *args], capture_output=True, text=True)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def test_run_chain_writes_npz_with_all_columns(tmp_path):
    out = tmp_path / "o.npz"
    r = cli("run", "pattern:?duration_us=30000&sensor=32x24&noise_hz=3", "--op", "filter.refractory:period_us=400",
            "--sink", str(out), "--stats", "--stats-json", str(tmp_path / "s.json"))
    assert "1:filter.refractory" in r.stdout and "latency to sink" in r.stdout
    d = np.load(out)
    assert {"t", "x", "y", "p", "noise", "vx", "vy"} <= set(d.files)
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["nodes"]["1:filter.refractory"]["events_out"] == len(d["t"])
    # the output file is a source too: the chain can continue from it
    r = cli("run", str(out), "--op", "filter.refractory:period_us=400", "--sink", str(tmp_path / "o2.npz"))
    assert np.array_equal(np.load(tmp_path / "o2.npz")["t"], d["t"])  # idempotent filter


def test_errors_are_one_clear_line(tmp_path):
    r = cli("run", "pattern:", "--op", "filter.nope", check=False)
    assert r.returncode == 1
    assert "tectum run: error: node '1:filter.nope': unknown operator 'filter.nope'" in r.stderr
    assert "Traceback" not in r.stderr
    r = cli("run", str(tmp_path / "missing.npz"), check=False)
    assert r.returncode == 1 and "no such file" in r.stderr


def test_plugins_json():
    data = json.loads(cli("plugins", "--json").stdout)
    names = {o["name"] for o in data["operators"]}
    assert "filter.refractory" in names
    assert {"pattern", "npz"} <= {s["name"] for s in data["sources"]}


def test_demo_writes_picture_and_report(tmp_path):
    r = cli("demo", "--out", str(tmp_path), "--duration-us", "50000")
    assert (tmp_path / "before_after.png").stat().st_size > 1000
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["events_in"] > report["events_out"] > 0
    assert "signal kept" in r.stdout


def test_help_lists_verbs():
    out = cli("--help").stdout
    for verb in ("demo", "run", "plugins", "bench"):
        assert verb in out


def test_info_of_a_file_without_events_says_so_instead_of_a_rate(tmp_path):
    out = tmp_path / "maps.npz"
    p = tectum.Pipeline()
    cam = p.source("simulate:rotation", duration_us=30_000, sensor="32x24")
    p.sink(str(out), p.op("map.high_pass", cam))
    tectum.run(p)
    r = subprocess.run([sys.executable, "-m", "tectum", "info", str(out)], capture_output=True, text=True, check=True)
    lines = {k.strip(): v.strip() for k, v in (line.split(":", 1) for line in r.stdout.splitlines())}
    assert lines["rate"] == "no events"
    assert lines["streams"] == "maps 3"
