"""The packet types that flow along a pipeline's edges.

The packet contract
-------------------
* Every packet covers a half-open time interval ``[t_start, t_end)`` in
  microseconds (int). Its samples satisfy ``t_start <= t < t_end`` and are
  sorted by ``t`` (non-decreasing).
* ``t_end`` is a watermark: the stream promises that no later packet holds a
  sample with ``t < t_end``. Consecutive packets of one stream therefore have
  ``next.t_start >= prev.t_end``; samples sharing one timestamp are never split
  across two packets.
* An empty packet is valid and still carries its interval: that is how time
  advances downstream when nothing happens (a tick).
* Packets are immutable. Operators never write into the arrays of a packet
  they receive; they allocate outputs (or share untouched columns).
* Events: ``t`` int64 µs, ``x``/``y`` uint16 pixels, ``p`` int8 in {+1, -1}
  (sources convert 0/1 polarity at the edge), all 1-D and C-contiguous, plus
  the sensor size ``(width, height)`` in pixels and any extra per-event
  columns (``vx``, ``vy``, ``lifetime``, ``noise`` ...), attached without
  copying the base columns.
* Checked once: :meth:`EventPacket.validate` (one compiled pass over the
  events) marks the packet as checked, and views and selections of a
  checked packet are checked too, so a source that validates its packets
  does not pay for a second check where they enter the pipeline (the
  pipeline's guard checks every packet that is not marked). The mark is
  sound because packets are immutable.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator, Mapping
from types import MappingProxyType
from typing import Any, ClassVar, Self

import numpy as np
from numba import njit

from .errors import PacketError

__all__ = ["Kind", "Packet", "EventPacket", "accepts", "as_times", "register_kind", "packet_class"]

_BASE = ("t", "x", "y", "p")
#: The arrays the base columns of a packet are views of (``t``, ``x``, ``y``, ``p``): see ``EventPacket._own``.
Owners = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
_NO_COLUMNS: Mapping[str, np.ndarray] = MappingProxyType({})
_DTYPES = {"t": np.dtype(np.int64), "x": np.dtype(np.uint16), "y": np.dtype(np.uint16), "p": np.dtype(np.int8)}


class _KindMeta(type):
    def __iter__(cls) -> Iterator[Kind]:
        """Every registered kind (built-in and plugin), in registration order."""
        return iter(tuple(_KIND_CLASSES))


class Kind(str, metaclass=_KindMeta):
    """The name of a kind of stream a pipeline edge can carry (``events``,
    ``imu``, ``poses``, ...): a plain string with the built-in kinds as
    attributes. Plugins add kinds by registering a packet class
    (:func:`tectum.register_kind`, or the ``tectum_register_kinds`` hook);
    ``iter(Kind)`` gives every registered kind. :attr:`ANY` in a sink's or
    operator's ``consumes`` accepts every kind."""

    __slots__ = ()

    EVENTS: ClassVar[Kind]
    FRAMES: ClassVar[Kind]
    IMU: ClassVar[Kind]
    POSES: ClassVar[Kind]
    TRIGGERS: ClassVar[Kind]
    RESULTS: ClassVar[Kind]
    ANGULAR_VELOCITY: ClassVar[Kind]
    TRACKS: ClassVar[Kind]
    CLUSTERS: ClassVar[Kind]
    MAPS: ClassVar[Kind]
    POINTS: ClassVar[Kind]
    ANY: ClassVar[Kind]

    def __new__(cls, name: str) -> Kind:
        if not isinstance(name, str) or not _KIND_NAME.match(name):
            raise ValueError(f"a stream kind is a lower-case identifier, got {name!r}")
        return super().__new__(cls, name)

    def __repr__(self) -> str:
        return f"Kind({str.__repr__(self)})"

    def __str__(self) -> str:
        return str.__str__(self)


_KIND_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
#: Packet class of every registered kind (filled by ``register_kind``).
_KIND_CLASSES: dict[Kind, type[Packet]] = {}
for _name in ("events", "frames", "imu", "poses", "triggers", "results", "angular_velocity", "tracks",
              "clusters", "maps", "points", "any"):
    setattr(Kind, _name.upper(), Kind(_name))


