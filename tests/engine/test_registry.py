"""Plugins: hooks, entry points, duplicate names, the sample third-party plugin."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pluggy
import pytest

import tectum
from tectum import DuplicateNameError, Operator, RegistryError, hookimpl
from tectum._registry import build_registry, plugin_manager

SAMPLE = Path(__file__).resolve().parents[1] / "sample_plugin"


class A(Operator):
    name = "filter.same_test"


class B(Operator):
    name = "filter.same_test"


class PluginA:
    @hookimpl
    def tectum_register_operators(self, registry):
        registry.add_operator(A)


class PluginB:
    @hookimpl
    def tectum_register_operators(self, registry):
        registry.add_operator(B)


def test_builtins_come_through_entry_points():
    reg = tectum.get_registry()
    assert reg.operators["filter.refractory"].owner == "filter"
    assert reg.sources["npz"].owner == "core" and reg.sinks["npz"].owner == "core"


def test_duplicate_names_fail_naming_both_owners():
    pm = plugin_manager()
    pm.register(PluginA(), name="alpha")
    pm.register(PluginB(), name="beta")
    with pytest.raises(DuplicateNameError, match=r"operator 'filter.same_test' is registered twice: by plugin 'alpha' .*A\) and by plugin 'beta' .*B\)"):
        build_registry(pm)


@pytest.mark.parametrize("bad", ["refractory", "nofamily.x", "filter.Bad-Name"])
def test_operator_names_are_family_method(bad):
    class Bad(Operator):
        name = bad

    class P:
        @hookimpl
        def tectum_register_operators(self, registry):
            registry.add_operator(Bad)

    pm = pluggy.PluginManager("tectum")
    from tectum import hookspecs

    pm.add_hookspecs(hookspecs)
    pm.register(P(), name="p")
    with pytest.raises(RegistryError, match="is not 'family.method'"):
        build_registry(pm)


def test_sources_and_sinks_are_chosen_by_scheme_content_and_extension(tmp_path):
    reg = tectum.get_registry()
    assert reg.source_for("pattern:?speed=3").name == "pattern"
    f = tmp_path / "recording.bin"
    from tectum.sinks.npz import write_npz

    from helpers import bars

    write_npz(str(tmp_path / "x.npz"), bars(2000))
    os.replace(tmp_path / "x.npz", f)
    assert reg.source_for(str(f)).name == "npz"  # by content, whatever the name
    assert reg.sink_for(str(tmp_path / "new.npz")).name == "npz"
    with pytest.raises(RegistryError, match="no such file"):
        reg.source_for(str(tmp_path / "missing.xyz"))


@pytest.fixture(scope="module")
def sample_plugin_path(tmp_path_factory):
    """The sample plugin installed (with its entry point) into a folder of its own."""
    target = tmp_path_factory.mktemp("plugin-site")
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
         "--target", str(target), str(SAMPLE)],
        check=True, capture_output=True,
    )
    return target


def _env(extra: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(extra), env.get("PYTHONPATH", "")])
    return env


def test_sample_plugin_from_the_cli(sample_plugin_path, tmp_path):
    tectum_cmd = [sys.executable, "-m", "tectum"]
    out = subprocess.run([*tectum_cmd, "plugins", "--json"], env=_env(sample_plugin_path),
                         capture_output=True, text=True, check=True)
    ops = {o["name"]: o for o in json.loads(out.stdout)["operators"]}
    assert ops["filter.every_nth"]["plugin"] == "sample"
    dst = tmp_path / "half.npz"
    subprocess.run([*tectum_cmd, "run", "pattern:?duration_us=20000&sensor=32x24", "--op", "filter.every_nth:n=2",
                    "--sink", str(dst)], env=_env(sample_plugin_path), check=True, capture_output=True)
    src = tmp_path / "all.npz"
    subprocess.run([*tectum_cmd, "run", "pattern:?duration_us=20000&sensor=32x24", "--sink", str(src)],
                   check=True, capture_output=True)
    import numpy as np

    a, h = np.load(src), np.load(dst)
    assert np.array_equal(a["t"][::2], h["t"]) and np.array_equal(a["x"][::2], h["x"])


def test_sample_plugin_from_a_pipeline_file(sample_plugin_path, tmp_path):
    f = tmp_path / "p.toml"
    f.write_text(
        '[[source]]\nid = "cam"\nuri = "pattern:"\nparams = { duration_us = 10000, sensor = "32x24" }\n'
        '[[op]]\nid = "nth"\nname = "filter.every_nth"\ninput = "cam"\nparams = { n = 3 }\n'
        '[[sink]]\nuri = "out.npz"\ninput = "nth"\n'
    )
    r = subprocess.run([sys.executable, "-m", "tectum", "run", str(f), "--stats"], env=_env(sample_plugin_path),
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "nth" in r.stdout and (tmp_path / "out.npz").exists()


def test_folders_are_recognised_by_their_content(tmp_path):
    reg = tectum.get_registry()
    with pytest.raises(RegistryError, match="folder that no source recognises"):
        reg.source_for(str(tmp_path))
    (tmp_path / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    assert reg.source_for(str(tmp_path)).name == "rosbag"


def _another_engine_suite(out, quick):
    return {}


def test_duplicate_bench_suites_fail_naming_both_owners():
    class Again:
        @hookimpl
        def tectum_register_bench_suites(self, registry):
            registry.add_bench_suite("engine", _another_engine_suite, "a second engine suite")

    pm = plugin_manager()
    pm.register(Again(), name="again")
    with pytest.raises(DuplicateNameError, match=r"bench suite 'engine' is registered twice: by plugin 'evaluation' "
                                                 r"\(tectum\.evaluation\.suites\.engine\.run\) and by plugin 'again' "
                                                 r"\(.*_another_engine_suite\)"):
        build_registry(pm)


def test_sample_plugin_bench_suite_is_listed_and_runs(sample_plugin_path, tmp_path):
    import re

    env = _env(sample_plugin_path)
    listed = subprocess.run([sys.executable, "-m", "tectum", "bench", "--list"], env=env, capture_output=True,
                            text=True, check=True).stdout
    assert re.search(r"^sample\s+speed of filter\.every_nth \(the sample plugin\)\s+\(plugin sample\)$", listed, re.M)
    assert re.search(r"^engine\s+scheduler overhead .*\(plugin evaluation\)$", listed, re.M)
    r = subprocess.run([sys.executable, "-m", "tectum", "bench", "sample", "--quick", "--out", str(tmp_path)],
                       env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    data = json.loads((tmp_path / "bench-sample.json").read_text())
    assert data["suite"] == "sample" and data["results"]["throughput"]["events"] == 100_000
    (rec,) = data["results"]["targets"]
    assert rec["met"] == (rec["value"] >= rec["goal"] == 1.0)
    verdict = "met" if rec["met"] else "MISSED"
    assert re.search(rf"^every_nth, n = 2\s+\S+\s+Mev/s\s+>= 1\s+{verdict}\s*$", r.stdout, re.M)


class Wheel(tectum.SamplePacket):
    """A plugin's own kind: wheel odometry."""

    kind = tectum.Kind("wheel_test")
    fields = {"speed": tectum.Field("f8", (), "m/s"), "slip": tectum.Field("f8", (), "", optional=True)}


