"""Operators, sources and sinks: the three component classes plugins provide.

An operator is a small class around pure numba kernels. It declares the kinds
it consumes and produces, keeps its state in explicit attributes, and turns
each packet into zero or more packets. Ticks (time advancing with nothing to
report) arrive as empty packets; :meth:`Operator.finish` is called once at
end of stream. Packets of kinds an operator does not consume pass by it
untouched to its downstream nodes, except kinds it produces: its own stream
of such a kind replaces the upstream one (counted in the node's
``NodeStats.replaced``; ``results`` always pass by).

An operator with several inputs that keep their identity (events and poses,
a stereo pair) declares **named ports** in :attr:`Operator.inputs` and
implements :meth:`Operator.process_ports`: the engine joins the ports by
watermark and calls it with one packet per port, all covering the same
interval ``[t0, t1)``, released only once every port's stream has passed
``t1`` (so the poses up to the events' time are always there with the
events). Packets of other kinds on a port's edge are not passed by.

The life cycle: :meth:`Operator.warmup` once before the first packet
(compile kernels), then :meth:`Operator.process` (or ``process_ports``) per
packet, :meth:`Operator.on_tick` after each with the input watermark (for
time-driven output), and :meth:`Operator.finish` at end of stream.
:meth:`Operator.memory_us` states how far back its state reaches (for time
sharding).
"""

from __future__ import annotations

import copy
import enum
import inspect
from collections.abc import AsyncIterator, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ._packet import EventPacket, Kind, Packet

__all__ = ["Operator", "Port", "Source", "Sink", "component_params", "same_sensor"]


@dataclass(frozen=True)
class Port:
    """A named input of an operator: the kind it takes, whether it must be
    connected, and what it is for (shown by ``tectum plugins NAME``)."""

    kind: Kind
    required: bool = True
    doc: str = ""


