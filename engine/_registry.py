"""The component registry, filled by plugins through pluggy hooks."""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import pluggy

from . import hookspecs
from ._macro import Macro
from ._operator import Operator, Sink, Source, component_params
from ._packet import Packet, register_kind
from .errors import DuplicateNameError, FormatError, RegistryError

__all__ = ["Registry", "RegistryView", "BenchSuite", "get_registry", "FAMILIES"]

FAMILIES = ("filter", "flow", "lifetime", "map", "tracker", "repr")
_OP_NAME = re.compile(r"^([a-z]+)\.([a-z][a-z0-9_]*)$")
_COMP_NAME = re.compile(r"^[a-z][a-z0-9_.]*$")
Role = Literal["operator", "source", "sink", "kind", "macro"]


@dataclass
class Entry:
    """A registered component and the plugin that owns it."""

    role: Role
    name: str
    cls: Any  # an Operator, Source, Sink, Macro or Packet subclass
    owner: str


@dataclass
class BenchSuite:
    """A suite of ``tectum bench`` and the plugin that owns it (see the
    ``tectum_register_bench_suites`` hook): ``run(out, quick)`` returns the
    suite's numbers, ``description`` is one line for ``--list``."""

    name: str
    run: Callable[[Path, bool], dict[str, Any]]
    description: str
    owner: str


@dataclass
class Registry:
    """Operators, sources, sinks, macros and bench suites by name, each with its owning plugin."""

    operators: dict[str, Entry] = field(default_factory=dict)
    macros: dict[str, Entry] = field(default_factory=dict)  # pipeline macros (used as operators are)
    sources: dict[str, Entry] = field(default_factory=dict)
    sinks: dict[str, Entry] = field(default_factory=dict)
    bench_suites: dict[str, BenchSuite] = field(default_factory=dict)
    kinds: dict[str, Entry] = field(default_factory=dict)  # sample kinds added by plugins
    plugins: dict[str, str] = field(default_factory=dict)  # plugin name -> distribution/module

    def _table(self, role: Role) -> dict[str, Entry]:
        return {"operator": self.operators, "source": self.sources, "sink": self.sinks, "macro": self.macros}[role]

    def add(self, role: Role, cls: type, owner: str) -> None:
        base = {"operator": Operator, "source": Source, "sink": Sink, "macro": Macro}[role]
        if not (isinstance(cls, type) and issubclass(cls, base)):
            raise RegistryError(f"plugin {owner!r} registered {cls!r} as a {role}, "
                                f"but it is not a {base.__name__} subclass")
        name: str = getattr(cls, "name", "")
        if role in ("operator", "macro"):
            m = _OP_NAME.match(name or "")
            if not m or m.group(1) not in FAMILIES:
                raise RegistryError(
                    f"plugin {owner!r}: {role} name {name!r} is not 'family.method' with family in {FAMILIES}"
                )
            other = (self.macros if role == "operator" else self.operators).get(name)
            if other is not None:
                raise DuplicateNameError(f"{name!r} is registered as an operator and as a macro: by plugin "
                                         f"{other.owner!r} and by plugin {owner!r}")
            ports = getattr(cls, "inputs", None) or {}
            clash = sorted(set(ports) & set(component_params(cls)))
            if clash:
                raise RegistryError(f"plugin {owner!r}: operator {name!r} has ports and parameters both named {clash}")
        elif not _COMP_NAME.match(name or ""):
            raise RegistryError(f"plugin {owner!r}: {role} name {name!r} is not a lower-case identifier")
        table = self._table(role)
        if name in table:
            prev = table[name]
            raise DuplicateNameError(
                f"{role} {name!r} is registered twice: by plugin {prev.owner!r} ({prev.cls.__module__}."
                f"{prev.cls.__qualname__}) and by plugin {owner!r} ({cls.__module__}.{cls.__qualname__})"
            )
        table[name] = Entry(role, name, cls, owner)

    def add_bench_suite(self, name: str, run: Callable[[Path, bool], dict[str, Any]], description: str,
                        owner: str) -> None:
        if not _COMP_NAME.match(name or ""):
            raise RegistryError(f"plugin {owner!r}: bench suite name {name!r} is not a lower-case identifier")
        if not callable(run):
            raise RegistryError(f"plugin {owner!r} registered bench suite {name!r} with {run!r}, which is not callable")
        if name in self.bench_suites:
            prev = self.bench_suites[name]
            raise DuplicateNameError(
                f"bench suite {name!r} is registered twice: by plugin {prev.owner!r} ({_qualname(prev.run)}) "
                f"and by plugin {owner!r} ({_qualname(run)})"
            )
        self.bench_suites[name] = BenchSuite(name, run, description, owner)

    # -- look-ups -------------------------------------------------------------
    def operator(self, name: str) -> type[Operator]:
        try:
            return self.operators[name].cls
        except KeyError:
            raise RegistryError(_unknown("operator", name, self.operators)) from None

    def source_for(self, arg: str) -> type[Source]:
        """The source class that opens ``arg``: by URL scheme, else by file
        content, else by extension. The one way tectum chooses a source (the
        CLI's ``info``, ``convert`` and ``run`` and the Python API all come
        here). Raises :class:`RegistryError` for a missing file or unknown
        scheme, :class:`FormatError` for a file nothing recognises."""
        return self._resolve(arg, self.sources, "source")

    def sink_for(self, arg: str) -> type[Sink]:
        """The sink class that writes ``arg``: by URL scheme, else by extension
        (an existing file is not sniffed: it will be replaced)."""
        return self._resolve(arg, self.sinks, "sink")

    def _resolve(self, arg: str, table: dict[str, Entry], role: str) -> type:
        scheme = _scheme(arg)
        if scheme is not None:
            for e in table.values():
                if scheme in e.cls.schemes:
                    return e.cls
            known = sorted({s for e in table.values() for s in e.cls.schemes})
            raise RegistryError(f"no {role} handles the scheme {scheme!r} (known: {', '.join(known)})")
        try:  # one stat for os.path.exists and os.path.isdir (system calls cost ~10 us each on a busy machine)
            mode = os.stat(arg).st_mode if role == "source" else 0
        except (OSError, ValueError):
            mode = -1
        if mode < 0:
            raise RegistryError(f"{arg!r}: no such file, and not a URL with a known scheme")
        if stat.S_ISDIR(mode):
            for e in table.values():
                if e.cls.sniff_dir(arg):
                    return e.cls
            raise RegistryError(f"{arg!r} is a folder that no source recognises")
        head = b""
        if role == "source":
            try:
                with open(arg, "rb", buffering=0) as f:  # unbuffered: no terminal test, no seek, no 8 KiB read
                    head = f.read(4096)
            except OSError as e:
                raise FormatError(f"cannot open: {e.strerror}", path=arg) from None
            for entry in table.values():
                if entry.cls.sniff(head):
                    return entry.cls
        lower = arg.lower()
        best = None
        for entry in table.values():
            for ext in entry.cls.extensions:
                if lower.endswith(ext) and (best is None or len(ext) > best[0]):
                    best = (len(ext), entry.cls)
        if best:
            return best[1]
        exts = ", ".join(sorted({x for e in table.values() for x in e.cls.extensions}))
        if role == "source":
            raise FormatError(f"unrecognised event file format (first bytes {head[:16]!r}; known extensions: "
                              f"{exts})", path=arg, offset=0)
        raise RegistryError(f"no {role} recognises {arg!r} (known extensions: {exts})")


