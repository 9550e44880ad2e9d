"""What every file source shares: the base class, header parsing and the
assembler that turns decoded chunks into packets obeying the packet contract.

Conventions (all formats)
-------------------------
* Time ``t`` is int64 µs, *absolute*: header offsets (``% t0``, DSEC
  ``t_offset``) are added and reported in :attr:`FileSource.t0_offset`;
  32-bit and 24-bit timestamp wrap-arounds are unrolled.
* ``x``/``y`` in pixels with the origin at the **top-left** corner, ``p`` in
  {+1 (ON, brighter), -1 (OFF)}: formats with other conventions (jAER AEDAT 2.0
  bottom-left y, DVS128 mirrored x, 0/1 polarity) are converted at the edge.
* Bad input raises :class:`tectum.FormatError` naming the file and the byte
  offset; with ``skip_bad=True`` the bad parts are dropped instead, counted in
  :attr:`FileSource.skipped_events` and listed (byte ranges) in
  :attr:`FileSource.skipped_ranges`.
"""

from __future__ import annotations

import functools
import os
import re
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any, ClassVar, NoReturn, TypeVar

import numpy as np

from tectum import EventPacket, FormatError, Kind, Packet, SamplePacket, Source

from . import _kernels as K

__all__ = ["FileSource", "EventAssembler", "SampleTiler", "ColumnPool", "parse_size", "byte_buffer",
           "read_full", "read_array", "read_prefixed_header", "sensor_from_header", "thread_count", "workers",
           "DEFAULT_CHUNK_BYTES", "FROM_OPTION", "FROM_EXTENT"]

DEFAULT_CHUNK_BYTES = 1 << 22
#: :attr:`FileSource.sensor_from` of a size given by the ``sensor`` option
FROM_OPTION = "the sensor option"
#: :attr:`FileSource.sensor_from` of a size read off the coordinates
FROM_EXTENT = "the extent of the coordinates"

#: Prophesee sensors whose RAW headers give no geometry, by ``system_ID``
#: (Metavision SDK system ids) or plugin name fragment.
_PROPHESEE_GEOMETRY = {
    "system_id": {"21": (640, 480), "28": (640, 480), "30": (640, 480), "31": (640, 480), "35": (1280, 720),
                  "39": (1280, 720), "40": (320, 320), "47": (1280, 720), "48": (1280, 720), "49": (1280, 720),
                  "52": (320, 320), "53": (320, 320)},
    "plugin": {"gen3": (640, 480), "gen31": (640, 480), "gen41": (1280, 720), "imx636": (1280, 720),
               "imx646": (1280, 720), "genx320": (320, 320), "gen4": (1280, 720)},
}


def parse_size(s: str | tuple[int, int] | None) -> tuple[int, int] | None:
    """``"640x480"`` (or a pair) -> ``(640, 480)``; None stays None."""
    if s is None or s == "":
        return None
    if isinstance(s, tuple):
        return int(s[0]), int(s[1])
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", str(s))
    if not m:
        raise ValueError(f"sensor size {s!r} is not WIDTHxHEIGHT")
    return int(m.group(1)), int(m.group(2))


def read_prefixed_header(f: Any, prefix: bytes, path: str, limit: int = 1 << 20) -> tuple[list[str], int]:
    """Read the text header lines starting with ``prefix`` at the top of ``f``.

    Returns the lines (prefix and line end stripped) and the byte offset of
    the first byte after the header, where ``f`` is left. A ``% end`` line
    closes the header. The bytes are read in blocks (4 KiB, then doubling)
    and split here, so ``f`` may be unbuffered (a reader that reads big
    chunks into its own buffers: a buffered file's terminal test and seek
    cost system calls) at a read or two for the usual header.
    """
    f.seek(0)
    data = b""
    eof = False

    def want(n: int) -> bytes:
        """``data`` holding at least ``n`` bytes, or all the file's."""
        nonlocal data, eof
        while len(data) < n and not eof:
            got = f.read(max(4096, len(data)))
            eof = not got
            data += got or b""
        return data

    lines: list[str] = []
    pos = 0
    while True:
        if want(pos + 1)[pos:pos + 1] != prefix:
            break
        nl = data.find(b"\n", pos + 1, pos + 1 + limit)
        while nl < 0 and not eof and len(data) < pos + 1 + limit:  # the line goes on past the bytes read
            want(len(data) + 1)
            nl = data.find(b"\n", pos + 1, pos + 1 + limit)
        if nl < 0:  # no line end within ``limit`` bytes (``readline(limit)`` would stop there) or before the end
            raise FormatError("header line is not terminated (truncated or not a text header)", path=path,
                              offset=pos)
        rest = data[pos + 1:nl + 1]
        pos = nl + 1
        if pos > limit:
            raise FormatError(f"header longer than {limit} bytes", path=path, offset=pos)
        line = rest.rstrip(b"\r\n").decode("latin1").strip()
        lines.append(line)
        if prefix == b"%" and line.lower() == "end":
            break
    f.seek(pos)
    return lines, pos