class Operator:
    """Base class of operators (``family.method`` names).

    Subclasses set :attr:`name`, :attr:`consumes` and :attr:`produces`, take
    their parameters as typed keyword arguments of ``__init__`` (with units
    in the name or docstring), and implement :meth:`process`.
    """

    #: Registry name, ``family.method`` (e.g. ``filter.background_activity``).
    name: ClassVar[str] = ""
    #: Kinds of packet this operator handles; others pass by it (except those it produces).
    consumes: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS,)
    #: Kinds of packet this operator emits.
    produces: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS,)
    #: Named input ports (``{"events": Port(Kind.EVENTS), "poses": Port(Kind.POSES)}``);
    #: None for a one-input operator (its inputs merged, see :attr:`consumes`).
    inputs: ClassVar[Mapping[str, Port] | None] = None
    #: Heavy operators (optimisers, solvers) run off the event loop by
    #: default: a bounded edge in front and the work in a worker thread
    #: (a node's ``offload=`` overrides this).
    heavy: ClassVar[bool] = False

    def process(self, packet: Any) -> Sequence[Packet]:
        """Handle one packet (possibly empty: a tick); return the outputs.
        (Typed ``Any`` so that subclasses name the packet class they consume.)"""
        raise NotImplementedError

    def process_ports(self, ports: Mapping[str, Packet]) -> Sequence[Packet]:
        """Operators with :attr:`inputs`: handle one joined batch, one packet
        per port (possibly empty), all covering the same interval. A port
        whose stream has not yet delivered any packet, or has ended before
        the interval, is absent."""
        raise NotImplementedError

    def on_tick(self, watermark: int) -> Sequence[Packet]:
        """Called after each input with the input watermark (µs: nothing
        earlier will come); return time-driven output (default none)."""
        return ()

    def finish(self) -> Sequence[Packet]:
        """End of stream: return whatever is still buffered (default none)."""
        return ()

    def output_mark(self, watermark: int) -> int:
        """On a feedback loop (see :meth:`tectum.Pipeline.delayed`): the time
        (µs) before which this operator will emit nothing more, now that its
        input has passed ``watermark``. The default, ``watermark``, holds
        for operators whose outputs follow their input (each packet within
        the interval of the input that made it); one whose output lags (a
        map stamped with the last event it used) returns how far it lags.
        The engine moves the loop's downstream watermarks there, so the loop
        advances while the operator emits nothing."""
        return watermark

    def memory_us(self) -> int | None:
        """How far back in event time this operator's state reaches, in µs:
        what it emits once its input has passed any time ``a`` depends only
        on its input from ``a - memory_us()`` on (a filter's ``dt_us``, a
        window's length). Time sharding (:mod:`tectum.scale`) starts each
        shard that much earlier and drops what the warm-up emits. None (the
        default) states no finite memory (state learned from the whole
        stream, chains of kept events, counts, trackers): such an operator
        refuses to shard, with that reason."""
        return None

    def join_us(self) -> int | None:
        """The longest span of input (µs) this operator wants in one call
        when the engine joins a source's small packets before they go in
        (they are joined up to the pipeline's ``max_events`` either way);
        None (the default): no limit. An operator whose output grows with
        the span (a frame per window) keeps it short, so the output of one
        call stays in cache until it is consumed."""
        return None

    def window_grid_us(self) -> int:
        """Operators that cut their output on a grid of windows counted from
        their first packet's start: the grid's period in µs, so a shard's
        warm-up starts on the grid; 0 (the default) for none."""
        return 0

    @classmethod
    def check_ports(cls, connected: frozenset[str]) -> str | None:
        """Operators with :attr:`inputs`: say what is wrong with this set of
        connected ports (e.g. "needs imu or poses"), or None when it is fine."""
        return None

    def warmup(self) -> None:
        """Compile kernels before the first packet, so the first packet of a
        control loop is not slowed by compilation. The default runs a copy
        of the operator on a few synthetic events (one-input event
        operators) and discards it, once per process for operators of the
        same class and settings (:func:`_settings`: kernels compiled once
        stay compiled; a pipeline built per run pays it once); override it
        where that is not right."""
        if self.inputs is not None or Kind.EVENTS not in self.consumes:
            return
        key = _settings(self)
        if key is not None and key in _WARMED:
            return
        try:
            twin = copy.deepcopy(self)
        except Exception:  # state that cannot be copied (locks, files): no warm-up
            return
        n = 16
        t = np.arange(n, dtype=np.int64) * 10
        xy = (np.arange(n) % 8).astype(np.uint16)
        pol = np.where(np.arange(n) % 2 == 0, 1, -1).astype(np.int8)
        pkt = EventPacket(t, xy, xy[::-1].copy(), pol, sensor=(8, 8), t_start=0, t_end=int(t[-1]) + 1)
        try:
            twin.process(pkt)
            twin.finish()
        except Exception:  # warming up is best effort: the real run reports real errors
            return
        if key is not None and len(_WARMED) < 4096:
            _WARMED.add(key)

    def __repr__(self) -> str:
        return f"<{self.name or type(self).__name__}>"


#: Operators' settings (:func:`_settings`) whose default warm-up has run in this process.
_WARMED: set[Any] = set()
_PLAIN = (bool, int, float, complex, str, bytes, type(None), np.dtype, np.generic)


def same_sensor(name: str, sensor: tuple[int, int], packet: EventPacket) -> tuple[int, int]:
    """``packet.sensor`` when it is ``sensor`` (width, height px), the one an
    operator's per-pixel state was made for at its first packet; else a
    :class:`ValueError` naming both. Kernels index such state by ``x, y``
    without bounds checks, so the events of a larger sensor would write past
    it: an operator with per-pixel state calls this on every packet after its
    first (one stream has one sensor)."""
    if packet.sensor is not sensor and packet.sensor != sensor:
        raise ValueError(f"{name}: events of a {packet.sensor[0]}x{packet.sensor[1]} sensor after its state was made "
                         f"for {sensor[0]}x{sensor[1]} (one stream has one sensor)")
    return packet.sensor


