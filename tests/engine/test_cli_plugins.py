"""``tectum plugins``: whole first sentences in plain text; ``tectum plugins
NAME``: the docstring as plain text, every parameter with its type, default
and unit, the stream kinds in and out. Checked for every registered
component, so a new one is covered."""

from __future__ import annotations

import json
import re

import pytest

import tectum
from tectum.cli import main
from tectum.cli._doc import first_sentence, parameters, plain_text

RST = re.compile(r"``|:(class|meth|mod|func|attr):`|`_")


def _all() -> list[str]:
    r = tectum.get_registry()
    return sorted({*r.operators, *r.sources, *r.sinks})


def _out(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    capsys.readouterr()
    assert main(["plugins", *argv]) == 0
    return capsys.readouterr().out


def test_one_operator_in_full(capsys: pytest.CaptureFixture[str]) -> None:
    out = _out(capsys, "filter.refractory")
    assert "Drop events that come less than period_us µs after the last kept event of the same pixel " \
           "(dropped events do not extend the period)." in " ".join(out.split())
    assert re.search(r"^  period_us\s+int = 1000 \[µs\]$", out, re.M), out
    assert "input: events" in out and "output: events" in out
    assert not RST.search(out)


@pytest.mark.parametrize("name", _all())
def test_every_component_in_full(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = _out(capsys, name)
    assert not RST.search(out), out
    reg = tectum.get_registry()
    for role, table in (("operator", reg.operators), ("source", reg.sources), ("sink", reg.sinks)):
        if name in table:
            for p in parameters(table[name].cls, skip_first=role != "operator"):
                assert re.search(rf"^  {p.name} +\S.* = ", out, re.M), (p.name, out)
    data = json.loads(_out(capsys, name, "--json"))
    assert all(p["type"] and p["default"] for d in data for p in d["parameters"])
    assert all(d.get("produces") or d.get("consumes") or d.get("inputs") for d in data)


def test_the_list_gives_whole_first_sentences(capsys: pytest.CaptureFixture[str]) -> None:
    data = json.loads(_out(capsys, "--json"))
    summaries = {e["name"]: e["summary"] for role in ("operators", "sources", "sinks") for e in data[role]}
    cut = {n: s for n, s in summaries.items() if not s.endswith((".", "!", "?")) or RST.search(s)}
    assert not cut
    listing = " ".join(_out(capsys).split())
    for s in summaries.values():
        assert s in listing


def test_unknown_name_suggests(capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["plugins", "filter.refractroy"]) == 1
    assert "did you mean filter.refractory" in capsys.readouterr().err


@pytest.mark.parametrize("doc, first", [
    ("Keep only ON events.\n\nMore.", "Keep only ON events."),
    ("Filter (Delbruck 2008): keep e.g. the first event. Then more.", "Filter (Delbruck 2008): keep e.g. the first "
                                                                     "event."),
    ("Drop events (see :class:`~tectum.Stats`. Really) here. Next.", "Drop events (see Stats. Really) here."),
    ("Warp ``t`` by *this*\n    much. And more.", "Warp t by this much."),
])
def test_first_sentence(doc: str, first: str) -> None:
    assert first_sentence(doc) == first


def test_plain_text_unmarks_rst() -> None:
    doc = """Title line.

    Parameters
    ----------
    see `the paper <https://x.org/p>`_ and :meth:`tectum.Source.packets`::

        code  stays
    """
    out = plain_text(doc)
    assert "----" not in out and "the paper (https://x.org/p)" in out and "tectum.Source.packets:" in out
    assert "    code  stays" in out
