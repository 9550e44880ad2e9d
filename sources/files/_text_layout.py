"""The layout of an event text file, read from its first lines: the column
order and the unit of the time column, each with the reason it was chosen.

The unit comes, in this order of trust, from the ``time_unit`` option, from
a header that names it (``t_us``, ``timestamp[ns]``, ``time (s)``), or from
the form of the values: decimals are seconds (the RPG ``events.txt``
layout, ``0.003811000 96 133 0``), integers are µs (the common CSV export),
integers of 18 or more digits ns since the epoch. The column order comes
from the ``columns`` option, else from a header naming all four columns
(``timestamp,x,y,polarity``; ``x@320`` as event-stream tools write it), else
``txyp``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ._text_head import PLAIN_LINES, plain_head

__all__ = ["TextLayout", "text_layout", "first_lines", "LETTERS", "UNITS"]

#: Units of the time column and their names in headers.
UNITS = {"s": "s", "sec": "s", "seconds": "s", "ms": "ms", "msec": "ms", "us": "us", "µs": "us", "usec": "us",
         "microseconds": "us", "ns": "ns", "nsec": "ns", "nanoseconds": "ns"}
_TIME = ("t", "ts", "time", "timestamp", "timestamps")
_FIELDS = {"x": "x", "y": "y", "p": "p", "pol": "p", "polarity": "p", "on": "p", "sign": "p", **{n: "t" for n in _TIME}}
_UNIT = "|".join(sorted(map(re.escape, UNITS), key=len, reverse=True))
# a time column's name with its unit: t_us, timestamp-ns, time (s), t[us]
_TIME_WITH_UNIT = re.compile(rf"^({'|'.join(_TIME)})(?:[ _-]+({_UNIT})|\s*[\[(]\s*({_UNIT})\s*[\])])$")
_EPOCH_NS_DIGITS = 18  # 1e17 ns is 1973: shorter integers are taken for µs
#: A letter (a header line has some, a data line none)
LETTERS = re.compile(rb"[A-Za-z]")
_FIELD_SEP = re.compile(rb"[ \t,;]+")
_FIRST_FIELD = re.compile(rb"^[^ \t,;\n]*", re.M)  # of each line: what _FIELD_SEP.split(line)[0] is


@dataclass(frozen=True)
class TextLayout:
    """Column order (a permutation of ``txyp``), time unit (``s``, ``ms``,
    ``us``, ``ns``) and, for each, why."""

    columns: str
    columns_from: str
    time_unit: str
    time_unit_from: str


def first_lines(head: bytes, k: int, *, strip: bool = True, comments: tuple[bytes, ...] = (b"#", b"%")) -> list[bytes]:
    """Up to ``k`` complete lines of ``head`` (a last one without its newline
    left out) that are not blank nor start with ``comments``; with ``strip``
    stripped (and tested for comments so), else as they are. Splits only as
    many lines as it needs (a few more than ``k``, more while too many were
    blank or comments): a sniffer reads the first lines of a 64 kB head, not
    all of them."""
    m = k + 8
    while True:
        pieces = head.split(b"\n", m)
        del pieces[-1]  # the rest of head, or the last line without its newline
        if strip:
            out = [ln for ln in map(bytes.strip, pieces) if ln and not ln.startswith(comments)]
        else:
            out = [raw for raw in pieces if not raw.startswith(comments) and raw.strip()]
        if len(out) >= k or len(pieces) < m:  # enough, or every line of head seen
            return out[:k]
        m *= 4


def _header(head: bytes) -> tuple[list[str], list[bytes]]:
    """The header's names (lower case, ``@size`` dropped; empty without a
    header) and the first data lines."""
    lines = first_lines(head, 21)
    if lines and LETTERS.search(lines[0]):
        text = lines[0].decode("utf-8", "replace").lower()
        return [re.sub(r"@\d+$", "", n.strip()) for n in re.split(r"[,\t;]| (?![\[(])", text) if n.strip()], lines[1:21]
    return [], lines[:20]


def _field(name: str) -> tuple[str | None, str | None]:
    """(field, unit) a header name stands for: ``"t_us"`` -> ``("t", "us")``."""
    if name in _FIELDS:
        return _FIELDS[name], None
    m = _TIME_WITH_UNIT.match(name)
    if m:
        return "t", UNITS[m.group(2) or m.group(3)]
    return None, None


def text_layout(head: bytes, columns: str | None = None, time_unit: str | None = None) -> TextLayout:
    """The layout of a text file starting with ``head`` (a few kB), the
    options (None: decide from the file) taking precedence. A head of plain
    event lines (:func:`plain_head`: no header) is judged in one pass, any
    other from its lines split."""
    k = (columns or "txyp").find("t")  # the time's field when there is no header
    plain, dot, width = plain_head(np.frombuffer(head, np.uint8), PLAIN_LINES, k) if k >= 0 else (False, False, 0)
    names, data = ([], []) if plain else _header(head)
    fields = [_field(n) for n in names]
    order = "".join(f for f, _ in fields if f)
    if columns:
        cols, cols_from = columns, "the columns option"
    elif len(names) == 4 and sorted(order) == sorted("txyp"):
        cols, cols_from = order, f"the header {','.join(names)!r}"
    else:
        cols, cols_from = "txyp", "no header naming t, x, y and p: the default"
    named = [(n, u) for n, (f, u) in zip(names, fields) if f == "t" and u]
    if time_unit:
        return TextLayout(cols, cols_from, time_unit, "the time_unit option")
    if named:
        return TextLayout(cols, cols_from, named[0][1], f"the header names the time column {named[0][0]!r}")
    if not plain:  # whether a time has a '.', and the most digits of one, from the lines split
        k = cols.index("t")
        if k == 0 and data:  # the first field of every line, in one call
            times = _FIRST_FIELD.findall(b"\n".join(data))
        else:
            times = [f[k] for f in (_FIELD_SEP.split(ln, k + 1) for ln in data) if len(f) > k]  # no further than t
        if not times:
            return TextLayout(cols, cols_from, "s", "no times to judge by: seconds, as in the RPG events.txt")
        dot = any(b"." in v for v in times)
        width = max(len(v.lstrip(b"+-")) for v in times)
    if dot:
        return TextLayout(cols, cols_from, "s", "the times are decimals: seconds, as in the RPG events.txt")
    if width >= _EPOCH_NS_DIGITS:
        return TextLayout(cols, cols_from, "ns", f"the times are integers of {_EPOCH_NS_DIGITS}+ digits: "
                                                 "ns since the epoch")
    return TextLayout(cols, cols_from, "us", "the times are integers: µs")