def accepts(consumes: Iterable[Kind], kind: Kind) -> bool:
    """True when a component consuming ``consumes`` takes packets of ``kind``."""
    return kind in consumes or Kind.ANY in consumes


def register_kind(cls: type[Packet]) -> type[Packet]:
    """Register a packet class as the class of its ``kind`` (usable as a
    class decorator). A kind registered twice by different classes raises
    :class:`tectum.DuplicateNameError` naming both."""
    from .errors import DuplicateNameError

    kind = getattr(cls, "kind", None)
    if not isinstance(kind, Kind) or kind == Kind.ANY:
        raise ValueError(f"{cls.__name__}.kind must be a tectum.Kind (not ANY), got {kind!r}")
    prev = _KIND_CLASSES.get(kind)
    if prev is not None and prev is not cls:
        raise DuplicateNameError(
            f"kind {str(kind)!r} is registered twice: by {prev.__module__}.{prev.__qualname__} "
            f"and by {cls.__module__}.{cls.__qualname__}")
    _KIND_CLASSES[kind] = cls
    return cls


def packet_class(kind: Kind | str) -> type[Packet]:
    """The packet class registered for ``kind``; raises KeyError naming the known kinds."""
    try:
        return _KIND_CLASSES[Kind(kind)]
    except KeyError:
        raise KeyError(f"unknown stream kind {str(kind)!r} (known: {', '.join(_KIND_CLASSES)})") from None