def _settings(op: Operator) -> Any:
    """What an operator's kernels can depend on, as a hashable key: its
    class and its attributes, plain values (numbers, strings, dtypes, enums,
    tuples of them) as they are, arrays by dtype and dimensions, anything
    else by type; None for an operator without ``__dict__``."""
    state = getattr(op, "__dict__", None)
    if state is None:
        return None
    return (type(op), tuple((k, _setting(v)) for k, v in sorted(state.items())))


def _setting(v: Any) -> Any:
    if isinstance(v, _PLAIN) or isinstance(v, enum.Enum):
        return v
    if isinstance(v, np.ndarray):
        return (np.ndarray, v.dtype, v.ndim)
    if isinstance(v, tuple) and all(isinstance(x, _PLAIN) for x in v):
        return v
    return type(v)


class Source:
    """Base class of sources.

    A source produces packets from :meth:`packets` (a plain iterator, for
    files and generators) or :meth:`apackets` (an async iterator, for live
    devices and sockets); implement one. Packets leave a source validated:
    use :meth:`tectum.EventPacket.validate` or a :class:`tectum.Repair`.

    Class attributes tell the registry which arguments the source opens:
    ``schemes`` (URL schemes such as ``"tcp"``), ``extensions`` (``".npz"``)
    and :meth:`sniff` (file content).
    """

    name: ClassVar[str] = ""
    produces: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS,)
    schemes: ClassVar[tuple[str, ...]] = ()
    extensions: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        """True when a file starting with ``head`` is in this source's format."""
        return False

    @classmethod
    def kinds_for(cls, arg: str, params: Mapping[str, Any]) -> tuple[Kind, ...]:
        """The kinds of stream this source will give for ``arg`` with
        ``params``, known before it opens (validation wires ports by them):
        by default every kind it can produce; a source whose streams depend
        on what the recording holds narrows this."""
        return cls.produces

    @classmethod
    def sniff_dir(cls, path: str) -> bool:
        """True when the folder ``path`` is a recording this source opens
        (a ROS 2 bag, a dataset sequence)."""
        return False

    def packets(self) -> Iterator[Packet]:
        raise NotImplementedError

    async def apackets(self) -> AsyncIterator[Packet]:
        for pkt in self.packets():
            yield pkt

    @property
    def is_async(self) -> bool:
        return type(self).apackets is not Source.apackets

    @property
    def live(self) -> bool:
        """True for sources whose data arrive in real time (devices, sockets):
        they are never paced by the scheduler."""
        return self.is_async

    #: Counters a source keeps (overruns, losses, rejected input ...); the
    #: scheduler copies them into the node's stats at the end of the run.
    counts: dict[str, int]

    def close(self) -> None:
        """Release files, devices and sockets (called once, always)."""


class Sink:
    """Base class of sinks.

    The scheduler calls :meth:`open`, then :meth:`write` per packet, then
    :meth:`close` on success or :meth:`abort` after an error. File sinks write
    to a temporary name and rename it in :meth:`close`, so an aborted run
    never leaves a half-written file behind.
    """

    name: ClassVar[str] = ""
    consumes: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS,)
    schemes: ClassVar[tuple[str, ...]] = ()
    extensions: ClassVar[tuple[str, ...]] = ()

    def open(self) -> None:
        """Prepare to write (create files, connect)."""

    def write(self, packet: Packet) -> None:
        raise NotImplementedError

    async def awrite(self, packet: Packet) -> None:
        """Async variant, for network sinks; defaults to :meth:`write`."""
        self.write(packet)

    def bind_stats(self, stats: Any) -> None:
        """Called before :meth:`open` with the run's :class:`tectum.Stats`,
        for sinks that show them (a live view); default: ignored."""

    def close(self) -> None:
        """Flush and commit the output."""

    def abort(self) -> None:
        """Discard partial output after an error (default: :meth:`close`)."""
        self.close()

    async def aclose(self) -> None:
        """Async variant of :meth:`close` (network sinks); defaults to it."""
        self.close()

    async def aabort(self) -> None:
        """Async variant of :meth:`abort`; defaults to it."""
        self.abort()


