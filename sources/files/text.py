"""Event text files: the UZH/RPG event-camera dataset ``events.txt`` and CSV.

One event per line, four numbers separated by spaces, tabs or commas, in
the order given by ``columns`` with time in ``time_unit``; without those
options, the header's names and the form of the times decide (decimals are
seconds, as in the dataset: ``0.003811000 96 133 0``; integers µs; see
:mod:`._text_layout`), and :meth:`TextSource.info` says which. Polarity
0/1 or -1/+1. Lines starting with ``#`` or ``%`` and a header line with
letters (``t,x,y,p``) are skipped. Time is parsed from the decimal text
exactly into integer µs (rounded half up below 1 µs), never through a float.

Companion files next to ``events.txt`` (the dataset's layout) give more
streams: ``imu.txt`` (``t ax ay az gx gy gz``) and ``groundtruth.txt``
(``t px py pz qx qy qz qw``) and ``images.txt`` (``t path``). The sensor
size comes from the option, then from the first image, else from the largest
coordinates (a first pass over the file).
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Callable, Generator, Iterator, Mapping
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from tectum import FramePacket, ImuPacket, Kind, Packet, PosePacket, interleave

from ._common import POOL as _POOL
from ._common import EventAssembler, FileSource, byte_buffer, read_full
from ._text_head import plain_events_head
from ._text_layout import LETTERS, TextLayout, first_lines, text_layout
from ._text_swar import REACH, fast_lines

__all__ = ["TextSource", "parse_lines"]

_UNIT_DIGITS = {"s": 6, "ms": 3, "us": 0, "ns": -3}
#: the events file of a sequence folder of the RPG event-camera dataset (a folder given as the path opens it)
EVENTS_FILE = "events.txt"
#: :attr:`FileSource.sensor_from` of a size taken from the sequence's images
FROM_IMAGES = "the first image of images.txt"
_HOLD = 1 << 21  # events held in memory while inferring the sensor size
_HOLD_BYTES = 1 << 26  # text held (for error offsets) while inferring the sensor size
_RUNS = 4096  # runs of bad lines one parse_lines call records
_DTYPES = (np.int64, np.uint16, np.uint16, np.int8)  # t, x, y, p
_NO_WHERE = np.empty(0, np.int64)  # parse_lines without the line offsets


#: ``parse_lines`` reasons for a bad line
_REASONS = {1: "line is not 4 numbers", 2: "negative coordinate", 3: "coordinate above 65535",
            4: "polarity is not 0/1 or -1/+1 (or mixes the two)", 5: "time out of the int64 µs range"}
#: ``parse_lines`` state: polarity convention (0 not seen yet, 1 is 0/1, 2 is -1/+1), largest x, largest y,
#: 1 once a time was below the one before it in a call (0 while they never decrease)
_STATE = 4


@njit(cache=True, nogil=True, inline="always")
def _at(buf, i):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """``buf[i]`` for ``i >= 0`` as int64: an unsigned index spares the
    negative-index check, and int64 arithmetic on the byte keeps the digit
    loops 5x faster than on uint8 (numba's mixed-type promotion)."""
    return np.int64(buf[np.uint64(i)])


@njit(cache=True, nogil=True, inline="always")
def _sep(c):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    return c == 32 or c == 9 or c == 44 or c == 13


@njit(cache=True, nogil=True, inline="always")
def _digits(buf, j):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The unsigned decimal integer at ``buf[j:]``: (value, digits, end).
    Loops here are ``while True`` with a ``break``: numba compiles ``while
    48 <= c <= 57`` into a loop about 5x slower."""
    v = np.int64(0)
    k = j
    while True:
        d = _at(buf, k) - 48
        if d < 0 or d > 9:
            break
        v = v * 10 + d
        k += 1
    return v, k - j, k


@njit(cache=True, nogil=True, inline="always")
def _blanks(buf, j):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The index of the first byte from ``j`` on that is no space, tab or comma."""
    while True:
        c = _at(buf, j)
        if c != 32 and c != 9 and c != 44:
            return j
        j += 1


@njit(cache=True, nogil=True)
def _plain_line(buf, i, digits, scale, big):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The common line in the order ``t x y p``: four plain numbers, the
    time with at most one ``.``, the polarity with at most a ``-``, parsed
    without the checks only odd lines need. Returns (ok, index of the line's
    newline, t, x, y, p); not ok (the caller parses the line the careful
    way) on anything else: another sign, a fraction on a coordinate, 19 or
    more digits, a time past the int64 µs range, a coordinate above 65535,
    a fifth column, a stray character. ``scale`` is ``10 ** digits``
    (``digits >= 0``), ``big`` the largest whole part of a time."""
    j = _blanks(buf, i)
    tv, nd, j = _digits(buf, j)
    if nd == 0 or nd > 18 or tv >= big:
        return False, j, 0, 0, 0, 0
    tv *= scale
    if _at(buf, j) == 46:
        j += 1
        frac = np.int64(0)
        fd = 0
        while fd < digits:
            d = _at(buf, j) - 48
            if d < 0 or d > 9:
                break
            frac = frac * 10 + d
            fd += 1
            j += 1
        for _ in range(digits - fd):
            frac *= 10
        tv += frac
        d = _at(buf, j) - 48
        if 0 <= d and d <= 9:  # the first digit below 1 µs rounds half up
            if d >= 5:
                tv += 1
            while True:
                j += 1
                d = _at(buf, j) - 48
                if d < 0 or d > 9:
                    break
    if not _sep(_at(buf, j)):
        return False, j, 0, 0, 0, 0
    xv, nx, j = _digits(buf, _blanks(buf, j))
    yv, ny, j = _digits(buf, _blanks(buf, j))
    j = _blanks(buf, j)
    neg = _at(buf, j) == 45
    if neg:
        j += 1
    pv, n_p, j = _digits(buf, j)
    if neg:
        pv = -pv
    while True:
        c = _at(buf, j)
        if not _sep(c):
            break
        j += 1
    ok = (c == 10 and 0 < nx <= 18 and 0 < ny <= 18 and n_p == 1 and xv <= 65535 and yv <= 65535
          and (pv == 1 or pv == 0 or pv == -1))
    return ok, j, tv, xv, yv, pv


@njit(cache=True, nogil=True)
def parse_lines(buf, order, digits, state, skip, t, x, y, p, where, bad, fast=True):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Parse complete lines of ``buf`` (uint8) in one pass into the columns
    (t int64 µs, x and y uint16, p int8 ±1; ``where`` gets each line's
    offset unless it is empty). ``order[k]`` is the field (0 t, 1 x, 2 y,
    3 p) of column k; ``digits`` the power of ten from the time unit to µs.
    Time is built from its decimal digits in integer arithmetic: digits below
    1 µs round half up (on the first dropped digit; away from zero for
    negative times). ``state`` (see ``_STATE``) carries the polarity
    convention, set by the first 0 or -1, the largest coordinates and
    whether a time decreased (from the call's second event on: what
    :meth:`EventAssembler.commit` need not check again).

    Bad lines go to ``bad`` (int64, at least one row of three): runs of
    them, each (offset of the first, offset of the last one's line end,
    lines), blank and comment lines inside a run belonging to it. Without
    ``skip`` parsing stops at the first bad line; with it parsing goes on
    past bad lines until a new run finds ``bad`` full, so one pass over the
    bytes parses any input in bounded memory.
    With ``fast``, runs of lines of the plain form ``t x y p`` are parsed by
    :func:`._text_swar.fast_lines` (the same results; False: line by line,
    for tests to compare with), the others line by line: ``_plain_line``
    for the common forms, the careful way for the rest.
    Returns (n_events, bytes consumed, runs in ``bad``, reason of the
    first bad line or 0)."""
    n = 0
    i = 0
    m = buf.shape[0]
    track = where.shape[0] > 0
    runs = 0
    why = 0
    big = np.int64(9223372036854775807)  # the largest whole part of a time in the unit
    scale = np.int64(1)
    for _ in range(max(digits, 0)):
        big //= 10
        scale *= 10
    joined = False  # the next bad line joins the last run (nothing good since)
    plain = digits >= 0 and order[0] == 0 and order[1] == 1 and order[2] == 2  # t x y p
    xmax, ymax = state[1], state[2]  # the largest coordinates of the lines parsed the quick way
    # the last complete line ends at the last newline
    last = m - 1
    while last >= 0 and _at(buf, last) != 10:
        last -= 1
    end = min(last + 1, m - REACH)  # the lines fast_lines may parse end before
    wait = 0  # lines to parse line by line before trying fast_lines again
    backoff = 64
    while i <= last:
        if fast and plain and wait == 0:
            run = i
            if digits == 6:  # each unit its own compiled fast_lines (a literal digits)
                i, k = fast_lines(buf, i, end, 6, big, state, t, x, y, p, n)
            elif digits == 3:
                i, k = fast_lines(buf, i, end, 3, big, state, t, x, y, p, n)
            else:
                i, k = fast_lines(buf, i, end, 0, big, state, t, x, y, p, n)
            if track:  # the run's lines are its events, one a newline
                for e in range(n, k):
                    where[np.uint64(e)] = run
                    while _at(buf, run) != 10:
                        run += 1
                    run += 1
            if k > n:
                joined = False
            if k - n < 4:  # few plain lines here: try again later, later each time
                wait = backoff
                backoff = min(2 * backoff, 1 << 14)
            else:
                backoff = 64
            n = k
            if i > last:
                break
        wait = max(wait - 1, 0)
        start = i
        c = _at(buf, i)
        if c == 35 or c == 37:  # '#' or '%': comment
            while _at(buf, i) != 10:
                i += 1
            i += 1
            continue
        if plain:
            ok, j, tv, xv, yv, pv = _plain_line(buf, i, digits, scale, big)
            if ok and (pv == 1 or state[0] == (1 if pv == 0 else 2) or state[0] == 0):
                if pv != 1 and state[0] == 0:
                    state[0] = 1 if pv == 0 else 2
                joined = False
                k = np.uint64(n)  # unsigned: no negative-index checks
                if n > 0 and tv < t[k - np.uint64(1)]:
                    state[3] = 1
                t[k] = tv
                x[k] = xv
                y[k] = yv
                p[k] = 1 if pv == 1 else -1
                xmax = max(xmax, xv)
                ymax = max(ymax, yv)
                if track:
                    where[k] = start
                n += 1
                i = j + 1
                continue
        col = 0
        code = 0
        tv = np.int64(0)
        xv = np.int64(0)
        yv = np.int64(0)
        pv = np.int64(0)
        while True:
            while i < last and _sep(_at(buf, i)):
                i += 1
            c = _at(buf, i)
            if c == 10:
                break
            neg = False
            if c == 45:
                neg = True
                i += 1
            elif c == 43:
                i += 1
            ip = np.int64(0)
            nd = 0
            over = False  # the whole part does not fit int64 (it stops growing)
            while 48 <= _at(buf, i) <= 57:
                d = _at(buf, i) - 48
                if ip < 922337203685477580 or (ip == 922337203685477580 and d <= 7):
                    ip = ip * 10 + d
                else:
                    over = True
                i += 1
                nd += 1
            frac = np.int64(0)
            fd = 0
            up = 0
            nzfrac = False
            if _at(buf, i) == 46:
                i += 1
                start_frac = i
                while fd < digits and 48 <= _at(buf, i) <= 57:  # the digits down to 1 µs
                    d = _at(buf, i) - 48
                    frac = frac * 10 + d
                    fd += 1
                    i += 1
                if 48 <= _at(buf, i) <= 57:  # the first digit below: rounds
                    up = 1 if _at(buf, i) >= 53 else 0
                    fd += 1
                    i += 1
                    while 48 <= _at(buf, i) <= 57:
                        i += 1
                nd += i - start_frac
                nzfrac = frac != 0 or up != 0
                if not nzfrac:
                    for j in range(start_frac, i):
                        if _at(buf, j) != 48:
                            nzfrac = True
                            break
            c = _at(buf, i)
            if nd == 0 or not (c == 10 or _sep(c)) or col >= 4:
                code = 1
                break
            if order[col] == 0 and (over or ip >= big):  # int64 µs would wrap
                code = 5
                break
            if over:  # a coordinate or polarity far out of range: kept from wrapping
                code = 4 if order[col] == 3 else 3
                break
            f = order[col]
            if f == 0:
                v = ip
                if digits >= 0:
                    for _ in range(digits):
                        v *= 10
                    for _ in range(digits - min(fd, digits)):
                        frac *= 10
                    v += frac + up
                else:  # below 1 µs: rounds half up on the first dropped digit
                    for _ in range(-digits - 1):
                        v //= 10
                    v = v // 10 + (1 if v % 10 >= 5 else 0)
                tv = -v if neg else v
            else:
                if nzfrac:
                    code = 1
                    break
                v = -ip if neg else ip
                if f == 1:
                    xv = v
                elif f == 2:
                    yv = v
                else:
                    pv = v
            col += 1
        if code == 0 and col != 4 and col != 0:
            code = 1
        if code == 0 and col == 4:
            if xv < 0 or yv < 0:
                code = 2
            elif xv > 65535 or yv > 65535:
                code = 3
            elif pv == 0 or pv == -1:
                conv = 1 if pv == 0 else 2
                if state[0] == 0:
                    state[0] = conv
                elif state[0] != conv:
                    code = 4
            elif pv != 1:
                code = 4
        if code:
            if runs == 0:
                why = code
            while _at(buf, i) != 10:
                i += 1
            if joined:
                bad[runs - 1, 1] = i
                bad[runs - 1, 2] += 1
            elif runs == bad.shape[0]:
                state[1], state[2] = max(state[1], xmax), max(state[2], ymax)
                return n, start, runs, why
            else:
                bad[runs, 0] = start
                bad[runs, 1] = i
                bad[runs, 2] = 1
                runs += 1
                joined = True
            if not skip:
                state[1], state[2] = max(state[1], xmax), max(state[2], ymax)
                return n, start, runs, why
            i += 1
            continue
        i += 1  # past the newline
        if col == 0:  # blank line
            continue
        joined = False
        if n > 0 and tv < t[n - 1]:
            state[3] = 1
        t[n] = tv
        x[n] = xv
        y[n] = yv
        p[n] = 1 if pv == 1 else -1
        if xv > state[1]:
            state[1] = xv
        if yv > state[2]:
            state[2] = yv
        if track:
            where[n] = start
        n += 1
    state[1], state[2] = max(state[1], xmax), max(state[2], ymax)
    return n, last + 1, runs, why


#: A number, matched one way only (``\d+\.?\d*`` splits a run of digits between its two parts in as many
#: ways as it has digits, and a line failing after k matched ones then retries all their splits: hours)
_NUM = rb"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
_LINE = re.compile(rb"^\s*" + _NUM + rb"(?:[ \t,]+" + _NUM + rb"){2}[ \t,]+" + _NUM + rb"\s*$")
#: Lines each ending with a newline, of 4 numbers, the 4th a polarity (blanks: whitespace but the newline)
_EVENT_LINES = re.compile(rb"(?:[^\S\n]*" + _NUM + rb"(?:[ \t,]+" + _NUM + rb"){2}[ \t,]+(?:0|[+-]?1)[^\S\n]*\n)+")


def looks_like_events_text(head: bytes) -> bool:
    """First data lines are 4 numeric columns, the 4th a polarity (0/1/-1):
    at once when the head starts with plain event lines (:func:`plain_events_head`,
    the common file), else by :func:`_events_text_lines`."""
    if plain_events_head(head):
        return True  # 20 plain lines: no sample stream's kind line, no header, each of _EVENT_LINES's form
    return _events_text_lines(head)


def _events_text_lines(head: bytes) -> bool:
    """:func:`looks_like_events_text` from the head's first lines, split and
    matched against the form of an event line."""
    if head.startswith(b"# tectum ") and not head.startswith(b"# tectum events"):
        return False  # a sample stream (tectum.sources.files.samples_csv)
    lines = first_lines(head, 21, strip=False)
    if lines and LETTERS.search(lines[0]) and b"," in lines[0]:
        lines = lines[1:]  # CSV header
    if len(lines) < 2:
        return len(lines) == 1 and len(head) < 4096 and bool(_LINE.match(lines[0]))
    return _EVENT_LINES.fullmatch(b"\n".join(lines[:20]) + b"\n") is not None  # one match, not 20


def _header_end(text: bytes) -> int | None:
    """Where the data of a file starting with ``text`` start: after the
    header, the first line that is no comment nor blank, if it has letters;
    else 0. None when ``text`` ends before that line does."""
    k = 0
    nl = text.find(b"\n")
    while nl >= 0 and (text.startswith((b"#", b"%"), k) or not text[k:nl].strip()):
        k, nl = nl + 1, text.find(b"\n", nl + 1)
    if nl < 0:
        return None
    return nl + 1 if LETTERS.search(text[k:nl]) else 0


class _Chunk(NamedTuple):
    """Lines parsed by :meth:`TextSource._parse`: ``n`` events in ``cols``
    from byte ``pos``, a function giving each event's byte offset, the
    bytes consumed, and what the parser saw of them for
    :meth:`EventAssembler.commit` (times never decrease, largest x, largest y)."""

    pos: int
    n: int
    cols: tuple[np.ndarray, ...]
    where: Callable[[], np.ndarray]
    size: int
    bounds: tuple[bool, int, int]


class TextSource(FileSource):
    """Events from ``events.txt``-style text or CSV files.

    Parameters (besides :class:`FileSource`'s)
    ------------------------------------------
    columns:
        Column order, a permutation of ``txyp`` (e.g. ``xytp``); default:
        the header's, else ``txyp``.
    time_unit:
        ``s``, ``ms``, ``us`` or ``ns``; default: the unit the header names,
        else seconds for decimal times (the RPG dataset) and µs for integers.
    companions:
        Read ``imu.txt``, ``groundtruth.txt`` and ``images.txt`` beside an
        ``events.txt`` as IMU, pose and frame streams.

    The path may be a sequence folder of the RPG event-camera dataset
    layout (``events.txt`` and its companions in it): it opens that folder's
    ``events.txt``.
    """

    name = "text"
    format = "text"
    extensions = (".txt", ".csv")
    produces = (Kind.EVENTS, Kind.IMU, Kind.POSES, Kind.FRAMES)

    def __init__(self, path: str, columns: str | None = None, time_unit: str | None = None,
                 companions: bool = True, **kw: Any) -> None:
        super().__init__(_events_file(os.fspath(path)), **kw)
        if columns is not None and sorted(columns) != sorted("txyp"):
            raise ValueError(f"columns must be a permutation of 'txyp', got {columns!r}")
        if time_unit is not None and time_unit not in _UNIT_DIGITS:
            raise ValueError(f"time_unit must be one of {list(_UNIT_DIGITS)}")
        self.columns = columns
        self.time_unit = time_unit
        #: Column order and time unit used, and why (known once reading starts).
        self.layout: TextLayout | None = None
        self.companions = companions

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return looks_like_events_text(head)

    @classmethod
    def sniff_dir(cls, path: str) -> bool:
        """A sequence folder of the RPG event-camera dataset layout: its
        ``events.txt`` (the companions beside it), when that file's head
        reads as events text."""
        try:
            with open(os.path.join(path, EVENTS_FILE), "rb", buffering=0) as f:
                return looks_like_events_text(f.read(4096))
        except OSError:
            return False

    @classmethod
    def kinds_for(cls, arg: str, params: Mapping[str, Any]) -> tuple[Kind, ...]:
        """Events, and the companion streams whose files lie beside ``arg``."""
        if not params.get("companions", True):
            return (Kind.EVENTS,)
        folder = os.path.dirname(os.path.abspath(_events_file(arg.split("?", 1)[0])))
        beside = {Kind.IMU: "imu.txt", Kind.POSES: "groundtruth.txt", Kind.FRAMES: "images.txt"}
        return (Kind.EVENTS, *(k for k, n in beside.items() if os.path.isfile(os.path.join(folder, n))))

    def _parse(self, columns: Callable[[int], tuple[np.ndarray, ...]], state: np.ndarray) -> Iterator[_Chunk]:
        """The file's lines parsed a chunk at a time: the events go into the
        columns ``columns(capacity)`` gives (t, x, y, p, from index 0). Bad
        lines raise, or with ``skip_bad`` are counted and passed over in the
        same pass: time is linear and memory bounded by the chunk size
        whatever the input. Chunks are read into pooled buffers (a fresh
        one costs a page fault per 4 KiB); a read coming short is the last,
        and a last line without its newline is parsed after it, with one."""
        f = self._open(buffering=0)  # chunks read straight into the pooled buffers
        size = self.chunk_bytes
        buf = byte_buffer(size + 1)  # room for a newline after a last line without one
        n = read_full(f, buf[:size])  # the first chunk, which holds the head
        head = bytes(buf[:min(n, 1 << 16)])
        if n == size < 1 << 16:  # small chunks: the head reads on
            head += f.read((1 << 16) - n)
            f.seek(n)
        if not head or head.isspace():
            self._fail("empty file: no events" if not head else "empty file: only blank lines", 0)
        self.layout = lay = text_layout(head, self.columns, self.time_unit)
        order = np.array(["txyp".index(c) for c in lay.columns], np.int64)
        digits = _UNIT_DIGITS[lay.time_unit]
        pos = 0
        rest = buf[:0]
        first = True
        while True:
            if not first:
                size = max(self.chunk_bytes, rest.shape[0])  # a long line: reads double, time stays linear
                buf = byte_buffer(rest.shape[0] + size + 1)
                buf[:rest.shape[0]] = rest
                n = rest.shape[0] + read_full(f, buf[rest.shape[0]:rest.shape[0] + size])
            eof = n - rest.shape[0] < size  # read_full stops short only at the end of the file
            start = 0
            if first:  # the header: the first line that is no comment nor blank, if it has letters
                first = False
                found = _header_end(head[:n])  # head holds more than the chunk when chunks are small
                if found is None and n > len(head):  # the first 64 kB do not decide: the whole chunk
                    found = _header_end(bytes(buf[:n]))
                start = found or 0
            pos += start
            at = yield from self._lines(buf[start:n], pos, columns, state, order, digits)
            rest = buf[start + at:n]
            pos += at
            if at == 0 and n - start > self.chunk_bytes + (1 << 20):
                self._fail("no line end in the last MiB: not a text event file", pos)
            if eof:
                if rest.shape[0] and not bytes(rest).isspace():  # the last line, without a newline
                    buf[n] = 10
                    yield from self._lines(buf[start + at:n + 1], pos, columns, state, order, digits)
                return

    def _lines(self, arr: np.ndarray, pos: int, columns: Callable[[int], tuple[np.ndarray, ...]], state: np.ndarray,
               order: np.ndarray, digits: int) -> Generator[_Chunk, None, int]:
        """The complete lines of ``arr`` (the file's bytes from ``pos``)
        parsed as :meth:`_parse` says; returns the bytes they take."""
        runs = np.empty((_RUNS, 3), np.int64)
        at = 0
        while True:
            view = arr[at:]
            cols = columns(view.shape[0] // 8 + 2)  # a line has at least 8 bytes ("0 0 0 0\n")
            before = state.copy()
            k, used, nruns, reason = parse_lines(view, order, digits, state, self.skip_bad, *cols, _NO_WHERE, runs)
            if nruns and not self.skip_bad:
                a, b = int(runs[0, 0]), int(runs[0, 1])
                self._fail(f"{_REASONS[reason]}: {bytes(view[a:b])[:80]!r}", pos + at + a)
            for a, b, c in runs[:nruns].tolist():
                self._note_skip(pos + at + a, pos + at + b, c)
            yield _Chunk(pos + at, k, cols, functools.partial(self._where, view[:used], before, pos + at), used,
                         (not state[3], int(state[1]), int(state[2])))  # the state's so far: bounds of these
            at += used
            if nruns < _RUNS:
                return at

    def _where(self, view: np.ndarray, state: np.ndarray, pos: int) -> np.ndarray:
        """The byte offsets of the events of ``view`` (parsed again from
        ``state``): asked for only when something is wrong."""
        lay = self.layout
        assert lay is not None
        out = [np.empty(view.shape[0] // 8 + 2, d) for d in (*_DTYPES, np.int64)]
        order = np.array(["txyp".index(c) for c in lay.columns], np.int64)
        k, *_ = parse_lines(view, order, _UNIT_DIGITS[lay.time_unit], state.copy(), self.skip_bad, *out,
                            np.empty((_RUNS, 3), np.int64))
        return pos + out[4][:k]

    def info(self) -> dict[str, Any]:
        """:meth:`FileSource.info` with the time unit and column order used,
        each with its reason (``"us (the times are integers: µs)"``)."""
        out = super().info()
        if self.layout is not None:
            out["time_unit"] = f"{self.layout.time_unit} ({self.layout.time_unit_from})"
            out["columns"] = f"{self.layout.columns} ({self.layout.columns_from})"
        return out

    def _sensor_guess(self) -> tuple[int, int] | None:
        imgs = self._images()
        if imgs:
            import cv2

            img = cv2.imread(imgs[0][1], cv2.IMREAD_UNCHANGED)
            if img is not None:
                return self._sensor_guessed((int(img.shape[1]), int(img.shape[0])), FROM_IMAGES)
        return None

    def _beside(self, name: str) -> str | None:
        if not self.companions:
            return None
        q = os.path.join(os.path.dirname(os.path.abspath(self.path)), name)
        return q if os.path.isfile(q) else None

    def _images(self) -> list[tuple[int, str]]:
        q = self._beside("images.txt")
        if q is None:
            return []
        out = []
        base = os.path.dirname(q)
        with open(q, "rb") as f:
            for line in f:
                parts = line.split()
                if len(parts) >= 2 and not line.startswith(b"#"):
                    out.append((_to_us(parts[0]), os.path.join(base, parts[1].decode())))
        return out

    def _packets(self) -> Iterator[Packet]:
        """The events, with the companion streams (IMU, poses, frames)
        interleaved in time: each up to an events packet's end before it."""
        return interleave(self._event_packets(), self._companions())

    def _event_packets(self) -> Iterator[Packet]:
        """Without a sensor size from the option or an image, the extent of
        the coordinates: a small file (up to ``_HOLD`` events and
        ``_HOLD_BYTES`` of text) is parsed once and held, a larger one is
        read twice (bounded memory)."""
        sensor = self._sensor(None) or self._sensor_guess()
        state = np.zeros(_STATE, np.int64)
        held: list[_Chunk] = []
        if sensor is None:
            asm = EventAssembler(self, (1, 1))  # its sensor set once the pass has found the extent
            events = size = 0
            for c in self._parse(asm.reserve, state):
                if held:  # the last chunk stays in the assembler's reservation, the others shrink to copies
                    held[-1] = held[-1]._replace(cols=tuple(a[:held[-1].n].copy() for a in held[-1].cols))
                held.append(c)
                events += c.n
                size += c.size
                if events > _HOLD or size > _HOLD_BYTES:  # too much to hold: a pass for the extent only
                    held = []
                    for _ in self._parse(lambda n: _POOL.take(n), state):
                        pass
                    self.skipped_events, self.skipped_ranges = 0, []  # counted by the pass that keeps the events
                    break
            self.close()
            sensor = self._sensor_guessed((int(state[1]) + 1, int(state[2]) + 1))
            state[:] = 0
            if len(held) == 1:  # a file of one chunk: committed from the reservation it was parsed into, no copy
                asm.sensor = sensor
                yield from asm.commit(held[0].n, held[0].pos, held[0].where, held[0].bounds)
                yield from asm.finish()
                return
        asm = EventAssembler(self, sensor)
        if held:
            for c in held:
                for a, b in zip(asm.reserve(c.n), c.cols):
                    a[:] = b[:c.n]
                yield from asm.commit(c.n, c.pos, c.where, c.bounds)
        else:
            for c in self._parse(asm.reserve, state):
                yield from asm.commit(c.n, c.pos, c.where, c.bounds)
                if asm.past_end():
                    break
        yield from asm.finish()

    def _companions(self) -> list[Iterator[Packet]]:
        """The companion streams beside ``events.txt``, each an iterator of
        packets in time order (images are read when their turn comes)."""
        streams: list[Iterator[Packet]] = []
        q = self._beside("imu.txt")
        a = _table(q, 7) if q else None
        if a is not None:
            streams.append(iter([ImuPacket(a[0], accel=a[1][:, 0:3], gyro=a[1][:, 3:6])]))
        q = self._beside("groundtruth.txt")
        a = _table(q, 8) if q else None
        if a is not None:
            streams.append(iter([PosePacket(a[0], position=a[1][:, 0:3], orientation=a[1][:, 3:7])]))
        imgs = self._images()
        if imgs:
            streams.append(self._frames(imgs))
        return streams

    @staticmethod
    def _frames(imgs: list[tuple[int, str]]) -> Iterator[Packet]:
        import cv2

        for k, (t, name) in enumerate(imgs):
            img = cv2.imread(name, cv2.IMREAD_UNCHANGED)
            if img is None:
                continue
            end = imgs[k + 1][0] if k + 1 < len(imgs) else t + 1
            yield FramePacket(np.array([t], np.int64), images=img[None], t_start=t, t_end=max(end, t + 1))


def _events_file(path: str) -> str:
    """``path``, or the :data:`EVENTS_FILE` inside it when it is a folder
    (a sequence of the RPG event-camera dataset)."""
    return os.path.join(path, EVENTS_FILE) if os.path.isdir(path) else path


def _to_us(s: bytes) -> int:
    arr = np.frombuffer(s + b" 0 0 1\n", np.uint8)
    out = [np.empty(1, d) for d in (*_DTYPES, np.int64)]
    n, *_ = parse_lines(arr, np.arange(4), 6, np.zeros(_STATE, np.int64), False, *out, np.empty((1, 3), np.int64))
    return int(out[0][0]) if n else 0


def _table(path: str, ncols: int) -> tuple[np.ndarray, np.ndarray] | None:
    rows = []
    with open(path, "rb") as f:
        for line in f:
            parts = line.split()
            if len(parts) == ncols and not line.startswith(b"#"):
                rows.append(parts)
    if not rows:
        return None
    t = np.array([_to_us(r[0]) for r in rows], np.int64)
    v = np.array([[float(c) for c in r[1:]] for r in rows], np.float64)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]