class Packet:
    """Base of all packets: a time interval ``[t_start, t_end)`` in µs."""

    __slots__ = ("t_start", "t_end")
    kind: ClassVar[Kind]
    t_start: int
    t_end: int
    t: np.ndarray

    def __len__(self) -> int:
        return self.t.shape[0]  # a Python int already (no int() call: len() runs per packet)

    @property
    def duration(self) -> int:
        """``t_end - t_start`` in µs."""
        return self.t_end - self.t_start

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    def _init_interval(self, t: np.ndarray, t_start: int | None, t_end: int | None) -> None:
        if (t_start is None or t_end is None) and t.shape[0] > 1 and t[-1] < t[0]:
            self._check_times_order(t)  # names the first decreasing index
        if t_start is None:
            t_start = int(t[0]) if t.shape[0] else 0
        if t_end is None:
            t_end = int(t[-1]) + 1 if t.shape[0] else int(t_start)
        t_start, t_end = int(t_start), int(t_end)
        if t_end < t_start:
            raise PacketError(f"interval [{t_start}, {t_end}) ends before it starts")
        object.__setattr__(self, "t_start", t_start)
        object.__setattr__(self, "t_end", t_end)

    @staticmethod
    def _check_times_order(t: np.ndarray) -> None:
        bad = np.flatnonzero(t[1:] < t[:-1])
        if bad.size:
            i = int(bad[0]) + 1
            raise PacketError(f"timestamps decrease at index {i}: {int(t[i - 1])} then {int(t[i])} µs", index=i)

    def _check_times(self) -> None:
        t = self.t
        if t.shape[0] == 0:
            return
        if t.shape[0] > 1:
            bad = np.flatnonzero(t[1:] < t[:-1])
            if bad.size:
                i = int(bad[0]) + 1
                raise PacketError(
                    f"timestamps decrease at index {i}: {int(t[i - 1])} then {int(t[i])} µs", index=i
                )
        if int(t[0]) < self.t_start or int(t[-1]) >= self.t_end:
            i = 0 if int(t[0]) < self.t_start else len(t) - 1
            raise PacketError(
                f"sample at index {i} (t={int(t[i])} µs) lies outside the packet interval "
                f"[{self.t_start}, {self.t_end})",
                index=i,
            )

    def _bounds(self, t0: int | None, t1: int | None) -> tuple[int, int, int, int]:
        lo = self.t_start if t0 is None else max(int(t0), self.t_start)
        hi = self.t_end if t1 is None else min(int(t1), self.t_end)
        hi = max(hi, lo)
        t = self.t  # the method, not np.searchsorted: 0.4 µs a search, not 1 (a source cuts a packet per slice)
        return lo, hi, int(t.searchsorted(lo)), int(t.searchsorted(hi))

    def slice_time(self, t0: int | None = None, t1: int | None = None) -> Self:
        """Zero-copy view of the samples with ``t0 <= t < t1`` (µs).

        The result's interval is ``[t0, t1)`` clipped to this packet's interval.
        """
        lo, hi, i, j = self._bounds(t0, t1)
        return self._take_slice(i, j, lo, hi)  # type: ignore[return-value]  # subclasses slice to their class

    def _take_slice(self, i: int, j: int, t_start: int, t_end: int) -> Packet:
        raise NotImplementedError

    def split_at(self, t: int) -> tuple[Self, Self]:
        """Two zero-copy views: ``[t_start, t)`` and ``[t, t_end)`` (µs)."""
        t = min(max(int(t), self.t_start), self.t_end)
        return self.slice_time(None, t), self.slice_time(t, None)

    def batches(self, max_samples: int) -> Iterator[Self]:
        """Split into zero-copy views of at most ``max_samples`` samples each.

        Samples sharing a timestamp stay together (a run longer than
        ``max_samples`` goes out whole), intervals stay contiguous and cover
        this packet's interval exactly. ``max_samples=1`` gives one timestamp
        per packet: event-by-event mode.
        """
        if max_samples < 1:
            raise ValueError("max_samples must be >= 1")
        n = len(self)
        if n <= max_samples:
            yield self
            return
        t = self.t
        take: Any = self._take_slice  # makes packets of this class
        if max_samples == 1:  # one timestamp per packet: walk the runs
            runs = (np.flatnonzero(t[1:] != t[:-1]) + 1).tolist()
            ts = t[runs].tolist()
            lo, start = self.t_start, 0
            ev: Any = self
            if type(self) is EventPacket and not ev.columns:  # the hot case, inlined
                x, y, p, sensor = ev.x, ev.y, ev.p, ev.sensor
                checked = ev._checked
                if len(runs) == n - 1:  # one event per timestamp: rows of (n, 1) views cost less than slices
                    blank: Any = _Build
                    cls, cols = EventPacket, _NO_COLUMNS
                    for hi, a, b, c, d in zip([*ts, self.t_end], t.reshape(-1, 1), x.reshape(-1, 1),
                                              y.reshape(-1, 1), p.reshape(-1, 1)):
                        q = blank()  # _built, inlined (a call costs as much as the stores)
                        q.t = a
                        q.x = b
                        q.y = c
                        q.p = d
                        q.sensor = sensor
                        q.columns = cols
                        q.t_start = lo
                        q.t_end = hi
                        q._checked = checked
                        q._at = -1
                        q._stop = -1
                        q._own = None
                        q.__class__ = cls
                        yield q
                        lo = hi
                    return
                built: Any = _built  # makes EventPackets (the class tested above)
                for stop, hi in zip(runs, ts):
                    yield built(t[start:stop], x[start:stop], y[start:stop], p[start:stop], sensor, lo, hi,
                                _NO_COLUMNS, checked)
                    start, lo = stop, hi
            else:
                for stop, hi in zip(runs, ts):
                    yield take(start, stop, lo, hi)
                    start, lo = stop, hi
            yield take(start, n, lo, self.t_end)
            return
        start, lo = 0, self.t_start
        while start < n:
            stop = start + max_samples
            if stop >= n:
                yield take(start, n, lo, self.t_end)
                return
            ts_ = t[stop - 1]
            if t[stop] == ts_:  # a run straddles the cut: cut before it, or after it
                before = int(np.searchsorted(t, ts_, side="left"))
                stop = before if before > start else int(np.searchsorted(t, ts_, side="right"))
                if stop >= n:
                    yield take(start, n, lo, self.t_end)
                    return
            hi = int(t[stop])
            yield take(start, stop, lo, hi)
            start, lo = stop, hi


def _as_column(name: str, a: Any, n: int | None) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim == 0 or (n is not None and arr.shape[0] != n):
        raise PacketError(f"column {name!r} has shape {arr.shape}, expected {n} rows")
    return arr


