"""Pipelines are data, validated before anything runs."""

from __future__ import annotations

import pytest

from tectum import Kind, Operator, Pipeline, PipelineError
from tectum.testing import ListSink, ListSource


class FramesOnly(Operator):
    name = "repr.frames_only_test"
    consumes = (Kind.FRAMES,)
    produces = (Kind.FRAMES,)

    def process(self, packet):
        return [packet]


def test_valid_chain_resolves_names_and_types():
    p = Pipeline()
    s = p.source("pattern:", duration_us=1000)
    o = p.op("filter.refractory", s, period_us="250")
    p.sink("out.npz", o)
    plan = p.validate()
    assert plan.order == ("pattern", "refractory", "out")
    assert plan.nodes["refractory"].params["period_us"] == 250  # converted from text
    assert plan.nodes["pattern"].params["duration_us"] == 1000


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda p: p.op("filter.nope", p.source("pattern:")), r"unknown operator 'filter.nope'"),
        (lambda p: p.op("filter.refractory", p.source("pattern:"), period=3), r"unknown parameter 'period'; parameters: period_us"),
        (lambda p: p.op("filter.refractory", p.source("pattern:"), period_us="soon"), r"parameter 'period_us'"),
        (lambda p: p.op("filter.refractory", "ghost"), r"no source"),
        (lambda p: (p.source("pattern:"), p.op("filter.refractory", "ghost")), r"unknown node 'ghost'"),
        (lambda p: p.source("nosuch://x"), r"no source handles the scheme 'nosuch'"),
        (lambda p: p.sink("out.unknownext", p.source("pattern:")), r"no sink recognises 'out.unknownext'"),
        (lambda p: p.op(FramesOnly(), p.source("pattern:")), r"consumes \{frames\} but its input\(s\) 'pattern' provide only \{events\}"),
    ],
)
def test_validation_errors_are_clear(build, message):
    p = Pipeline()
    build(p)
    with pytest.raises(PipelineError, match=message):
        p.validate()


def test_cycles_are_found():
    p = Pipeline()
    p.source("pattern:", id="s")
    p.op("filter.refractory", ["s", "b"], id="a")
    p.op("filter.refractory", "a", id="b")
    with pytest.raises(PipelineError, match="cycle: a -> b -> a|cycle: b -> a -> b"):
        p.validate()


def test_duplicate_ids_and_sink_inputs():
    p = Pipeline()
    p.source("pattern:", id="s")
    with pytest.raises(PipelineError, match="used twice"):
        p.source("pattern:", id="s")
    p.sink(ListSink(), "s", id="k")
    p.op("filter.refractory", "k", id="bad")
    with pytest.raises(PipelineError, match="reads from sink 'k'"):
        p.validate()


def test_toml_pipeline(tmp_path):
    f = tmp_path / "p.toml"
    f.write_text(
        '[pipeline]\nmax_events = 128\n'
        '[[source]]\nid = "cam"\nuri = "pattern:"\nparams = { duration_us = 20000, sensor = "32x24" }\n'
        '[[op]]\nid = "rf"\nname = "filter.refractory"\ninput = "cam"\nparams = { period_us = 500 }\n'
        '[[sink]]\nuri = "out.npz"\ninput = "rf"\n'
    )
    p = Pipeline.from_toml(f)
    plan = p.validate()
    assert p.batch.max_events == 128
    assert plan.nodes["out"].spec.name == str(tmp_path / "out.npz")
    f.write_text('[[source]]\nuri = "pattern:"\nfoo = 1\n')
    with pytest.raises(PipelineError, match=r"unknown key\(s\) \['foo'\]"):
        Pipeline.from_toml(f)
    f.write_text("[[source]\n")
    with pytest.raises(PipelineError, match="p.toml"):
        Pipeline.from_toml(f)


def test_instances_through_the_api():
    p = Pipeline()
    s = p.source(ListSource([]), id="src")
    p.sink(ListSink(), s)
    assert p.validate().nodes["src"].provides == frozenset({Kind.EVENTS})
