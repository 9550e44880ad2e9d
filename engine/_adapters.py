"""Adapters between :class:`EventPacket` and the structured arrays of other
libraries (tonic, faery, Prophesee's openeb/Metavision, iniVation's
dv-processing).

Going out copies into the layout the other library expects (0/1 or bool
polarity, its field order and dtypes). Coming in accepts any structured
array whose fields are named in one of these conventions and converts at the
edge: polarity to ±1, time to int64 µs.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ._packet import EventPacket
from .errors import PacketError

__all__ = ["LAYOUTS", "to_structured", "from_structured"]

Layout = Literal["tonic", "faery", "metavision", "dv"]

#: The dtype of each layout; polarity field last-but-not-always, as each library has it.
LAYOUTS: dict[str, np.dtype] = {
    # tonic's events_struct: x, y, t (µs), p (bool)
    "tonic": np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "?")]),
    # faery.EVENTS_DTYPE: t (µs, u64), x, y, on (bool)
    "faery": np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("on", "?")]),
    # Metavision EventCD: x, y, p (0/1 as int16), t (µs, int64)
    "metavision": np.dtype([("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")]),
    # dv-processing EventStore.numpy(): timestamp (µs), x, y, polarity (0/1)
    "dv": np.dtype([("timestamp", "<i8"), ("x", "<i2"), ("y", "<i2"), ("polarity", "u1")]),
}

_TIME = ("t", "ts", "timestamp")
_POL = ("p", "on", "polarity", "pol")


def to_structured(packet: EventPacket, layout: Layout) -> np.ndarray:
    """The packet's events as a structured array in ``layout``."""
    try:
        dt = LAYOUTS[layout]
    except KeyError:
        raise ValueError(f"unknown layout {layout!r}; known: {sorted(LAYOUTS)}") from None
    out = np.empty(len(packet), dt)
    names = dt.names or ()
    tname = next(n for n in names if n in _TIME)
    pname = next(n for n in names if n in _POL)
    out[tname] = packet.t
    out["x"] = packet.x
    out["y"] = packet.y
    out[pname] = packet.p > 0
    return out


def from_structured(
    arr: np.ndarray,
    *,
    sensor: tuple[int, int],
    t_start: int | None = None,
    t_end: int | None = None,
    time_scale: float = 1.0,
) -> EventPacket:
    """A packet from a structured array with fields x, y, a time field
    (``t``/``ts``/``timestamp``) and a polarity field (``p``/``on``/
    ``polarity``). ``time_scale`` converts its time unit to µs (1e6 for
    seconds). The result is validated."""
    names = arr.dtype.names
    if not names:
        raise PacketError("expected a structured array with named fields")
    try:
        tname = next(n for n in _TIME if n in names)
        pname = next(n for n in _POL if n in names)
    except StopIteration:
        raise PacketError(f"fields {names} lack a time ({_TIME}) or polarity ({_POL}) field") from None
    if "x" not in names or "y" not in names:
        raise PacketError(f"fields {names} lack x or y")
    t = arr[tname]
    if time_scale != 1.0 or t.dtype.kind == "f":
        t = np.round(t.astype(np.float64) * time_scale)
    if t.dtype.kind == "u" and t.size and int(t.max()) > np.iinfo(np.int64).max:
        raise PacketError("timestamps do not fit int64 µs")
    return EventPacket.from_arrays(t, arr["x"], arr["y"], arr[pname], sensor=sensor, t_start=t_start, t_end=t_end)