class EventPacket(Packet):
    """Events as a struct of arrays, with the sensor size and the interval.

    Parameters
    ----------
    t, x, y, p:
        1-D arrays of equal length: ``t`` int64 µs, ``x``/``y`` uint16 pixels,
        ``p`` int8 polarity in {+1, -1}. Dtypes must match exactly; use
        :meth:`from_arrays` to convert foreign data.
    sensor:
        ``(width, height)`` in pixels.
    t_start, t_end:
        The interval in µs; defaults to ``[t[0], t[-1] + 1)``.
    columns:
        Extra per-event columns, each with one row per event.
    """

    __slots__ = ("t", "x", "y", "p", "sensor", "columns", "_checked", "_at", "_stop", "_own")
    kind = Kind.EVENTS
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    sensor: tuple[int, int]
    columns: Mapping[str, np.ndarray]
    _checked: bool
    #: Where the events start in the arrays the base columns are views of
    #: (``t.base``, ``x.base``, ...): every one a contiguous slice of its
    #: 1-D owner at this index; -1 when not known. Set by slicing
    #: (:meth:`slice_time`, :meth:`batches`), so that :func:`join_consecutive`
    #: joins a source's slices as a view without looking at pointers.
    _at: int
    #: Where they end there (``_at`` + the number of events; -1 with ``_at``):
    #: the engine's per-slice test reads it instead of the length of ``t``.
    _stop: int
    #: The owner arrays themselves, ``(t, x, y, p)``, when known (else
    #: None): one tuple shared by every slice of one packet (set with
    #: ``_at`` by slicing; a packet that owns its arrays keeps the tuple its
    #: first slice made), so that one identity test tells that two packets
    #: are views of the same four arrays (the engine's test per slice when
    #: it joins a run).
    _own: Owners | None

    def __init__(
        self,
        t: np.ndarray,
        x: np.ndarray,
        y: np.ndarray,
        p: np.ndarray,
        *,
        sensor: tuple[int, int],
        t_start: int | None = None,
        t_end: int | None = None,
        columns: Mapping[str, np.ndarray] | None = None,
    ) -> None:
        n = None
        for name, a in zip(_BASE, (t, x, y, p)):
            if not isinstance(a, np.ndarray) or a.dtype != _DTYPES[name] or a.ndim != 1:
                got = getattr(a, "dtype", type(a).__name__)
                raise PacketError(f"column {name!r} must be a 1-D {_DTYPES[name]} array, got {got}")
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise PacketError(f"column {name!r} has {a.shape[0]} events, 't' has {n}")
        cols = {}
        for name, a in (columns or {}).items():
            if name in _BASE:
                raise PacketError(f"extra column {name!r} shadows a base column")
            cols[name] = _as_column(name, a, n)
        w, h = int(sensor[0]), int(sensor[1])
        if w <= 0 or h <= 0 or w > 65536 or h > 65536:
            raise PacketError(f"sensor size {sensor!r} is not a (width, height) in 1..65536")
        set_ = object.__setattr__
        set_(self, "t", t)
        set_(self, "x", x)
        set_(self, "y", y)
        set_(self, "p", p)
        set_(self, "sensor", (w, h))
        set_(self, "columns", MappingProxyType(cols))
        set_(self, "_checked", False)
        set_(self, "_at", -1)
        set_(self, "_stop", -1)
        set_(self, "_own", None)
        self._init_interval(t, t_start, t_end)

    # -- construction -------------------------------------------------------
    @classmethod
    def _trusted(cls, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, sensor: tuple[int, int],
                 t_start: int, t_end: int, columns: Mapping[str, np.ndarray], checked: bool = False,
                 at: int = -1, own: Owners | None = None) -> EventPacket:
        """Internal: build from arrays already known to satisfy the contract
        (views and selections of a valid packet); skips every check.
        ``checked``: the arrays are views or selections of a packet that
        :meth:`validate` passed (see :attr:`checked`); ``at``, ``own``: see
        :attr:`_at` and :attr:`_own` (``own`` only with ``at``)."""
        cols = MappingProxyType(dict(columns)) if columns else _NO_COLUMNS
        if cls is EventPacket:
            return _built(t, x, y, p, sensor, t_start, t_end, cols, checked, at, own)
        pkt = _new(cls)
        _set_t(pkt, t)
        _set_x(pkt, x)
        _set_y(pkt, y)
        _set_p(pkt, p)
        _set_sensor(pkt, sensor)
        _set_columns(pkt, cols)
        _set_t_start(pkt, t_start)
        _set_t_end(pkt, t_end)
        _set_checked(pkt, checked)
        _set_at(pkt, at)
        _set_stop(pkt, at + t.shape[0] if at >= 0 else -1)
        _set_own(pkt, own)
        return pkt

    @classmethod
    def empty(cls, sensor: tuple[int, int], t_start: int, t_end: int | None = None) -> EventPacket:
        """A packet with no events covering ``[t_start, t_end)`` µs (a tick)."""
        z = np.empty(0, np.int64)
        return cls(
            z, np.empty(0, np.uint16), np.empty(0, np.uint16), np.empty(0, np.int8),
            sensor=sensor, t_start=t_start, t_end=t_start if t_end is None else t_end,
        )

    @classmethod
    def from_arrays(
        cls,
        t: Any,
        x: Any,
        y: Any,
        p: Any,
        *,
        sensor: tuple[int, int],
        t_start: int | None = None,
        t_end: int | None = None,
        columns: Mapping[str, Any] | None = None,
        validate: bool = True,
        time_unit: str = "us",
    ) -> EventPacket:
        """Build a packet from foreign arrays: converts dtypes and polarity.

        Times are integer µs; floats are accepted only when finite and
        whole, or, with ``time_unit="s"`` (or ``"ms"``), as seconds (or
        milliseconds) rounded to the nearest µs. Coordinates must be whole
        numbers in 0..65535. Polarity given as {0, 1} or bool becomes {-1,
        +1}; any other value than {-1, 0, +1} is an error. Errors name the
        first bad value. With ``validate`` (the default) the result is
        checked with :meth:`validate`.
        """
        t = as_times(t, time_unit)
        xs, ys = np.asarray(x), np.asarray(y)
        for name, a in (("x", xs), ("y", ys)):
            if a.dtype.kind == "f":
                bad = np.flatnonzero(~np.isfinite(a) | (a != np.round(a)))
                if bad.size:
                    i = int(bad[0])
                    raise PacketError(f"column {name!r}: event {i} has {name}={float(a.ravel()[i])}, not a whole pixel",
                                      index=i)
            elif a.dtype.kind not in "iub" and a.size:
                raise PacketError(f"column {name!r} must be numbers, got {a.dtype}")
            if a.size and (a.min() < 0 or a.max() > 65535):
                raise PacketError(f"column {name!r} has values outside 0..65535")
        p = _polarity(np.asarray(p))
        pkt = cls(
            t,
            np.ascontiguousarray(xs, dtype=np.uint16),
            np.ascontiguousarray(ys, dtype=np.uint16),
            p,
            sensor=sensor,
            t_start=t_start,
            t_end=t_end,
            columns={k: np.ascontiguousarray(v) for k, v in (columns or {}).items()},
        )
        if validate:
            pkt.validate()
        return pkt

    # -- checks ---------------------------------------------------------------
    @property
    def checked(self) -> bool:
        """True when :meth:`validate` passed on this packet, or on the packet
        it is a view or a selection of: the pipeline's guard does not check
        it again."""
        return self._checked

    def validate(self) -> EventPacket:
        """Check the whole contract (order, interval, geometry, polarity).

        Raises :class:`PacketError` naming the first bad event; returns self,
        marked :attr:`checked`. Sources call this where data enters (or let
        the pipeline's guard do it); operators' outputs are trusted. One
        compiled pass over the events; the error is worked out only when
        that pass finds one.
        """
        if self._checked:
            return self
        t = self.t
        n = t.shape[0]
        w, h = self.sensor
        if n and (t[0] < self.t_start or t[n - 1] >= self.t_end or not _events_ok(t, self.x, self.y, self.p, w, h)):
            self._raise_first_error()
        _set_checked(self, True)
        return self

    def _raise_first_error(self) -> None:
        """Raise the :class:`PacketError` of :meth:`validate`, naming the
        first bad event (checks in order: time order, interval, x, y,
        polarity)."""
        self._check_times()
        w, h = self.sensor
        if len(self):
            for name, lim in (("x", w), ("y", h)):
                a = getattr(self, name)
                bad = np.flatnonzero(a >= lim)
                if bad.size:
                    i = int(bad[0])
                    raise PacketError(
                        f"event {i} has {name}={int(a[i])}, outside the sensor {w}x{h}", index=i
                    )
            bad = np.flatnonzero((self.p != 1) & (self.p != -1))
            if bad.size:
                i = int(bad[0])
                raise PacketError(f"event {i} has polarity {int(self.p[i])}, expected +1 or -1", index=i)
        raise PacketError("packet breaks the contract")  # _events_ok and the checks above disagree

    # -- views ----------------------------------------------------------------
    def _take_slice(self, i: int, j: int, t_start: int, t_end: int) -> EventPacket:
        cols = self.columns
        t, x, y, p = self.t, self.x, self.y, self.p
        at, own = self._at, self._own
        if at >= 0:
            at += i
        elif t.base is None and x.base is None and y.base is None and p.base is None:
            at = i  # 1-D arrays that own their data: the slices' owners, one tuple for all of them
            if own is None:
                own = (t, x, y, p)
                _set_own(self, own)
        return EventPacket._trusted(
            t[i:j], x[i:j], y[i:j], p[i:j], self.sensor, t_start, t_end,
            {k: v[i:j] for k, v in cols.items()} if cols else cols, self._checked, at, own,
        )

    def select(self, mask: np.ndarray) -> EventPacket:
        """The events where ``mask`` (bool, one per event) is true (a copy),
        same interval."""
        mask = np.asarray(mask)
        if mask.dtype != np.bool_ or mask.shape != self.t.shape:
            raise PacketError(f"select needs a bool mask of shape {self.t.shape}, got {mask.dtype} {mask.shape}")
        idx = np.flatnonzero(mask)  # scan the mask once, not once per column
        return self.take(idx)

    def take(self, idx: np.ndarray) -> EventPacket:
        """The events at the increasing indices ``idx`` (a copy), same interval."""
        return EventPacket._trusted(
            self.t[idx], self.x[idx], self.y[idx], self.p[idx], self.sensor, self.t_start, self.t_end,
            {k: v[idx] for k, v in self.columns.items()}, self._checked,
        )

    def with_columns(self, **columns: np.ndarray) -> EventPacket:
        """A new packet sharing every array, with these columns added or replaced."""
        cols = dict(self.columns)
        cols.update(columns)
        pkt = EventPacket(
            self.t, self.x, self.y, self.p, sensor=self.sensor,
            t_start=self.t_start, t_end=self.t_end, columns=cols,
        )
        _set_checked(pkt, self._checked)  # the same base columns and interval
        _set_at(pkt, self._at)
        _set_stop(pkt, self._stop)
        _set_own(pkt, self._own)
        return pkt

    def without_columns(self, *names: str) -> EventPacket:
        """A new packet sharing every array, without the named extra columns."""
        cols = {k: v for k, v in self.columns.items() if k not in names}
        pkt = EventPacket(
            self.t, self.x, self.y, self.p, sensor=self.sensor,
            t_start=self.t_start, t_end=self.t_end, columns=cols,
        )
        _set_checked(pkt, self._checked)  # the same base columns and interval
        _set_at(pkt, self._at)
        _set_stop(pkt, self._stop)
        _set_own(pkt, self._own)
        return pkt

    def with_interval(self, t_start: int, t_end: int) -> EventPacket:
        """The same events with another interval (checked)."""
        pkt = EventPacket(
            self.t, self.x, self.y, self.p, sensor=self.sensor,
            t_start=t_start, t_end=t_end, columns=self.columns,
        )
        pkt._check_times()
        return pkt

    def __getitem__(self, name: str) -> np.ndarray:
        """A column by name: ``t``, ``x``, ``y``, ``p`` or an extra one."""
        if name in _BASE:
            return getattr(self, name)
        return self.columns[name]

    @property
    def column_names(self) -> tuple[str, ...]:
        return _BASE + tuple(self.columns)

    def __repr__(self) -> str:
        extra = f", columns={list(self.columns)}" if self.columns else ""
        return (
            f"EventPacket({len(self)} events, [{self.t_start}, {self.t_end}) µs, "
            f"sensor={self.sensor[0]}x{self.sensor[1]}{extra})"
        )


