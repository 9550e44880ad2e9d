"""Pipeline macros: expansion at validation (node ids ``<id>.<part>``, the
macro's id handing on its outputs), the same result as the nodes written
by hand, from Python, a pipeline file and the CLI (``--explain``,
``tectum plugins``), and precise errors."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

import tectum
from tectum import Expansion, Kind, Macro, PipelineError, Port
from tectum.cli import main as cli
from tectum.testing import ListSink, ListSource, assert_streams_equal


class Clean(Macro):
    """Test macro: two refractory filters in a chain and a count image of
    what leaves them; both the events and the images leave the macro."""

    name = "filter.clean_twice"
    inputs = {"events": Port(Kind.EVENTS)}

    def __init__(self, period_us: int = 1000, window_us: int = 5000) -> None:
        self.period_us, self.window_us = period_us, window_us

    def expand(self, x: Expansion) -> None:
        x.op("a", "filter.refractory", x.port("events"), period_us=self.period_us)
        x.op("b", "filter.refractory", x.part("a"), period_us=2 * self.period_us)
        x.op("img", "repr.count", x.part("b"), window_us=self.window_us)
        x.output("b", "img")


@pytest.fixture
def reg() -> tectum.Registry:
    r = copy.copy(tectum.get_registry())
    r.macros = dict(r.macros)
    r.add("macro", Clean, "test")
    return r


def _events() -> tectum.EventPacket:
    rng = np.random.default_rng(3)
    n = 3000
    t = np.sort(rng.integers(0, 30_000, n))
    return tectum.EventPacket.from_arrays(t, rng.integers(0, 8, n), rng.integers(0, 8, n), np.ones(n),
                                          sensor=(8, 8), t_start=0, t_end=30_000)


def test_a_macro_expands_into_its_parts_and_equals_them_written_by_hand(reg: tectum.Registry) -> None:
    ev = _events()
    p = tectum.Pipeline()
    cam = p.source(ListSource([ev]), id="cam")
    p.op("filter.clean_twice", cam, id="c", period_us=300)
    got = ListSink()
    p.sink(got, "c")
    plan = p.validate(reg)
    assert [n for n in plan.order] == ["cam", "c.a", "c.b", "c.img", "c", "sink"]
    assert plan.nodes["c.b"].params == {"period_us": 600} and plan.nodes["c"].inputs == ("c.b", "c.img")
    tectum.run(p, registry=reg)

    q = tectum.Pipeline()
    cam = q.source(ListSource([ev]), id="cam")
    a = q.op("filter.refractory", cam, period_us=300)
    b = q.op("filter.refractory", a, period_us=600)
    img = q.op("repr.count", b, window_us=5000)
    want_ev, want_img = ListSink(), ListSink()
    q.sink(want_ev, b)
    q.sink(want_img, img)
    tectum.run(q)
    assert {pk.kind for pk in got.packets if len(pk)} == {Kind.EVENTS, Kind.FRAMES}
    assert_streams_equal(want_ev.packets + want_img.packets, got.packets, "macro vs by hand")


def test_explain_shows_the_expansion(reg: tectum.Registry) -> None:
    p = tectum.Pipeline()
    p.source("pattern:", id="cam", duration_us=1000)
    p.op("filter.clean_twice", "cam", id="c", window_us=2000)
    p.sink("out.npz", "c")
    text = p.explain(reg)
    assert "  c.a    filter.refractory           period_us=1000\n" in text, text
    assert "  c.img  repr.count                  window_us=2000\n" in text, text
    assert "  c      filter.clean_twice (macro)  window_us=2000\n" in text, text
    assert "  c.a -> c.b\n" in text and "  c.b -> c\n" in text and "  c.img -> c\n" in text


def test_a_pipeline_file_names_a_macro(reg: tectum.Registry, tmp_path: Any) -> None:
    f = tmp_path / "p.toml"
    f.write_text('[[source]]\nid = "cam"\nuri = "pattern:"\n[[op]]\nid = "c"\nname = "filter.clean_twice"\n'
                 'input = "cam"\nparams = { period_us = 50 }\n[[sink]]\nuri = "out.npz"\ninput = "c"\n')
    plan = tectum.Pipeline.from_toml(f).validate(reg)
    assert plan.nodes["c.a"].params == {"period_us": 50}


@pytest.mark.parametrize("kw, msg", [
    ({"period": 5}, r"node 'c' \(filter.clean_twice\): unknown parameter 'period'; parameters: period_us, "
                    r"window_us"),
    ({"period_us": "soon"}, r"node 'c' \(filter.clean_twice\): parameter 'period_us'"),
    ({"ports": {"imu": "cam"}}, r"node 'c' \(filter.clean_twice\) has no port\(s\) \['imu'\]; ports: \['events'\]"),
])
def test_bad_macro_use_names_the_node(reg: tectum.Registry, kw: dict[str, Any], msg: str) -> None:
    p = tectum.Pipeline()
    p.source("pattern:", id="cam")
    p.op("filter.clean_twice", kw.pop("ports", "cam"), id="c", **kw)
    with pytest.raises(PipelineError, match=msg):
        p.validate(reg)


def test_a_macro_may_not_shadow_an_operator() -> None:
    class Shadow(Clean):
        name = "filter.refractory"

    r = copy.copy(tectum.get_registry())
    r.macros = dict(r.macros)
    with pytest.raises(tectum.DuplicateNameError, match="registered as an operator and as a macro"):
        r.add("macro", Shadow, "test")


def test_cli_explain_prints_tracker_evo_and_runs_nothing(tmp_path: Any, capsys: Any) -> None:
    out = tmp_path / "traj.tum"
    rc = cli(["run", "pattern:?duration_us=1000", "--op", "tracker.evo:calib=40;40;20;15,delay_us=3000",
              "--sink", str(out), "--sink", str(tmp_path / "maps.npz"), "--explain"])
    text = capsys.readouterr().out
    assert rc == 0 and not out.exists()
    assert "1:tracker.evo.tracker  tracker.edge_align" in text and "1:tracker.evo.mapper   map.emvs" in text
    assert "1:tracker.evo.mapper -> 1:tracker.evo.tracker (maps)  delayed 3000 µs  (closes a loop)" in text
    assert "1:tracker.evo.tracker -> 1:tracker.evo.mapper (poses)" in text
    assert "loops:\n  1:tracker.evo.tracker -> 1:tracker.evo.mapper" in text


def test_plugins_lists_macros(capsys: Any) -> None:
    assert cli(["plugins"]) == 0
    listing = capsys.readouterr().out
    assert "macros:\n  tracker.evo  [tracker] EVO:" in listing
    assert cli(["plugins", "tracker.evo"]) == 0
    one = capsys.readouterr().out
    assert "tracker.evo (macro, plugin 'tracker'" in one and "delay_us" in one and "events: events" in one