def header_dict(lines: list[str]) -> dict[str, str]:
    """``key value`` lines -> lower-cased keys mapping to values."""
    out: dict[str, str] = {}
    for line in lines:
        parts = line.split(None, 1)
        if parts:
            out.setdefault(parts[0].lower().rstrip(":"), parts[1].strip() if len(parts) > 1 else "")
    return out


def sensor_from_header(h: dict[str, str]) -> tuple[int, int] | None:
    """Geometry from a Prophesee header: ``geometry WxH``, ``width``/``height``,
    or a known sensor (``system_ID``/``plugin_name``)."""
    if "geometry" in h:
        try:
            return parse_size(h["geometry"])
        except ValueError:
            return None
    if "width" in h and "height" in h:
        try:
            return int(h["width"]), int(h["height"])
        except ValueError:
            return None
    plugin = h.get("plugin_name", "").lower()
    for frag, size in sorted(_PROPHESEE_GEOMETRY["plugin"].items(), key=lambda kv: -len(kv[0])):
        if frag in plugin:
            return size
    return _PROPHESEE_GEOMETRY["system_id"].get(h.get("system_id", ""))


def t0_from_header(h: dict[str, str], path: str) -> int:
    """The ``% t0 N`` (µs) time offset of a header, 0 when absent."""
    for key in ("t0", "t_offset", "time_offset"):
        if key in h:
            try:
                return int(h[key].split()[0])
            except (ValueError, IndexError):
                raise FormatError(f"header {key!r} is not an integer µs: {h[key]!r}", path=path) from None
    return 0


#: The size of a huge page (x86-64, arm64 with 4 KiB pages), bytes.
_HUGE_PAGE = 1 << 21
#: Column sets of at least this many bytes are carved from one block aligned to a huge page.
HUGE_SET = 2 * _HUGE_PAGE


