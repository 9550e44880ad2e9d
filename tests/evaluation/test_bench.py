"""``tectum bench``: suites come from the registry (built-ins lazily), targets
are reported met or MISSED, on screen and in the JSON."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

import tectum._registry
from tectum import hookimpl
from tectum._registry import build_registry, plugin_manager
from tectum.cli import main
from tectum.evaluation.harness import target, targets_table


def test_target_is_met_on_the_right_side_of_the_goal():
    assert target("rate", 2.0e5, 2.0e5, "events/s")["met"]
    assert not target("rate", 1.9e5, 2.0e5, "events/s")["met"]
    assert target("latency", 999.0, 1000.0, "µs", higher_is_better=False)["met"]
    assert not target("latency", 1001.0, 1000.0, "µs", higher_is_better=False)["met"]
    assert not target("rate", math.nan, 1.0, "Mev/s")["met"]
    assert not target("latency", math.nan, 1.0, "µs", higher_is_better=False)["met"]


def test_targets_table_says_met_or_missed_beside_each_goal():
    lines = targets_table([target("ebe", 250_000.0, 200_000, "events/s"),
                           target("p99", 1500.0, 1000, "µs", higher_is_better=False)]).splitlines()
    assert lines[0].split() == ["measure", "value", "unit", "target", "met"]
    assert lines[1].split() == ["ebe", "250000", "events/s", ">=", "200000", "met"]
    assert lines[2].split() == ["p99", "1500", "µs", "<=", "1000", "MISSED"]


def test_builtin_suites_are_registered_without_importing_them():
    code = ("import sys, tectum; s = tectum.get_registry().bench_suites; print(sorted(s));"
            "print(sorted(m for m in sys.modules if m.startswith('tectum.evaluation.suites.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines() == [str(sorted(["engine", "io", "filters", "flow", "map", "tracker", "simulate", "net", "calibrate", "scale",
                                              "pose"])), "[]"]


class Tiny:
    """A plugin with two suites: one states two targets, one is broken."""

    @hookimpl
    def tectum_register_bench_suites(self, registry):
        registry.add_bench_suite("tiny", self.tiny, "two targets, one missed")
        registry.add_bench_suite("broken", lambda out, quick: [1, 2], "returns a list")

    @staticmethod
    def tiny(out, quick):
        (out / "tiny.txt").write_text(f"quick={quick}")
        return {"answer": 42, "targets": [target("fast", 3.0, 2.0, "Mev/s"), target("small", 9.0, 5.0, "µs", False)]}


@pytest.fixture
def tiny_registry(monkeypatch):
    pm = plugin_manager()
    pm.register(Tiny(), name="tiny_plugin")
    monkeypatch.setattr(tectum._registry, "_default", build_registry(pm))


def test_bench_runs_a_registered_suite_and_reports_its_targets(tiny_registry, tmp_path, capsys):
    assert main(["bench", "--list"]) == 0
    listed = capsys.readouterr().out
    assert "tiny " in listed and "two targets, one missed  (plugin tiny_plugin)" in listed and "engine " in listed
    assert main(["bench", "tiny", "--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "tiny.txt").read_text() == "quick=True"
    assert "targets: 1 of 2 met; MISSED: small" in out
    data = json.loads((tmp_path / "bench-tiny.json").read_text())
    assert data["results"]["answer"] == 42
    assert [(t["name"], t["met"]) for t in data["results"]["targets"]] == [("fast", True), ("small", False)]


def test_bench_refuses_unknown_suites_and_bad_results(tiny_registry, tmp_path, capsys):
    assert main(["bench", "tiny", "nope", "--out", str(tmp_path)]) == 2
    assert "unknown suite(s) nope; registered: " in capsys.readouterr().err
    assert not (tmp_path / "bench-tiny.json").exists()  # nothing runs when one name is wrong
    assert main(["bench", "broken", "--out", str(tmp_path)]) == 1
    assert "bench suite 'broken' (plugin 'tiny_plugin') returned list, not a dict" in capsys.readouterr().err