@njit(cache=True, nogil=True)
def _events_ok(t, x, y, p, w, h):  # type: ignore[no-untyped-def]
    """True when ``t`` never decreases, every ``x < w``, ``y < h`` and every
    ``p`` is +1 or -1: the per-event part of the contract, in one
    branch-free pass (no early exit: the loop vectorises)."""
    bad = False
    prev = t[0]
    for i in range(t.shape[0]):
        ti = t[i]
        pi = p[i]
        bad |= (ti < prev) | (x[i] >= w) | (y[i] >= h) | ((pi != 1) & (pi != -1))
        prev = ti
    return not bad



def join_consecutive(pkts: list[EventPacket]) -> EventPacket:
    """Consecutive packets of one event stream (same sensor and columns,
    ``next.t_start >= prev.t_end``, not checked) as one packet covering
    ``[first.t_start, last.t_end)``; checked when every packet is. A copy,
    unless the packets (without extra columns) are views lying end to end
    in the same arrays (a source cutting a decoded block): then a view of
    those arrays (no copy: 13 bytes per event not written and read again)."""
    first = pkts[0]
    if len(pkts) == 1:
        return first
    if not first.columns:
        view = _joined_view(pkts)
        if view is not None:
            return view
    t, x, y, p = (np.concatenate([getattr(q, k) for q in pkts]) for k in _BASE)
    cols = {k: np.concatenate([q.columns[k] for q in pkts]) for k in first.columns}
    return EventPacket._trusted(t, x, y, p, first.sensor, first.t_start, pkts[-1].t_end, cols,
                                all(q._checked for q in pkts))