class OtherWheel(tectum.SamplePacket):
    kind = tectum.Kind("wheel_test")
    fields = {"rpm": tectum.Field("f8", ())}


def test_a_plugin_registers_a_kind_that_streams_like_the_built_ins():
    class Plugin:
        @hookimpl
        def tectum_register_kinds(self, registry):
            registry.add_kind(Wheel)

    pm = plugin_manager()
    pm.register(Plugin(), name="odometry")
    reg = build_registry(pm)
    assert reg.kinds["wheel_test"].owner == "odometry"
    assert tectum.packet_class("wheel_test") is Wheel and tectum.Kind("wheel_test") in list(tectum.Kind)
    a = Wheel([1, 2], speed=[1, 2], t_end=10)
    b = Wheel([10], speed=[3], slip=[0.5], t_start=10, t_end=20)
    both = tectum.concat([Wheel.empty(0, 1), a.with_interval(1, 10), b])
    assert both.speed.tolist() == [1, 2, 3] and np.isnan(both.slip[:2]).all()
    with pytest.raises(tectum.PacketError, match="speed"):
        Wheel([1], speed=["fast"])

    class Twin:
        @hookimpl
        def tectum_register_kinds(self, registry):
            registry.add_kind(OtherWheel)

    pm.register(Twin(), name="twin")
    with pytest.raises(DuplicateNameError, match="Wheel.*OtherWheel"):
        build_registry(pm)


def test_ports_and_parameters_may_not_share_a_name():
    class Clash(Operator):
        name = "map.clash_test"
        inputs = {"events": tectum.Port(tectum.Kind.EVENTS)}

        def __init__(self, events: int = 1) -> None:
            self.events = events

    with pytest.raises(RegistryError, match="ports and parameters both named \\['events'\\]"):
        tectum.Registry().add("operator", Clash, "me")
