"""Event text writer: the RPG ``events.txt`` layout (``t x y p``, t in seconds
with 9 decimals, p 0/1) or CSV, formatted by a numba kernel (no Python per
event). Time is printed from integer µs exactly, so reading back gives the
same µs."""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit

from tectum import EventPacket

from ._common import FileSink

__all__ = ["TextSink", "format_events"]

_UNIT_DIGITS = {"s": 6, "ms": 3, "us": 0}


@njit(cache=True, nogil=True)
def _put_uint(out, k, v):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    if v == 0:
        out[k] = 48
        return k + 1
    n = 0
    tmp = v
    while tmp > 0:
        tmp //= 10
        n += 1
    for i in range(n - 1, -1, -1):
        out[k + i] = 48 + v % 10
        v //= 10
    return k + n


@njit(cache=True, nogil=True)
def format_events(t, x, y, p, order, digits, sep, pad_ns, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Write lines into ``out`` (uint8); returns bytes used."""
    k = 0
    scale = np.int64(1)
    for _ in range(digits):
        scale *= 10
    for i in range(t.shape[0]):
        for c in range(4):
            f = order[c]
            if c > 0:
                out[k] = sep
                k += 1
            if f == 0:
                v = t[i]
                if v < 0:
                    out[k] = 45
                    k += 1
                    v = -v
                if digits > 0:
                    k = _put_uint(out, k, v // scale)
                    out[k] = 46
                    k += 1
                    fr = v % scale
                    for d in range(digits - 1, -1, -1):
                        out[k + d] = 48 + fr % 10
                        fr //= 10
                    k += digits
                    for _ in range(pad_ns):
                        out[k] = 48
                        k += 1
                else:
                    k = _put_uint(out, k, v)
            elif f == 1:
                k = _put_uint(out, k, np.int64(x[i]))
            elif f == 2:
                k = _put_uint(out, k, np.int64(y[i]))
            else:
                out[k] = 49 if p[i] > 0 else 48
                k += 1
        out[k] = 10
        k += 1
    return k


class TextSink(FileSink):
    """Events to ``events.txt``-style text (``.txt``) or CSV (``.csv``).

    Parameters
    ----------
    columns:
        Column order, a permutation of ``txyp``.
    time_unit:
        ``s`` (default; printed with 9 decimals like the RPG dataset), ``ms`` or ``us``.
    header:
        Write a ``t,x,y,p`` header line (CSV) — default for ``.csv``.
    """

    name = "text"
    format = "text"
    title = "text"
    extensions = (".txt",)  # .csv: the csv sink, which writes events through this one

    def __init__(self, path: str, columns: str = "txyp", time_unit: str = "s", header: bool | None = None) -> None:
        super().__init__(path)
        if sorted(columns) != sorted("txyp"):
            raise ValueError(f"columns must be a permutation of 'txyp', got {columns!r}")
        if time_unit not in _UNIT_DIGITS:
            raise ValueError(f"time_unit must be one of {list(_UNIT_DIGITS)}")
        self.csv = self.path.lower().endswith(".csv")
        self.columns = columns
        self.time_unit = time_unit
        self.header = self.csv if header is None else header
        self.order = np.array(["txyp".index(c) for c in columns], np.int64)

    def _begin(self, packet: EventPacket) -> None:
        assert self.f is not None
        if self.header:
            self.f.write((",".join(self.columns) if self.csv else " ".join(self.columns)).encode() + b"\n")

    def _empty(self) -> None:
        self._begin(EventPacket.empty((1, 1), 0))

    def _end(self) -> None:
        # A stream without events still leaves a file that says so: a 0-byte
        # text file reads back as an error (an empty file is a damaged one).
        if self.count == 0 and not self.header:
            assert self.f is not None
            self.f.write(b"# tectum: no events\n")

    def _events(self, packet: EventPacket) -> None:
        assert self.f is not None
        digits = _UNIT_DIGITS[self.time_unit]
        pad = 3 if self.time_unit == "s" else 0
        out = np.empty(len(packet) * (22 + digits + pad + 3 * 6), np.uint8)
        k = format_events(packet.t, packet.x, packet.y, packet.p, self.order, digits,
                          44 if self.csv else 32, pad, out)
        self.f.write(out[:k].tobytes())


def write_text(path: str, packet: EventPacket, **kw: Any) -> None:
    from ._common import write_all

    write_all(TextSink(path, **kw), [packet])