def _joined_view(pkts: list[EventPacket]) -> EventPacket | None:
    """``pkts`` as one view of the arrays they are slices of, when every
    column of every packet is a contiguous slice, at the same index, of one
    1-D array per column, and each packet starts where the one before ends;
    else None."""
    first = pkts[0]
    owners: list[np.ndarray] = []
    for a in (first.t, first.x, first.y, first.p):
        o = a.base
        if type(o) is not np.ndarray or o.ndim != 1 or o.dtype != a.dtype or not o.flags.c_contiguous:
            return None
        owners.append(o)
    ot, ox, oy, op = owners
    start = at = -1
    for q in pkts:
        if q.t.base is not ot or q.x.base is not ox or q.y.base is not oy or q.p.base is not op:
            return None
        i = q._at  # known where the packet was sliced; else found from the pointers
        if i < 0:
            i = _slice_index(q.t, q.x, q.y, q.p, ot, ox, oy, op)
        if i < 0 or (at >= 0 and i != at):
            return None
        if start < 0:
            start = i
        at = i + q.t.shape[0]
    return EventPacket._trusted(ot[start:at], ox[start:at], oy[start:at], op[start:at], first.sensor,
                                first.t_start, pkts[-1].t_end, _NO_COLUMNS, all(q._checked for q in pkts), start)