class ColumnPool:
    """Reusable ``(t, x, y, p)`` output columns for decoders.

    Fresh memory costs page faults (here ~2 GB/s, slower than decoding), so
    decoders write into column sets taken from this pool. A set is handed
    out again only when nothing else refers to it: packets hold views of a
    set, and a view keeps its base array alive, so a set whose arrays are
    referenced by the pool alone belongs to no live packet (or view, or
    copy of a view) and can be overwritten. At most ``max_sets`` free sets
    of at most ``max_bytes`` each are kept; the others are left to the
    garbage collector.
    """

    def __init__(self, max_sets: int = 4, max_bytes: int = 1 << 25,
                 dtypes: tuple[Any, ...] = (np.int64, np.uint16, np.uint16, np.int8)) -> None:
        self.max_sets = max_sets
        self.max_bytes = max_bytes
        self.dtypes = tuple(np.dtype(d) for d in dtypes)
        self._sets: list[tuple[np.ndarray, ...]] = []
        self._lock = threading.Lock()

    def _is_free(self, k: int) -> bool:
        # 2 references each when only the pool holds them: the container and getrefcount's argument
        if sys.getrefcount(self._sets[k]) != 2:
            return False
        cols = self._sets[k]
        for j in range(len(cols)):  # a loop, not all() of a generator: ~1 us less a packet
            if sys.getrefcount(cols[j]) != 2:
                return False
        # a set carved from one block: a view of a column (a packet's) refers to the block, not to
        # the column; free when the block's references are its columns', this name's and the argument's
        block = cols[0].base
        return block is None or sys.getrefcount(block) == len(cols) + 2

    def _new_set(self, n: int) -> tuple[np.ndarray, ...]:
        """Columns for ``n`` events: separate arrays, or, from
        :data:`HUGE_SET` bytes on, slices of one block aligned to 2 MiB,
        which the OS backs with huge pages (NumPy asks for them for
        allocations of 4 MiB and more): a decoder writing the columns then
        misses the TLB once per 2 MiB, not per 4 KiB page (~6 % of a DAT
        decode's CPU, cold or warm)."""
        n = max(n, 1)
        room = [-(-n * d.itemsize // 64) * 64 for d in self.dtypes]  # each column from a cache line
        if sum(room) < HUGE_SET:
            return tuple(np.empty(n, d) for d in self.dtypes)
        block = np.empty(sum(room) + _HUGE_PAGE, np.uint8)
        at = -block.ctypes.data % _HUGE_PAGE
        cols = []
        for size, d in zip(room, self.dtypes):
            cols.append(block[at:at + n * d.itemsize].view(d))
            at += size
        return tuple(cols)

    def take(self, n: int) -> tuple[np.ndarray, ...]:
        """Columns (of ``dtypes``, by default int64, uint16, uint16, int8: t, x,
        y, p) holding at least ``n`` events,
        owned by the caller until it drops every reference to them and to
        views of them."""
        with self._lock:
            best, size = -1, 0
            for k in range(len(self._sets)):
                m = self._sets[k][0].shape[0]
                # the size first, then whether it is free: a set no smaller than the best so far is not
                # looked at (a DAT decode in a process whose pool also holds three bigger sets from
                # other files: 3.4 -> 2.4 us a packet)
                if m >= n and (best < 0 or m < size) and self._is_free(k):
                    best, size = k, m
            if best >= 0:
                return self._sets[best]  # referenced by the caller before the lock is released
            cols = self._new_set(n)
            if n * sum(d.itemsize for d in self.dtypes) <= self.max_bytes:
                self._sets = (self._sets + [cols])[-self.max_sets:]
            return cols


#: The process's column pool (shared by every file source).
POOL = ColumnPool()

#: Reusable byte buffers (uint8), on the same terms as :data:`POOL`.
BUFFERS = ColumnPool(max_sets=4, max_bytes=1 << 24, dtypes=(np.uint8,))


def byte_buffer(n: int) -> np.ndarray:
    """A uint8 array of ``n`` bytes to read or decompress into, taken from
    :data:`BUFFERS` (a fresh one would cost a page fault per 4 KiB)."""
    return BUFFERS.take(n)[0][:n]


def read_full(f: Any, view: np.ndarray) -> int:
    """Fill ``view`` from ``f``, reading again while the OS returns less:
    the bytes read, fewer than asked only at the end of the file."""
    have = 0
    while have < view.shape[0]:
        got = f.readinto(view[have:])
        if not got:
            break
        have += got
    return have


def read_array(f: Any, n: int, dtype: Any) -> np.ndarray:
    """Up to ``n`` items of ``dtype`` read from ``f`` (:func:`read_full`:
    again while the OS returns less, as an unbuffered file may), whole
    items only: fewer only at the end of the file."""
    a = np.empty(n, dtype)
    return a[:read_full(f, a.view(np.uint8)) // a.itemsize]


def thread_count(threads: int) -> int:
    """A ``threads`` option: 0 is one per CPU, at most 4 (what :func:`workers`
    serves, this thread included)."""
    if threads < 0:
        raise ValueError("threads must be >= 0 (0: one per CPU, at most 4)")
    return min(threads or (os.cpu_count() or 1), 4)


@functools.cache
def workers() -> ThreadPoolExecutor:
    """Threads the file formats share for work that releases the GIL
    (compiled kernels, compression), made on first use (and again in a
    forked child, where the parent's threads do not exist)."""
    return ThreadPoolExecutor(3, thread_name_prefix="tectum-files")


def _after_fork_in_child() -> None:
    """A forked child (e.g. a DataLoader worker) gets new worker threads and
    new pool locks: the parent's threads are gone and a lock held by one of
    them at the fork would never be released."""
    workers.cache_clear()
    for pool in (POOL, BUFFERS):
        pool._lock = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


#: Events of room a reservation keeps for the held-back run, at least, and
#: the step its size is rounded up to (see :func:`_room`)
_CARRY_ROOM = 1024
_ROOM_STEP = 4096


def _room(k: int, n: int) -> int:
    """The size of column set to take for ``k`` held-back and ``n`` new
    events: ``n`` plus room for a run of up to :data:`_CARRY_ROOM`, rounded
    up to :data:`_ROOM_STEP`, so chunks of one size take sets of one size
    whatever their held-back runs, and a consumer that lets each packet go
    before the next gets the same set back every chunk (still in the cache)
    instead of alternating between sets a few events apart."""
    return -(-(n + max(k, _CARRY_ROOM)) // _ROOM_STEP) * _ROOM_STEP


class EventAssembler:
    """Turn decoded chunks (arrays) into contract-abiding packets.

    Adds the time offset, checks order and geometry (raising or dropping,
    per ``skip_bad``), keeps runs of equal timestamps in one packet (the last
    run of a chunk waits for the next chunk), clips to ``[t_min, t_max)``
    and makes the intervals tile time without gaps.

    With ``skip_bad``, a time out of order is resolved by dropping the fewest
    events that leave the rest in order (:func:`._kernels.longest_rise`): a
    corrupt time, too high or too low, costs its own event, not everything
    after it. To judge a too-high time by the events after it, the last
    :attr:`LOOKAHEAD` events of each chunk wait for the next one (a packet
    then ends just after its last event).
    """

    #: Events held back for judging with the next chunk (``skip_bad``): a
    #: run of up to this many bad times at a chunk's end is recognised.
    LOOKAHEAD = 4096

    def __init__(self, src: FileSource, sensor: tuple[int, int], *, offset: int = 0,
                 check_geometry: bool = True) -> None:
        self.src = src
        self.sensor = sensor
        self.offset = offset
        self.check_geometry = check_geometry
        self.last_t: int | None = None
        self.next_start: int | None = src.t_start_us
        self.carry: tuple[np.ndarray, ...] | None = None
        self.floor: int | None = None  # skip_bad: events below (emitted time) are dropped
        self.carry_from = 0  # skip_bad: byte offset of the chunk the oldest held-back event came from
        self.count = 0
        self._cols: tuple[np.ndarray, ...] | None = None
        self._k = 0
        # resume_at: the pooled set of the last reserve, where its new events start, where the columns
        # of the next commit start in it and where the committed events end
        self._set: tuple[np.ndarray, ...] | None = None
        self._origin = self._from = self._end = 0

    def past_end(self) -> bool:
        """True once events reached the source's ``t_end_us`` (stop decoding)."""
        end = self.src.t_end_us
        return end is not None and self.last_t is not None and self.last_t >= end

    # -- zero-copy path: decode straight into pooled columns -------------------
    def reserve(self, n: int) -> tuple[np.ndarray, ...]:
        """Columns ``(t, x, y, p)`` with room for ``n`` new events, for a
        decoder to fill from index 0 before calling :meth:`commit`. They are
        views into a pooled set that starts with the held-back run, so the
        packet is built without copying the chunk."""
        ct = self.carry
        k = 0 if ct is None else ct[0].shape[0]
        self._set = None  # the last set is free again once its packets are gone
        cols = POOL.take(_room(k, n))
        if ct is not None:
            for a, c in zip(cols, ct):
                a[:k] = c
            self.carry = None
        self._cols, self._k = cols, k
        self._set, self._origin, self._from = cols, k, 0
        t, x, y, p = cols  # unpacked, not a generator: ~1 us less a chunk
        return t[k:k + n], x[k:k + n], y[k:k + n], p[k:k + n]

    def resume_at(self, i: int) -> bool:
        """After :meth:`commit`: make the events a decoder wrote from index
        ``i`` of the columns the last :meth:`reserve` returned (past the
        committed ones) the next commit's, without moving them: the
        held-back run is copied just before them. False, and nothing done,
        when it does not fit between the committed events and ``i`` (then
        :meth:`reserve` anew). Lets threads decode into stretches of one
        reservation, each committed in turn."""
        cols = self._set
        ct = self.carry
        c = 0 if ct is None else ct[0].shape[0]
        s = self._origin + i
        if cols is None or self._cols is not None or s - c < self._end:
            return False
        if ct is not None:
            for a, h in zip(cols, ct):
                a[s - c:s] = h
            self.carry = None
        self._cols, self._k, self._from = tuple(a[s - c:] for a in cols), c, s - c
        return True

    def commit(self, n: int, byte_offset: int = 0,
               where: Callable[[], np.ndarray] | None = None,
               bounds: tuple[bool, int, int] | None = None) -> list[EventPacket]:
        """The decoder wrote ``n`` events (``t`` before the offset) into the
        columns of :meth:`reserve`: the packets they complete. Checks, errors
        and ``skip_bad`` behave as in :meth:`push`. ``bounds``: what the
        decoder found while writing them, (times never decrease, largest x,
        largest y), sparing a pass over the columns when they show nothing
        wrong (a decoder may say False whenever unsure)."""
        cols, k = self._cols, self._k
        assert cols is not None, "commit() without reserve()"
        self._cols = None
        self._end = self._from + k + n
        t, x, y, p = cols
        if n == 0:
            if k:
                self.carry = tuple(a[:k].copy() for a in cols)
            return []
        w, h = self.sensor if self.check_geometry else (1 << 30, 1 << 30)
        prev = self.last_t if self.last_t is not None else -(1 << 62)
        if bounds is not None and bounds[0] and bounds[1] < w and bounds[2] < h and int(t[k]) + self.offset >= prev:
            if self.offset:
                t[k:k + n] += self.offset
        elif K.check_events(t, x, y, k, k + n, self.offset, prev, w, h) >= 0:
            # something is wrong: the general path reports or drops it
            self.carry = tuple(a[:k].copy() for a in cols) if k else None
            s = slice(k, k + n)
            return self.push(t[s].copy(), x[s].copy(), y[s].copy(), p[s].copy(), byte_offset, where)
        self.last_t = int(t[k + n - 1])
        a, m = 0, k + n
        lo, hi = self.src.t_start_us, self.src.t_end_us
        if lo is not None and k == 0:
            a = int(np.searchsorted(t[:m], lo, side="left"))
        if hi is not None:
            m = k + int(np.searchsorted(t[k:m], hi, side="left"))
        if m <= a:
            return []
        return self._split(t, x, y, p, a, m, k, byte_offset, pooled=True)

    def _split(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, a: int, m: int, old: int,
               byte_offset: int, pooled: bool = False) -> list[EventPacket]:
        """Events ``[a, m)``: a packet of the complete ones, the rest held
        back (the last run of equal times; with ``skip_bad``, at least the
        last :attr:`LOOKAHEAD` events, and the packet ends after its last).
        ``pooled``: the columns are a set of :data:`POOL` (see :meth:`_packet`)."""
        skip = self.src.skip_bad
        # the method, not np.searchsorted (~1.5 us less a packet)
        i = a + int(t[a:m].searchsorted(t[max(a, m - self.LOOKAHEAD) if skip else m - 1], "left"))
        self.carry = (t[i:m].copy(), x[i:m].copy(), y[i:m].copy(), p[i:m].copy())
        if i >= old:  # the first ``old`` events were held back before, from an earlier chunk
            self.carry_from = byte_offset
        if i == a:
            return []
        end = int(t[i - 1]) + 1 if skip else int(t[i])
        if skip:
            self.floor = end
        return [self._packet(t[a:i], x[a:i], y[a:i], p[a:i], end, pooled)]

    def push(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray,
             byte_offset: int = 0, where: Any = None) -> list[EventPacket]:
        """Add decoded events (``t`` before the offset); ``where`` maps each
        event to its byte offset in the file (for error messages), or is a
        function building that map (called only when something is wrong)."""
        if self.offset:
            t = t + self.offset
        old = 0
        if self.src.skip_bad:
            t, x, y, p, old = self._resync(t, x, y, p, byte_offset, where)
        else:
            t, x, y, p = self._check(t, x, y, p, byte_offset, where)
        if t.shape[0] == 0:
            return []
        t, x, y, p = self._clip(t, x, y, p)
        if self.carry is not None:
            old = self.carry[0].shape[0]
            t, x, y, p = (np.concatenate(a) for a in zip(self.carry, (t, x, y, p)))
            self.carry = None
        if t.shape[0] == 0:
            return []
        return self._split(t, x, y, p, 0, t.shape[0], old, byte_offset)

    def _resync(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, byte_offset: int,
                where: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
        """``skip_bad``: the held-back events and these, less the fewest that
        break time order or lie outside the sensor (counted as skipped), and
        how many of those kept were held back."""
        k = 0
        if self.carry is not None:  # judged again, with the events after them
            k = self.carry[0].shape[0]
            t, x, y, p = (np.concatenate(a) for a in zip(self.carry, (t, x, y, p)))
            self.carry = None
        n = t.shape[0]
        ok = (x < self.sensor[0]) & (y < self.sensor[1]) if self.check_geometry else np.ones(n, np.bool_)
        keep = np.empty(n, np.bool_)
        kept = K.longest_rise(t, ok, -(1 << 62) if self.floor is None else self.floor, keep)
        if kept < n:
            bad = np.flatnonzero(~keep)
            if callable(where):
                where = where()
            new = bad[bad >= k] - k
            at = np.asarray(where)[new] if where is not None else np.full(new.shape[0], byte_offset, np.int64)
            lo = [self.carry_from] if new.shape[0] < bad.shape[0] else []  # held back: in an earlier chunk
            hi = [byte_offset - 1] if lo else []
            self.src._note_skip(min(lo + at.tolist()), max(hi + at.tolist()), int(bad.shape[0]))
            t, x, y, p = t[keep], x[keep], y[keep], p[keep]
        if t.shape[0]:
            self.last_t = int(t[-1])
        return t, x, y, p, int(keep[:k].sum())

    def finish(self) -> list[EventPacket]:
        """End of file: the held-back run, or an empty packet for the range."""
        out = []
        end = self.src.t_end_us
        if self.carry is not None and self.carry[0].shape[0]:
            t, x, y, p = self.carry
            self.carry = None
            out.append(self._packet(t, x, y, p, end if end is not None else int(t[-1]) + 1))
        elif self.next_start is not None and end is not None and end > self.next_start:
            out.append(EventPacket.empty(self.sensor, self.next_start, end))
            self.next_start = end
        return out

    def _packet(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, t_end: int,
                pooled: bool = False) -> EventPacket:
        """The packet of these events up to ``t_end``; ``pooled``: the
        arrays are equal slices of one :data:`POOL` set's columns (1-D,
        contiguous, of the packet's dtypes), so only the sensor and interval
        are checked before building it without the constructor's checks."""
        start = self.next_start if self.next_start is not None else int(t[0])
        self.next_start = t_end
        n = t.shape[0]
        self.count += n
        w, h = self.sensor
        framed = type(w) is int and type(h) is int and 0 < w <= 65536 and 0 < h <= 65536 and start <= t_end
        if pooled and framed:
            return EventPacket._trusted(t, x, y, p, self.sensor, start, t_end, {})
        t, x, y, p = (np.ascontiguousarray(t, np.int64), np.ascontiguousarray(x, np.uint16),
                      np.ascontiguousarray(y, np.uint16), np.ascontiguousarray(p, np.int8))
        if framed and t.ndim == x.ndim == y.ndim == p.ndim == 1 and x.shape[0] == n and y.shape[0] == n \
                and p.shape[0] == n:
            # what the constructor checks holds: built without its checks (~10 us less a packet)
            return EventPacket._trusted(t, x, y, p, self.sensor, start, t_end, {})
        return EventPacket(t, x, y, p, sensor=self.sensor, t_start=start, t_end=t_end)

    def _clip(self, t: np.ndarray, *rest: np.ndarray) -> tuple[np.ndarray, ...]:
        lo, hi = self.src.t_start_us, self.src.t_end_us
        if lo is None and hi is None:
            return (t, *rest)
        i = 0 if lo is None else int(np.searchsorted(t, lo, side="left"))
        j = t.shape[0] if hi is None else int(np.searchsorted(t, hi, side="left"))
        return tuple(a[i:j] for a in (t, *rest))

    def _check(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, byte_offset: int,
               where: Any) -> tuple[np.ndarray, ...]:
        n = t.shape[0]
        if n == 0:
            return t, x, y, p
        prev = self.last_t if self.last_t is not None else int(t[0])
        dec = (t[0] < prev) or (n > 1 and bool(np.any(t[1:] < t[:-1])))
        bad = None
        if dec:
            run = np.maximum.accumulate(t)
            if prev > run[0]:
                run = np.maximum(run, prev)
            bad = t < run
        if self.check_geometry:
            w, h = self.sensor
            geo = (x >= w) | (y >= h)
            if geo.any():
                bad = geo if bad is None else (bad | geo)
        if bad is None:
            self.last_t = int(t[-1])
            return t, x, y, p
        i = int(np.flatnonzero(bad)[0])
        if callable(where):
            where = where()
        at = int(where[i]) if where is not None else byte_offset
        w, h = self.sensor
        if x[i] >= w or y[i] >= h:
            msg = f"event ({int(x[i])}, {int(y[i])}) lies outside the {w}x{h} sensor"
        else:
            before = prev if i == 0 else int(np.max(t[:i]))
            msg = f"timestamp decreases: {int(t[i])} µs after {before} µs"
        raise FormatError(msg, path=self.src.path, offset=at)


def record_offsets(at: int, size: int, rows: int | np.ndarray) -> np.ndarray:
    """Byte offsets of records of ``size`` bytes from byte ``at``: of the
    first ``rows`` records, or of the records indexed by ``rows``. With
    ``functools.partial``, the lazy ``where`` of :meth:`EventAssembler.commit`."""
    idx = np.arange(rows, dtype=np.int64) if isinstance(rows, int) else rows
    return at + size * idx


S = TypeVar("S", bound=SamplePacket)


class SampleTiler:
    """Turn decoded samples (frames, IMU, triggers...) of several streams into
    packets: clip to the source's time range, drop (``skip_bad``) or raise on
    samples going back in time, and tile each stream's intervals without gaps."""

    def __init__(self, src: FileSource) -> None:
        self.src = src
        self.ends: dict[Any, int] = {}

    def push(self, cls: type[S], key: Any, t: np.ndarray, pos: int = 0, **data: np.ndarray) -> S | None:
        """Samples ``t`` (µs) with fields ``data`` of stream ``key``, found at
        byte ``pos``; the packet to emit, or None when nothing is left."""
        t = np.asarray(t, np.int64)
        keep = np.ones(t.shape[0], bool)
        lo, hi = self.src.t_start_us, self.src.t_end_us
        if lo is not None:
            keep &= t >= lo
        if hi is not None:
            keep &= t < hi
        if t.shape[0] > 1 and bool(np.any(t[1:] < t[:-1])):
            late = np.zeros(t.shape[0], bool)
            late[1:] = t[1:] < np.maximum.accumulate(t)[:-1]
        else:
            late = None
        prev = self.ends.get(key)
        if prev is not None:
            late = (t < prev) if late is None else (late | (t < prev))
        if late is not None and bool(np.any(late & keep)):
            if not self.src.skip_bad:
                i = int(np.flatnonzero(late & keep)[0])
                self.src._fail(f"stream {key} timestamps decrease ({int(t[i])} µs)", pos)
            self.src._note_skip(pos, pos, int((late & keep).sum()))
            keep &= ~late
        if not keep.any():
            return None
        if not keep.all():
            t, data = t[keep], {k: np.asarray(v)[keep] for k, v in data.items()}
        start = prev if prev is not None else int(t[0])
        self.ends[key] = int(t[-1]) + 1
        return cls(t, t_start=start, t_end=self.ends[key], **data)


class FileSource(Source):
    """Base of the file sources: options every format shares.

    Parameters
    ----------
    path:
        The file.
    sensor:
        ``"WIDTHxHEIGHT"`` in pixels, for files that do not say (or to check
        the file against).
    skip_bad:
        Drop undecodable parts (counted, see :attr:`skipped_events`) instead
        of raising :class:`tectum.FormatError`.
    t_start_us, t_end_us:
        Read only ``[t_start_us, t_end_us)`` (absolute µs, after offsets),
        seeking where the format has an index.
    chunk_bytes:
        Bytes read at a time (memory stays bounded by a small multiple).
    apply_t0:
        Add header time offsets (``% t0``, ``t_offset``) to timestamps
        (default); the offset is reported in :attr:`t0_offset` either way.
    """

    format: ClassVar[str] = ""
    produces: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS,)

    def __init__(self, path: str, sensor: str | None = None, skip_bad: bool = False,
                 t_start_us: int | None = None, t_end_us: int | None = None,
                 chunk_bytes: int = DEFAULT_CHUNK_BYTES, apply_t0: bool = True) -> None:
        if chunk_bytes < 64:
            raise ValueError("chunk_bytes must be >= 64")
        if t_start_us is not None and t_end_us is not None and t_end_us < t_start_us:
            raise ValueError("t_end_us is before t_start_us")
        self.path = os.fspath(path)
        self.sensor_opt = parse_size(sensor)
        self.skip_bad = bool(skip_bad)
        self.t_start_us = None if t_start_us is None else int(t_start_us)
        self.t_end_us = None if t_end_us is None else int(t_end_us)
        self.chunk_bytes = int(chunk_bytes)
        self.apply_t0 = bool(apply_t0)
        #: Header time offset found in the file, µs (added when ``apply_t0``).
        self.t0_offset = 0
        #: Events (or records) dropped because of bad input (``skip_bad``).
        self.skipped_events = 0
        #: Byte ranges ``(first, last)`` holding what was dropped.
        self.skipped_ranges: list[tuple[int, int]] = []
        #: Where the sensor size came from when the file does not say it (a
        #: phrase: :data:`FROM_OPTION`, :data:`FROM_EXTENT`, ...); None while
        #: the file says it, or before the file is read.
        self.sensor_from: str | None = None
        self._files: list[Any] = []

    # -- helpers for subclasses ------------------------------------------------
    def _open(self, buffering: int = -1) -> Any:
        """The file, for reading bytes; ``buffering=0``: unbuffered, for a
        reader that reads big chunks into buffers of its own (a buffered one
        adds system calls: a terminal test, a seek, a read past the end)."""
        try:
            f = open(self.path, "rb", buffering=buffering)
        except OSError as e:
            raise FormatError(f"cannot open: {e.strerror}", path=self.path) from None
        self._files.append(f)
        return f

    def _note_skip(self, first: int, last: int, n: int) -> None:
        self.skipped_events += n
        if self.skipped_ranges and self.skipped_ranges[-1][1] >= first - 8:
            a, b = self.skipped_ranges[-1]
            self.skipped_ranges[-1] = (a, max(b, last))
        else:
            self.skipped_ranges.append((first, last))

    def _fail(self, message: str, offset: int | None = None) -> NoReturn:
        raise FormatError(message, path=self.path, offset=offset)

    def _sensor(self, found: tuple[int, int] | None) -> tuple[int, int] | None:
        """The sensor size the file says (``found``; checked against the
        option), else the option's, else None (the caller finds it another
        way and says how: :meth:`_sensor_guessed`)."""
        if self.sensor_opt and found and self.sensor_opt != found:
            self._fail(f"the file says sensor {found[0]}x{found[1]}, the option says "
                       f"{self.sensor_opt[0]}x{self.sensor_opt[1]}")
        self.sensor_from = None if found or not self.sensor_opt else FROM_OPTION
        return found or self.sensor_opt

    def _sensor_guessed(self, size: tuple[int, int], how: str = FROM_EXTENT) -> tuple[int, int]:
        """``size`` (px), a sensor size the file does not say, found ``how``
        (default :data:`FROM_EXTENT`: the largest coordinates + 1, a lower
        bound of the camera's), recorded in :attr:`sensor_from`."""
        self.sensor_from = how
        return size

    # -- public ------------------------------------------------------------------
    def packets(self) -> Iterator[Packet]:
        try:
            yield from self._packets()
        finally:
            self.close()

    def _packets(self) -> Iterator[Packet]:
        raise NotImplementedError

    def time_span(self) -> tuple[int, int] | None:
        """Times of the first and last event (µs, offsets applied as read),
        from the format's index or the file's ends, without decoding what
        lies between; None where the format has neither (time sharding then
        makes one pass over the file)."""
        return None

    def info(self) -> dict[str, Any]:
        """Format, sensor, duration, event count, streams and offsets: a full
        pass over the file (streaming), unless the format keeps an index."""
        counts: dict[str, int] = {}
        first: int | None = None
        last: int | None = None
        sensor = None
        for pkt in self.packets():
            k = str(pkt.kind)
            counts[k] = counts.get(k, 0) + len(pkt)
            if isinstance(pkt, EventPacket):
                sensor = pkt.sensor
                if len(pkt):
                    first = int(pkt.t[0]) if first is None else first
                    last = int(pkt.t[-1])
        n = counts.get("events", 0)
        dur = (last - first) if first is not None and last is not None else 0
        return {"format": self.format, "path": self.path, "sensor": sensor, "events": n,
                "t_first_us": first, "t_last_us": last, "duration_us": dur,
                "rate_mev_s": (n / dur) if dur > 0 else 0.0,
                "streams": {k: v for k, v in counts.items()}, "t0_offset_us": self.t0_offset,
                "skipped_events": self.skipped_events, "sensor_from": self.sensor_from}

    @property
    def counts(self) -> dict[str, int]:
        """What ``--stats`` shows under the source: with ``skip_bad``, the
        events (or records) dropped and the byte ranges they came from,
        unless a format keeps counters of its own (set ``counts``)."""
        own: dict[str, int] | None = getattr(self, "_own_counts", None)
        if own is not None:
            return own
        if not self.skip_bad and not self.skipped_events:
            return {}
        return {"skipped_events": self.skipped_events, "skipped_ranges": len(self.skipped_ranges)}

    @counts.setter
    def counts(self, value: dict[str, int]) -> None:
        self._own_counts = value

    def close(self) -> None:
        for f in self._files:
            try:
                f.close()
            except OSError:
                pass
        self._files = []
