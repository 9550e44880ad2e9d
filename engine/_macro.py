"""Pipeline macros and delayed edges: declarations the validator expands.

A **macro** is one name (``tracker.evo``) that stands for several nodes and
their wiring. It is used wherever an operator name is (``Pipeline.op``, a
pipeline file's ``[[op]]``, the CLI's ``--op``); validation expands it into
nodes ``<id>.<part>`` plus a node ``<id>`` that hands on the outputs of the
parts the macro names (so sinks and operators read the macro's id as they
would read an operator's). The pipeline stays data: ``Pipeline.explain()``
and ``tectum run --explain`` show the expansion.

A **delayed edge** (:class:`Delayed`) delivers every packet crossing it
``delay_us`` later: its samples' times and its interval shift by that much.
A cycle in a pipeline is allowed when one of its edges is delayed (a
feedback loop: a tracker's poses feed a mapper whose maps come back to the
tracker).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from ._operator import Operator, Port
from ._packet import Kind
from .errors import PipelineError

__all__ = ["Delayed", "Macro", "Expansion", "MacroOutputs"]


@dataclass(frozen=True)
class Delayed:
    """An input edge from node ``node`` whose packets arrive ``delay_us`` µs
    late (> 0): give it as a named port's input,
    ``p.op("x", events=cam, maps=Delayed("m", 2000))``."""

    node: str
    delay_us: int

    def __post_init__(self) -> None:
        if isinstance(self.delay_us, bool) or not isinstance(self.delay_us, int) or self.delay_us <= 0:
            raise PipelineError(f"the delayed edge from {self.node!r}: delay_us must be an integer > 0 µs, "
                                f"got {self.delay_us!r}")


@dataclass(frozen=True)
class _Part:
    """A reference to another part of the same macro (see :meth:`Expansion.part`)."""

    name: str


@dataclass(frozen=True)
class _Input:
    """What feeds one of the macro's ports: a node given by name, or the
    macro's plain inputs (each part then takes from them by kind)."""

    ids: tuple[str, ...]
    by_name: bool


@dataclass
class PartSpec:
    """One node of an expansion, before it becomes a :class:`NodeSpec`."""

    part: str
    name: str
    params: dict[str, Any]
    ports: dict[str, str | Delayed | _Part] = field(default_factory=dict)  # str: a node outside the macro
    inputs: tuple[str, ...] = ()
    offload: bool | None = None
    buffer: int = 64
    parts_in: tuple[str, ...] = ()  # other parts read as plain inputs


class Expansion:
    """What :meth:`Macro.expand` builds with: parts (nodes) wired to each
    other and to what feeds the macro, and which parts' outputs leave it."""

    def __init__(self, macro: str, named: Mapping[str, str], positional: tuple[str, ...]) -> None:
        self.macro = macro
        self._named = dict(named)
        self._positional = positional
        self.parts: dict[str, PartSpec] = {}
        self.outputs: tuple[str, ...] = ()

    def port(self, name: str) -> _Input | None:
        """What feeds the macro's port ``name``: the node given for it by
        name, else the macro's plain inputs (the part fills its port from
        them by kind), or None when the macro has no input at all."""
        if name in self._named:
            return _Input((self._named[name],), True)
        return _Input(self._positional, False) if self._positional else None

    def part(self, name: str) -> _Part:
        """The output of part ``name`` (a port's input)."""
        return _Part(name)

    def delayed(self, part: str, delay_us: int) -> Delayed:
        """The output of part ``part``, ``delay_us`` µs late (a port's input)."""
        return Delayed(part, delay_us)

    def op(self, part: str, name: str, input: _Part | _Input | None = None, *, offload: bool | None = None,
           buffer: int = 64, **kw: Any) -> None:
        """Add part ``part`` running operator ``name``. ``input`` is a
        one-input operator's input (:meth:`part` or :meth:`port`); keywords
        that are :meth:`part`, :meth:`delayed` or :meth:`port` values wire
        named ports (None: leave that port open); the others are parameters."""
        if part in self.parts:
            raise PipelineError(f"macro {self.macro!r}: part {part!r} is added twice")
        spec = PartSpec(part, name, {}, offload=offload, buffer=buffer)
        extra: list[str] = []
        if isinstance(input, _Part):
            spec.parts_in = (input.name,)
        elif isinstance(input, _Input):
            extra += input.ids
        for k, v in kw.items():
            if v is None:
                continue
            if isinstance(v, (_Part, Delayed)):
                spec.ports[k] = v
            elif isinstance(v, _Input):
                if v.by_name:
                    spec.ports[k] = v.ids[0]
                else:
                    extra += v.ids
            else:
                spec.params[k] = v
        spec.inputs = tuple(dict.fromkeys(extra))
        self.parts[part] = spec

    def output(self, *parts: str) -> None:
        """The parts whose outputs leave the macro (its id reads them, merged by time)."""
        self.outputs = tuple(parts)


class Macro:
    """Base class of pipeline macros (``family.method`` names, as operators).

    A subclass sets :attr:`name` and :attr:`inputs` (its ports, as an
    operator's: wired by name or by kind), takes its parameters as typed
    keyword arguments of ``__init__`` (checked and converted like an
    operator's) and implements :meth:`expand`. Register it from a plugin's
    ``tectum_register_macros`` hook with ``registry.add_macro(cls)``.
    """

    name: ClassVar[str] = ""
    inputs: ClassVar[Mapping[str, Port]] = {}

    def expand(self, x: Expansion) -> None:
        """Add the parts (``x.op``) and name the outputs (``x.output``)."""
        raise NotImplementedError


class MacroOutputs(Operator):
    """The node a macro's id names: hands on its output parts' streams,
    merged by time (every kind passes by)."""

    name = ""
    consumes: ClassVar[tuple[Kind, ...]] = ()
    produces: ClassVar[tuple[Kind, ...]] = ()

    def __init__(self, macro: str, params: Mapping[str, Any], positional: tuple[str, ...]) -> None:
        self.macro = macro  # the macro's name, its converted parameters and plain inputs (for explain)
        self.params = dict(params)
        self.positional = positional

    def process(self, packet: Any) -> list[Any]:  # nothing is consumed: never called
        return [packet]