@njit(cache=True, nogil=True)
def _slice_index(t, x, y, p, ot, ox, oy, op):  # type: ignore[no-untyped-def]
    """The index at which ``t, x, y, p`` start inside ``ot, ox, oy, op``
    when each is a contiguous view of its owner, all at the same index
    (the owners are 1-D, contiguous, of the views' dtypes); else -1."""
    n = t.shape[0]
    if n > 1 and (t.strides[0] != t.itemsize or x.strides[0] != x.itemsize or y.strides[0] != y.itemsize
                  or p.strides[0] != p.itemsize):
        return -1
    d = t.ctypes.data - ot.ctypes.data
    if d < 0 or d % t.itemsize:
        return -1
    i = d // t.itemsize
    if (x.ctypes.data - ox.ctypes.data != i * x.itemsize or y.ctypes.data - oy.ctypes.data != i * y.itemsize
            or p.ctypes.data - op.ctypes.data != i * p.itemsize):
        return -1
    return i


def builder(cls: type) -> type:
    """``cls`` under construction: a subclass with the same layout (no slots
    of its own), the generic setattr (packets refuse attribute stores: they
    are immutable) and a blank ``__init__``. A blank instance takes plain
    stores (4x faster than a call per slot: a packet per event in
    event-by-event mode), then becomes a ``cls`` (``__class__`` swapped:
    same layout). One per class, made once (:func:`_built` for
    :class:`EventPacket`, :meth:`Packet.batches` inlining it per event,
    ``SamplePacket._trusted`` for the sample kinds)."""
    build = _BUILDERS.get(cls)
    if build is None:
        build = _BUILDERS[cls] = type(f"_Build{cls.__name__}", (cls,), {
            "__slots__": (), "__setattr__": object.__setattr__, "__init__": object.__init__,
            "__module__": cls.__module__})
    return build