def component_params(cls: type) -> dict[str, inspect.Parameter]:
    """The keyword parameters a component's ``__init__`` accepts, by name,
    including those it passes on to a base class through ``**kwargs``."""
    out: dict[str, inspect.Parameter] = {}
    for owner in _init_chain(cls):
        params = list(inspect.signature(owner.__init__).parameters.values())[1:]  # type: ignore[misc]
        for p in params:
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
                out.setdefault(p.name, p)
    return out


def _init_chain(cls: type) -> list[type]:
    """``cls`` and the base classes its ``__init__`` hands ``**kwargs`` on to."""
    chain = []
    for owner in cls.__mro__:
        if "__init__" not in owner.__dict__ or owner is object:
            continue
        chain.append(owner)
        sig = inspect.signature(owner.__init__)  # type: ignore[misc]
        if not any(p.kind == p.VAR_KEYWORD for p in sig.parameters.values()):
            break
    return chain


def as_packets(out: Iterable[Packet] | Packet | None) -> Sequence[Packet]:
    """Normalise what an operator returned into a sequence of packets."""
    if out is None:
        return ()
    if isinstance(out, Packet):
        return (out,)
    return out if isinstance(out, (list, tuple)) else list(out)


def coerce_param(cls: type, name: str, value: Any) -> Any:
    """Convert ``value`` (from TOML or a ``k=v`` string) to the annotated type."""
    import typing

    owner = next((c for c in _init_chain(cls) if name in inspect.signature(c.__init__).parameters), cls)  # type: ignore[misc]
    hints = typing.get_type_hints(owner.__init__)  # type: ignore[misc]  # the class's own constructor
    typ = hints.get(name)
    if typ is None:
        return value
    origin = typing.get_origin(typ)
    if origin is typing.Union or (origin is not None and str(origin) == "<class 'types.UnionType'>"):
        args = [a for a in typing.get_args(typ) if a is not type(None)]
        if value is None or (isinstance(value, str) and value.lower() == "none"):
            return None
        last: Exception | None = None
        for a in args:
            try:
                return _coerce_to(a, value)
            except (TypeError, ValueError) as e:
                last = e
        raise TypeError(f"expected {' or '.join(_type_name(a) for a in args)}, got {value!r}") from last
    return _coerce_to(typ, value)


def _type_name(typ: Any) -> str:
    """``int``, ``'auto'`` (a Literal's values), ``list[float]``: a type as a
    parameter's error message names it."""
    import typing

    if typing.get_origin(typ) is typing.Literal:
        return " or ".join(repr(v) for v in typing.get_args(typ))
    return typ.__name__ if isinstance(typ, type) else str(typ).replace("typing.", "")


def _coerce_to(typ: Any, value: Any) -> Any:
    import typing

    origin = typing.get_origin(typ)
    if origin is typing.Literal:
        for a in typing.get_args(typ):
            if value == a or (isinstance(value, str) and str(a) == value):
                return a
        raise ValueError(f"expected one of {typing.get_args(typ)}, got {value!r}")
    if origin in (tuple, list):
        items = value.split(";") if isinstance(value, str) else list(value)
        args = typing.get_args(typ)
        inner = args[0] if args else str
        return origin(_coerce_to(inner, v) for v in items)
    if typ is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "1", "yes", "on"):
            return True
        if isinstance(value, str) and value.lower() in ("false", "0", "no", "off"):
            return False
        raise ValueError(f"expected a boolean, got {value!r}")
    if typ is int:
        if isinstance(value, bool):
            raise ValueError(f"expected an integer, got {value!r}")
        if isinstance(value, float):
            if not value.is_integer():
                raise ValueError(f"expected an integer, got {value!r}")
            return int(value)
        return int(value)
    if typ is float:
        if isinstance(value, bool):
            raise ValueError(f"expected a number, got {value!r}")
        return float(value)
    if typ is str:
        if not isinstance(value, str):
            raise ValueError(f"expected a string, got {value!r}")
        return value
    if typ is Any or not isinstance(typ, type):
        return value
    if isinstance(value, typ):
        return value
    return typ(value)
