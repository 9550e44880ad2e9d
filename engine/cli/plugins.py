"""``tectum plugins [NAME]``: what is registered, and by which plugin; with a
NAME, everything about one component (its docstring, parameters with types,
units and defaults, the kinds of stream it takes and gives)."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import textwrap
from typing import Any

from tectum import get_registry

from ._doc import first_sentence, parameter_docs, parameters, plain_text

HELP = "list the registered operators, macros, sources and sinks with their owners; NAME: one component in full"

_ROLES = {"operators": "operator", "macros": "macro", "sources": "source", "sinks": "sink"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="?", help="an operator, source or sink (e.g. filter.refractory, npz): its "
                   "description, parameters and stream kinds")
    p.add_argument("--json", action="store_true", help="machine-readable output")


def _kinds(kinds: Any) -> list[str]:
    return [str(k) for k in kinds]


def describe(role: str, e: Any) -> dict[str, Any]:
    """One registry entry as plain data (what ``--json`` prints): summary,
    description (plain text), parameters, URL schemes / extensions, stream
    kinds in and out."""
    cls = e.cls
    rest, pdocs = parameter_docs(cls.__doc__)
    d: dict[str, Any] = {"name": e.name, "role": role, "plugin": e.owner,
                         "class": f"{cls.__module__}.{cls.__qualname__}",
                         "summary": first_sentence(cls.__doc__), "description": plain_text(rest)}
    d["parameters"] = [{**p._asdict(), "doc": pdocs.get(p.name, "")}
                       for p in parameters(cls, skip_first=role not in ("operator", "macro"))]
    if role == "macro":  # its ports; what it expands into: `tectum run --explain`
        d["inputs"] = {k: {"kind": str(p.kind), "required": p.required, "doc": p.doc} for k, p in cls.inputs.items()}
    elif role == "operator":
        d["consumes"], d["produces"] = _kinds(cls.consumes), _kinds(cls.produces)
        ports = getattr(cls, "inputs", None)
        if ports:
            d["inputs"] = {k: {"kind": str(getattr(p, "kind", p)), "required": getattr(p, "required", True),
                               "doc": getattr(p, "doc", "")} for k, p in ports.items()}
    else:
        d["schemes"], d["extensions"] = list(cls.schemes), list(cls.extensions)
        if role == "source":
            d["produces"] = _kinds(cls.produces)
        else:
            d["consumes"] = _kinds(cls.consumes)
    if "module" in rest:  # "see the module docstring": it is part of the description
        d["module"] = plain_text(sys.modules[cls.__module__].__doc__)
    return d


def _show(d: dict[str, Any], width: int) -> str:
    lines = [f"{d['name']} ({d['role']}, plugin {d['plugin']!r}, {d['class']})", "", d["description"], ""]
    if d.get("module"):
        lines += [f"From the module {d['class'].rsplit('.', 1)[0]}:", "", d["module"], ""]
    ps = d["parameters"]
    lines.append("parameters:" if ps else "parameters: none")
    w = max((len(p["name"]) for p in ps), default=0)
    for p in ps:
        unit = f" [{p['unit']}]" if p["unit"] else ""
        lines.append(f"  {p['name']:<{w}}  {p['type']} = {p['default']}{unit}")
        if p["doc"]:
            lines.append(textwrap.fill(p["doc"], width, initial_indent=" " * (w + 4),
                                       subsequent_indent=" " * (w + 4)))
    for key, label in (("schemes", "URL schemes"), ("extensions", "extensions")):
        if d.get(key):
            lines.append(f"{label}: {', '.join(d[key])}")
    if d.get("inputs"):
        lines.append("input ports:")
        for k, p in d["inputs"].items():
            extra = ("" if p["required"] else " (optional)") + (f": {p['doc']}" if p["doc"] else "")
            lines.append(f"  {k}: {p['kind']}{extra}")
    elif "consumes" in d:
        passing = " (packets of other kinds pass by)" if d["role"] == "operator" else ""
        lines.append(f"input: {', '.join(d['consumes'])}{passing}")
    if "produces" in d:
        lines.append(f"output: {', '.join(d['produces']) or 'nothing'}")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    from tectum.errors import RegistryError

    reg = get_registry()
    tables = {"operators": reg.operators, "macros": reg.macros, "sources": reg.sources, "sinks": reg.sinks}
    width = min(100, shutil.get_terminal_size((100, 24)).columns)
    if args.name:
        found = [(_ROLES[r], t[args.name]) for r, t in tables.items() if args.name in t]
        if not found:
            import difflib

            close = difflib.get_close_matches(args.name, [n for t in tables.values() for n in t], n=3)
            raise RegistryError(f"nothing is registered as {args.name!r}"
                                + (f"; did you mean {', '.join(close)}?" if close else ""))
        if args.json:
            print(json.dumps([describe(role, e) for role, e in found], indent=1))
        else:
            print("\n\n".join(_show(describe(role, e), width) for role, e in found))
        return 0
    if args.json:
        out: dict[str, Any] = {role: [describe(_ROLES[role], e) for e in sorted(t.values(), key=lambda e: e.name)]
                               for role, t in tables.items()}
        out["plugins"] = reg.plugins
        print(json.dumps(out, indent=1))
        return 0
    for role, t in tables.items():
        print(f"{role}:")
        w = max((len(n) for n in t), default=0)
        for e in sorted(t.values(), key=lambda e: e.name):
            print(textwrap.fill(f"{e.name:<{w}}  [{e.owner}] {first_sentence(e.cls.__doc__)}", width,
                                initial_indent="  ", subsequent_indent=" " * (w + 4)))
    print("\n`tectum plugins NAME` shows one in full: its parameters, units, defaults and stream kinds.")
    return 0