def _scheme(arg: str) -> str | None:
    m = re.match(r"^([a-zA-Z][a-zA-Z0-9+.-]*):(.*)$", arg)
    if not m or len(m.group(1)) == 1:  # a Windows drive letter is not a scheme
        return None
    return m.group(1).lower()


def _qualname(fn: Any) -> str:
    return f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', type(fn).__qualname__)}"


def _unknown(role: str, name: str, table: dict[str, Entry]) -> str:
    import difflib

    close = difflib.get_close_matches(name, list(table), n=3)
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    return f"unknown {role} {name!r}{hint} (see `tectum plugins`)"


class RegistryView:
    """What a hook receives: adds components on behalf of one plugin."""

    def __init__(self, registry: Registry, owner: str) -> None:
        self._registry = registry
        self.owner = owner

    def add_operator(self, cls: type[Operator]) -> None:
        self._registry.add("operator", cls, self.owner)

    def add_source(self, cls: type[Source]) -> None:
        self._registry.add("source", cls, self.owner)

    def add_sink(self, cls: type[Sink]) -> None:
        self._registry.add("sink", cls, self.owner)

    def add_macro(self, cls: type[Macro]) -> None:
        """Add a pipeline macro (see ``tectum_register_macros``)."""
        self._registry.add("macro", cls, self.owner)

    def add_kind(self, cls: type[Packet]) -> None:
        """Add a kind of sample stream (see ``tectum_register_kinds``)."""
        try:
            register_kind(cls)
        except ValueError as e:
            raise RegistryError(f"plugin {self.owner!r}: {e}") from None
        self._registry.kinds[str(cls.kind)] = Entry("kind", str(cls.kind), cls, self.owner)

    def add_bench_suite(self, name: str, run: Callable[[Path, bool], dict[str, Any]], description: str) -> None:
        """Add the ``tectum bench`` suite ``name``: ``run(out, quick)``
        returns its numbers; ``description`` is one line for ``--list``."""
        self._registry.add_bench_suite(name, run, description, self.owner)


def plugin_manager(load_entry_points: bool = True) -> pluggy.PluginManager:
    """A plugin manager with tectum's hook specifications and every plugin
    of the ``tectum`` entry-point group loaded."""
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    if load_entry_points:
        pm.load_setuptools_entrypoints(hookspecs.PROJECT)
    if pm.get_plugin("core") is None:
        raise RegistryError(
            "tectum's built-in plugins were not found through the 'tectum' entry-point group: "
            "install the package (pip install .) rather than importing it from the source tree"
        )
    return pm


def build_registry(pm: pluggy.PluginManager) -> Registry:
    """Call every plugin's registration hooks with a view naming it as owner."""
    reg = Registry()
    for name, plugin in pm.list_name_plugin():
        reg.plugins[name] = getattr(plugin, "__name__", repr(plugin))
    for hook in ("tectum_register_kinds", "tectum_register_sources", "tectum_register_sinks",
                 "tectum_register_operators", "tectum_register_macros", "tectum_register_bench_suites"):
        caller = getattr(pm.hook, hook)
        for impl in caller.get_hookimpls():  # registration order
            impl.function(registry=RegistryView(reg, impl.plugin_name))
    return reg


_default: Registry | None = None


def get_registry(*, reload: bool = False) -> Registry:
    """The process-wide registry (built on first use)."""
    global _default
    if _default is None or reload:
        _default = build_registry(plugin_manager())
    return _default


def _reset_for_tests(registry: Any = None) -> None:
    global _default
    _default = registry
