"""``--stats`` as a user reads it: events apart from the samples of other
streams (by kind), what a sink did not write, a file source's skipped counts
(issue 20, items 10 and 15)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
from davis_recording import counts, write_davis

import tectum

TECTUM = [sys.executable, "-m", "tectum"]


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([*TECTUM, *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r


def _row(report: str, node: str) -> list[str]:
    line = next(line for line in report.splitlines() if line.startswith(node + " "))
    return line.split()


def test_events_and_samples_are_counted_apart(tmp_path: Path) -> None:
    n = counts(write_davis(tmp_path / "davis.npz"))
    r = cli("run", str(tmp_path / "davis.npz"), "--op", "filter.refractory:period_us=1", "--sink",
            str(tmp_path / "out.raw"), "--stats", "--stats-json", str(tmp_path / "s.json"))
    source = _row(r.stdout, "source")
    assert int(source[3]) == n["events"]  # ev out: events only, not events + frames + IMU + triggers
    assert "samples out: 10 frames, 200 imu samples, 16 triggers" in r.stdout
    assert "not written: 10 frames, 200 imu samples, 16 triggers" in r.stdout  # EVT 2.0 holds events only
    op = _row(r.stdout, "1:filter.refractory")
    assert int(op[2]) == n["events"]  # the samples passed the filter by
    stats = json.loads((tmp_path / "s.json").read_text())["nodes"]
    assert stats["source"]["events_out"] == n["events"]
    assert stats["source"]["samples_out"] == {"frames": 10, "imu": 200, "triggers": 16}
    assert stats["sink"]["samples_in"] == {} and stats["sink"]["events_in"] == stats["1:filter.refractory"]["events_out"]
    assert stats["sink"]["not_written"] == {"frames": 10, "imu": 200, "triggers": 16}


def test_a_sink_that_takes_every_stream_counts_its_samples_in(tmp_path: Path) -> None:
    write_davis(tmp_path / "davis.npz")
    r = cli("run", str(tmp_path / "davis.npz"), "--sink", str(tmp_path / "copy.npz"), "--stats")
    sink = r.stdout.split("\nsink ")[1]
    assert "samples in: 10 frames, 200 imu samples, 16 triggers" in sink and "not written" not in sink


def test_file_source_skipped_counts_show(tmp_path: Path) -> None:
    a = np.zeros(100, dtype=[("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
    a["t"], a["x"], a["y"], a["p"] = np.arange(100) * 10, 3, 4, 1
    a["t"][50] = 5  # one timestamp back in time
    np.save(tmp_path / "bad.npy", a)
    r = cli("run", f"{tmp_path / 'bad.npy'}?skip_bad=true&sensor=32x24", "--stats")
    m = re.search(r"source.*\n(?:  .*\n)*?  skipped_events = (\d+)\n  skipped_ranges = (\d+)", r.stdout)
    assert m is not None, r.stdout
    assert int(m.group(1)) >= 1 and int(m.group(2)) >= 1
    assert int(_row(r.stdout, "source")[3]) == 100 - int(m.group(1))


def test_stats_report_in_python() -> None:
    stats = tectum.Stats()
    st = stats.node("cam")
    st.gave(tectum.ImuPacket([1, 2], accel=np.zeros((2, 3)), gyro=np.zeros((2, 3))))
    st.gave(tectum.EventPacket.from_arrays([1], [0], [0], [1], sensor=(2, 2)))
    assert (st.events_out, st.samples_out) == (1, {"imu": 2})
    assert "  samples out: 2 imu samples" in stats.report()
