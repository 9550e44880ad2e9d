"""Docstrings and signatures as a person reads them in a terminal: reST
markup turned into plain text, first sentences, parameter types, defaults
and the units their names carry (``period_us`` is in µs)."""

from __future__ import annotations

import inspect
import re
import textwrap
import typing
from typing import Any

__all__ = ["plain_text", "first_sentence", "parameters", "parameter_docs", "type_name", "unit_of", "Param"]

_ROLE = re.compile(r":[\w:.-]+:`~?([^`<]*?)(?:\s*<[^>]*>)?`")  # :class:`~a.B` -> a.B (tilde: last part)
_LINK = re.compile(r"`([^`<]+?)\s*<([^>]+)>`_+")
_LITERAL = re.compile(r"``(.+?)``", re.S)
_EMPHASIS = re.compile(r"(?<![\w*])\*{1,2}([^*\s](?:[^*]*[^*\s])?)\*{1,2}(?![\w*])")
_UNDERLINE = re.compile(r"^\s*([-=~^\"'`#*+])\1{2,}\s*$")
_ABBREVIATIONS = ("e.g.", "i.e.", "cf.", "vs.", "al.", "approx.", "etc.", "Fig.", "No.")
#: Units read from the end of a parameter's name.
_UNITS = (("_px_s", "px/s"), ("_rad_s", "rad/s"), ("_us", "µs"), ("_ms", "ms"), ("_ns", "ns"), ("_hz", "Hz"),
          ("_px", "px"), ("_deg", "degrees"), ("_rad", "rad"), ("_m", "m"), ("_s", "s"), ("_bytes", "bytes"))


def _inline(text: str) -> str:
    def role(m: re.Match[str]) -> str:
        target = m.group(1).strip()
        return target.rsplit(".", 1)[-1] if m.group(0).split("`", 1)[1].startswith("~") else target

    text = _LINK.sub(r"\1 (\2)", text)
    text = _ROLE.sub(role, text)
    text = _LITERAL.sub(r"\1", text)
    return _EMPHASIS.sub(r"\1", text)


def plain_text(doc: str | None, width: int = 88) -> str:
    """A docstring as plain text: reST roles, literals, emphasis and links
    unmarked, section underlines dropped, ``::`` as ``:``, prose paragraphs
    re-wrapped to ``width``; lists, tables and literal blocks keep their
    lines."""
    paragraphs = re.split(r"\n\s*\n", inspect.cleandoc(doc or ""))
    out = []
    for para in paragraphs:
        lines = [ln for ln in para.splitlines() if not _UNDERLINE.match(ln)]
        if not lines:
            continue
        lines = [re.sub(r"^\.\. (\w+)::\s*", lambda m: m.group(1).capitalize() + ": ", ln) for ln in lines]
        lines = _inline("\n".join(lines)).splitlines()  # a literal may run over a line end
        if lines[-1].rstrip().endswith("::"):
            lines[-1] = lines[-1].rstrip()[:-1]
        structured = any(ln[:1].isspace() or re.match(r"\s*([-*•]|\d+\.)\s", ln) or "|" in ln for ln in lines[1:]) \
            or re.match(r"\s*([-*•]|\d+\.)\s", lines[0])
        if structured or len(lines) == 1 and len(lines[0]) <= width:
            out.append("\n".join(ln.rstrip() for ln in lines))
        else:
            out.append(textwrap.fill(" ".join(ln.strip() for ln in lines), width))
    return "\n\n".join(out)


def parameter_docs(doc: str | None) -> tuple[str, dict[str, str]]:
    """Split a numpy-style ``Parameters`` section (the heading underlined,
    ``name:`` entries with indented text) out of a docstring. Returns the
    rest of the docstring and a plain-text description per parameter (none
    where the docstring describes its parameters in prose: that stays)."""
    text = inspect.cleandoc(doc or "")
    section = re.search(r"^Parameters[^\n]*\n(?:[^\n]*\n)?[-=]{3,}\n(.*?)(?=\n\s*\n(?!\s)|\n\S[^\n]*\n[-=]{3,}|\Z)",
                        text, re.S | re.M)
    if not section:
        return text, {}
    found = {m.group(1): " ".join(_inline(ln.strip()) for ln in m.group(2).splitlines())
             for m in re.finditer(r"^(\w+)\s*:[^\n]*\n((?:[ \t]+\S[^\n]*(?:\n|$))*)", section.group(1), re.M)}
    return ((text[:section.start()] + text[section.end():]).strip(), found) if found else (text, {})


def first_sentence(doc: str | None) -> str:
    """The first sentence of a docstring, in plain text, whole (never cut
    mid-sentence; abbreviations such as "e.g." do not end it)."""
    para = re.split(r"\n\s*\n", inspect.cleandoc(doc or ""), maxsplit=1)[0]
    text = " ".join(_inline(ln.strip()) for ln in para.splitlines())
    for m in re.finditer(r"[.!?](?=\s|$)", text):
        head = text[:m.end()]
        if not head.endswith(_ABBREVIATIONS) and head.count("(") <= head.count(")"):
            return head
    return text


def type_name(tp: Any) -> str:
    """A type annotation as a reader writes it: ``int | None``, ``one of a, b``."""
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        return "one of " + ", ".join(str(a) for a in typing.get_args(tp))
    if origin is typing.Union or type(tp).__name__ == "UnionType":
        return " | ".join(type_name(a) for a in typing.get_args(tp))
    if tp is type(None):
        return "None"
    if isinstance(tp, type) and origin is None:
        return tp.__name__
    return re.sub(r"\b(typing|collections\.abc|numpy)\.", "", str(tp))


def unit_of(name: str) -> str:
    """The unit a parameter's name carries (``dt_us`` -> ``µs``), or ""."""
    return next((u for suffix, u in _UNITS if name.endswith(suffix)), "")


class Param(typing.NamedTuple):
    name: str
    type: str
    default: str
    unit: str


def parameters(cls: type, skip_first: bool) -> list[Param]:
    """The keyword parameters of ``cls(...)``, as pipelines accept them
    (those passed on to a base class through ``**kw`` included: a file
    source's ``sensor``). ``skip_first`` leaves out a source's or sink's
    path/URL argument."""
    from tectum._operator import component_params

    hints: dict[str, Any] = {}
    for owner in reversed(cls.__mro__):  # the most derived annotation wins
        if "__init__" in vars(owner) and owner is not object:
            try:
                hints.update(typing.get_type_hints(owner.__init__))  # type: ignore[misc]
            except Exception:  # an annotation that does not resolve here: shown as written
                pass
    out = []
    for p in list(component_params(cls).values())[int(skip_first):]:
        tp = type_name(hints[p.name]) if p.name in hints else ("" if p.annotation is p.empty else str(p.annotation))
        out.append(Param(p.name, tp, "required" if p.default is p.empty else repr(p.default), unit_of(p.name)))
    return out