#: Each packet class's :func:`builder`.
_BUILDERS: dict[type, type] = {}
_Build = builder(EventPacket)


def _built(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, sensor: tuple[int, int], t_start: int,
           t_end: int, columns: Mapping[str, np.ndarray], checked: bool, at: int = -1,
           own: Owners | None = None) -> EventPacket:
    """An :class:`EventPacket` of these fields, unchecked (see :meth:`EventPacket._trusted`)."""
    pkt: Any = _Build()
    pkt.t = t
    pkt.x = x
    pkt.y = y
    pkt.p = p
    pkt.sensor = sensor
    pkt.columns = columns
    pkt.t_start = t_start
    pkt.t_end = t_end
    pkt._checked = checked
    pkt._at = at
    pkt._stop = at + t.shape[0] if at >= 0 else -1
    pkt._own = own
    pkt.__class__ = EventPacket
    return pkt


# Slot setters for EventPacket._trusted of subclasses (faster than object.__setattr__).
_new = object.__new__
_set_t, _set_x, _set_y, _set_p, _set_sensor, _set_columns, _set_checked, _set_at, _set_stop, _set_own = (
    EventPacket.__dict__[n].__set__
    for n in ("t", "x", "y", "p", "sensor", "columns", "_checked", "_at", "_stop", "_own")
)
_set_t_start, _set_t_end = (Packet.__dict__[n].__set__ for n in ("t_start", "t_end"))


_UNITS_US = {"us": 1, "ms": 1_000, "s": 1_000_000}


def as_times(t: Any, time_unit: str = "us") -> np.ndarray:
    """``t`` as int64 µs. Integers are taken as they are (in ``time_unit``);
    floats must be finite, and whole when in µs; in ``s`` or ``ms`` they are
    rounded to the nearest µs. Raises :class:`PacketError` naming the first
    bad sample."""
    if time_unit not in _UNITS_US:
        raise ValueError(f"time_unit must be one of {list(_UNITS_US)}, got {time_unit!r}")
    scale = _UNITS_US[time_unit]
    arr = np.asarray(t)
    if arr.dtype.kind in "iub":
        if arr.dtype.kind == "u" and arr.size and int(arr.max()) > np.iinfo(np.int64).max // scale:
            raise PacketError("'t' has values above the int64 µs range")
        out = np.ascontiguousarray(arr, dtype=np.int64)
        return out * scale if scale != 1 else out
    if arr.dtype.kind != "f":
        raise PacketError(f"'t' must be numbers of {time_unit}, got {arr.dtype}")
    us = arr * scale if scale != 1 else arr
    if scale != 1:
        us = np.round(us)
    bad = np.flatnonzero(~np.isfinite(us) | (us != np.round(us)) | (np.abs(us) > 2.0**62))
    if bad.size:
        i = int(bad[0])
        what = "whole µs (give time_unit='s' for seconds)" if scale == 1 else f"finite {time_unit}"
        raise PacketError(f"'t' must be {what}; sample {i} has t={float(arr.ravel()[i])}", index=i)
    return np.ascontiguousarray(us, dtype=np.int64)


def _polarity(p: np.ndarray) -> np.ndarray:
    if p.dtype == np.int8 and (p.size == 0 or bool(np.all((p == 1) | (p == -1)))):
        return np.ascontiguousarray(p)
    if p.size == 0:
        return np.empty(0, np.int8)
    if p.dtype == bool:
        return np.where(p, 1, -1).astype(np.int8)
    vals = np.unique(p)
    if np.all(np.isin(vals, (0, 1))):
        return np.where(p > 0, 1, -1).astype(np.int8)
    if np.all(np.isin(vals, (-1, 1))):
        return p.astype(np.int8)
    if np.all(np.isin(vals, (-1, 0, 1))):
        raise PacketError("polarity mixes 0 with -1: cannot tell the convention")
    raise PacketError(f"polarity values {vals[:5].tolist()} are not 0/1 or -1/+1")



register_kind(EventPacket)
