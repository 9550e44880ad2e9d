"""Prophesee RAW (EVT 2.0, EVT 3.0) and DAT files.

RAW files start with ``% key value`` header lines (``% evt 2.0`` or
``% format EVT3``, ``% geometry WxH``, optionally ``% end``); DAT files with
``% ...`` lines, then two bytes: event type (0 Event2d, 12 EventCD) and size
(8). Layouts follow Prophesee's documentation:

* EVT 2.0: 32-bit words, type in bits 31-28: CD_OFF 0x0 / CD_ON 0x1 (6-bit
  time LSB, 11-bit x, 11-bit y), EV_TIME_HIGH 0x8 (28 bits, time >> 6),
  EXT_TRIGGER 0xA, OTHERS 0xE, CONTINUED 0xF. Time has 34 bits; wraps unrolled.
* EVT 3.0: 16-bit words, type in bits 15-12: ADDR_Y 0x0, ADDR_X 0x2,
  VECT_BASE_X 0x3, VECT_12 0x4, VECT_8 0x5, TIME_LOW 0x6, CONTINUED_4 0x7,
  TIME_HIGH 0x8, EXT_TRIGGER 0xA, OTHERS 0xE, CONTINUED_12 0xF. Time has 24
  bits (wraps every 16.8 s): a TIME_HIGH falling by more than half its range
  counts one wrap.
* DAT: 8-byte records, uint32 time (µs, wraps unrolled), uint32 with x in
  bits 0-13, y in bits 14-27, polarity in bits 28-31.

A RAW file must say its format (``% evt`` / ``% format`` header lines): a
file without one (random bytes named ``.raw``, a damaged header) is refused
rather than guessed, unless the ``format`` option names it
(``recording.raw?format=evt3``).

Events before the first time base (EVT ``TIME_HIGH``) have no time and are
dropped (counted in :attr:`RawSource.untimed_events`). External triggers
(``EXT_TRIGGER``) come out as :class:`tectum.TriggerPacket` (``channel`` =
trigger id, ``value`` 1 rising / 0 falling edge).
"""

from __future__ import annotations

from collections.abc import Iterator
from functools import lru_cache, partial
from typing import Any, ClassVar

import numpy as np

from tectum import FormatError, Kind, Packet, TriggerPacket

from . import _kernels as K
from ._common import (
    EventAssembler,
    FileSource,
    SampleTiler,
    byte_buffer,
    header_dict,
    read_array,
    read_full,
    read_prefixed_header,
    record_offsets,
    sensor_from_header,
    t0_from_header,
)
from ._dat_kernels import decode_dat_within

__all__ = ["Evt2Source", "Evt3Source", "DatSource", "raw_format_of"]


def raw_format_of(h: dict[str, str]) -> str | None:
    """"evt2", "evt3" or None from a RAW header dictionary."""
    fmt = h.get("format", "").split(";")[0].strip().upper()
    evt = h.get("evt", "").strip()
    if fmt in ("EVT3", "EVT3.0") or evt.startswith("3"):
        return "evt3"
    if fmt in ("EVT2", "EVT2.0") or evt.startswith("2"):
        return "evt2"
    return None


#: RAW event formats: (word type, decoder state size, events a word yields at most)
_LAYOUTS: dict[str, tuple[type, int, int]] = {"evt2": (np.uint32, K.EVT2_STATE, 1),
                                               "evt3": (np.uint16, K.EVT3_STATE, 12)}


def format_option(value: str | None) -> str | None:
    """The ``format`` option of a RAW source: ``"evt2"``/``"evt3"`` (also
    written ``EVT 2.0``, ``evt3.0``...), or None."""
    if value is None or not str(value).strip():
        return None
    fmt = raw_format_of({"evt": str(value).lower().replace("evt", "").strip()})
    if fmt is None:
        raise ValueError(f"format {value!r} is not a RAW event format (evt2 or evt3)")
    return fmt


@lru_cache(maxsize=4)
def _head_format(head: bytes) -> str | None:
    """:func:`raw_format_of` the ``%`` lines among the first 64 lines of
    ``head`` (a file's first bytes). Cached: every RAW class sniffs the
    same bytes in turn. A head without ``evt`` in any case is no RAW file
    (``% evt 2.0``, ``% format EVT3``: both name it), without parsing."""
    if b"evt" not in head.lower():
        return None
    lines = [ln[1:].strip().decode("latin1", "replace") for ln in head.split(b"\n")[:64] if ln.startswith(b"%")]
    return raw_format_of(header_dict(lines))


class RawSource(FileSource):
    """Common part of the EVT 2.0 and EVT 3.0 readers.

    Parameters (besides :class:`FileSource`'s)
    ------------------------------------------
    format:
        ``evt2`` or ``evt3``: the event format of a RAW file whose header
        does not name it (without this, such a file is refused: bytes of one
        format decode as plausible but invented events in the other).
    """

    extensions: ClassVar[tuple[str, ...]] = (".raw",)
    #: the format this class reads when the header names none (the ``format`` option's default)
    evt: ClassVar[str] = ""
    produces = (Kind.EVENTS, Kind.TRIGGERS)

    def __init__(self, path: str, format: str | None = None, **kw: Any) -> None:
        super().__init__(path, **kw)
        #: The format named by the option, None to take the header's.
        self.named_format = format_option(format)
        self._use(self.named_format or self.evt)

    def _use(self, evt: str) -> None:
        """Decode ``evt`` (``"evt2"``/``"evt3"``)."""
        self.evt_format = evt
        self.word, self.state_size, self.fanout = _LAYOUTS[evt]

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"%") and _head_format(head) == cls.evt

    def _header(self, f: Any) -> tuple[dict[str, str], int, tuple[int, int] | None]:
        lines, start = read_prefixed_header(f, b"%", self.path)
        h = header_dict(lines)
        fmt = raw_format_of(h)
        if fmt is not None and self.named_format is not None and fmt != self.named_format:
            self._fail(f"the header says {fmt}, the format option says {self.named_format}", 0)
        if fmt is None and self.named_format is None:
            what = "has no header" if not lines else "has a header naming no event format (% evt / % format)"
            self._fail(f"{what}: not a RAW file, or a damaged one; if it holds raw EVT words, name their "
                       "format: FILE?format=evt2 or FILE?format=evt3", 0)
        self._use(fmt or self.evt_format)
        self.t0_offset = t0_from_header(h, self.path)
        self.header = h
        return h, start, sensor_from_header(h)

    def _kernel(self) -> Any:
        return K.decode_evt2 if self.evt_format == "evt2" else K.decode_evt3

    def _bounded_kernel(self) -> Any:
        """The fast path's kernel, which also returns the events' bounds."""
        return K.decode_evt2_bounded if self.evt_format == "evt2" else K.decode_evt3_bounded

    def info(self) -> dict[str, Any]:
        out = super().info()
        out["format"] = self.evt_format  # what was decoded (the option can differ from the class's)
        return out

    def _decode(self, words: np.ndarray,
                state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int,
                                            np.ndarray]:
        """All events of ``words`` in fresh arrays (t, x, y, p), the index of
        each one's word, the kernel's error position and count, and the
        triggers (slow path: extent scans, error offsets)."""
        n = words.shape[0] * self.fanout
        t = np.empty(n, np.int64)
        x = np.empty(n, np.uint16)
        y = np.empty(n, np.uint16)
        p = np.empty(n, np.int8)
        where = np.empty(n, np.int64)
        trig = np.empty((words.shape[0], 3), np.int64)
        ne, nt, bad, nbad, _ = self._kernel()(words, state, not self.skip_bad, t, x, y, p, where, trig)
        return t[:ne], x[:ne], y[:ne], p[:ne], where[:ne], int(bad), int(nbad), trig[:nt]

    def _words(self, f: Any, start: int) -> Iterator[tuple[int, np.ndarray]]:
        """(file offset, words) per chunk; the words live in one buffer,
        overwritten by the next chunk."""
        size = np.dtype(self.word).itemsize
        step = max(size, self.chunk_bytes - self.chunk_bytes % size)
        buf = byte_buffer(step)
        dtype = np.dtype(self.word).newbyteorder("<")
        pos = start
        while True:
            got = read_full(f, buf)  # the file may be unbuffered: a read may come short before its end
            if not got:
                return
            k = got - got % size
            if k < got:
                if not self.skip_bad:
                    self._fail(f"file ends inside a {size}-byte word (truncated)", pos + k)
                self._note_skip(pos + k, pos + got - 1, 1)
            yield pos, np.frombuffer(buf, dtype=dtype, count=k // size)
            pos += got

    def _packets(self) -> Iterator[Packet]:
        f = self._open(buffering=0)  # big reads into its own buffers
        h, start, sensor = self._header(f)
        sensor = self._sensor(sensor)
        if sensor is None:
            sensor = self._scan_extent(f, start)
        pos = start
        if self.t_start_us is not None and self.evt_format == "evt2":
            pos = self._seek_evt2(f, start, self.t_start_us - (self.t0_offset if self.apply_t0 else 0))
            f.seek(pos)
        yield from self._events(f, pos, sensor)

    def _seek_evt2(self, f: Any, start: int, t: int) -> int:
        """Where to start decoding an EVT 2.0 file for events at or after
        time ``t`` (µs, before the offset): a TIME_HIGH word whose time base
        lies below ``t``'s, found by bisection on the file (each probe scans
        forward to the next TIME_HIGH word), so nothing before it needs
        decoding. The file's start when its last time base is below its
        first (the 34-bit time wrapped: bisection would go wrong) or ``t``
        lies before the first. Assumes no wrap between the ends (a recording
        under 4.7 h)."""
        n = (f.seek(0, 2) - start) // 4
        want = t >> 6
        ends = self._time_base_ends(f, start, n)
        if ends is None or ends[0][1] >= want:
            return start
        lo, hi = ends[0][0], n  # the time base at word lo is below want's; none at or after hi is
        while hi - lo > _PROBE_WORDS:
            mid = (lo + hi) // 2
            hit = _time_base_from(f, start, n, mid)
            if hit is None or hit[0] >= hi or hit[1] >= want:
                hi = mid
            else:
                lo = hit[0]
        return start + 4 * lo

    def _time_base_ends(self, f: Any, start: int, n: int) -> tuple[tuple[int, int], tuple[int, int]] | None:
        """The first and last (word index, raw time base) of an EVT 2.0
        file of ``n`` words, or None when there is none or they show a wrap."""
        first = _time_base_from(f, start, n, 0)
        last = None
        for i in range(max(0, n - _PROBE_WORDS), -1, -_PROBE_WORDS):  # the last block holding one
            f.seek(start + 4 * i)
            words = read_array(f, min(_PROBE_WORDS, n - i), "<u4")  # (f may be unbuffered)
            hit = np.flatnonzero((words >> 28) == 8)
            if hit.size:
                last = i + int(hit[-1]), int(words[hit[-1]]) & 0x0FFFFFFF
                break
        if first is None or last is None or last[1] < first[1]:
            return None
        return first, last

    def time_span(self) -> tuple[int, int] | None:
        """EVT 2.0: from the first and last time bases (the last event lies
        within 64 µs of the last one); None for EVT 3.0, which has no such
        marks at its ends, or a file whose time wrapped."""
        f = self._open()
        try:
            _, start, _ = self._header(f)
            if self.evt_format != "evt2":
                return None
            ends = self._time_base_ends(f, start, (f.seek(0, 2) - start) // 4)
        finally:
            self.close()
        off = self.t0_offset if self.apply_t0 else 0
        return None if ends is None else (ends[0][1] * 64 + off, ends[1][1] * 64 + 63 + off)

    def _scan_extent(self, f: Any, start: int) -> tuple[int, int]:
        """No geometry in the file or options: the extent of the coordinates."""
        state = np.zeros(self.state_size, np.int64)
        w = h = 1
        f.seek(start)
        for _, words in self._words(f, start):
            t, x, y, *_ = self._decode(words, state)
            if t.shape[0]:
                w, h = max(w, int(x.max()) + 1), max(h, int(y.max()) + 1)
        f.seek(start)
        return self._sensor_guessed((w, h))

    def _events(self, f: Any, start: int, sensor: tuple[int, int]) -> Iterator[Packet]:
        """One packet per ``chunk_bytes`` of words (or sooner, when a
        chunk's events fill its columns), read :data:`_RAW_READ` bytes at a
        time into one small buffer and decoded into the chunk's columns:
        the buffer stays in the core's cache between the copy from the OS
        and the kernel's pass (a whole chunk read at once went to memory
        and back, as DAT's did). Triggers follow the events they came with."""
        state = np.zeros(self.state_size, np.int64)
        off = self.t0_offset if self.apply_t0 else 0
        asm = EventAssembler(self, sensor, offset=off)
        size = np.dtype(self.word).itemsize
        dtype = np.dtype(self.word).newbyteorder("<")
        self.triggers = 0
        tiler = SampleTiler(self)
        kernel = self._bounded_kernel()
        strict = not self.skip_bad
        step = max(size, self.chunk_bytes - self.chunk_bytes % size)  # bytes a chunk's words take
        piece = min(step, _RAW_READ - _RAW_READ % size)
        buf = byte_buffer(piece)
        trig = np.empty((piece // size, 3), np.int64)  # untouched rows cost nothing
        held = trig[:0]  # triggers at the latest time, waiting for the next chunk
        cap = max(1 << 12, self.chunk_bytes // size)  # events a chunk's columns hold
        pos = start  # the file offset of the next byte read
        eof = False
        while not eof and not asm.past_end():
            at, before, n = pos, state.copy(), 0  # where this packet's words start, the state there
            t, x, y, p = asm.reserve(cap)
            ordered, mx, my, full = True, 0, 0, False
            end = pos + step
            while pos < end and not full:
                got = read_full(f, buf[:min(piece, end - pos)])  # short only where the file ends
                if not got:
                    eof = True
                    break
                k = got - got % size
                if k < got:
                    if strict:
                        self._fail(f"file ends inside a {size}-byte word (truncated)", pos + k)
                    self._note_skip(pos + k, pos + got - 1, 1)
                words = np.frombuffer(buf, dtype=dtype, count=k // size)
                i = 0
                while i < words.shape[0]:
                    ne, nt, bad, nbad, used, ok, bx, by = kernel(words[i:], state, strict, t[n:], x[n:], y[n:],
                                                                 p[n:], trig)
                    self.triggers += nt
                    if bad >= 0:
                        where = pos + (i + bad) * size
                        if strict:
                            self._fail(f"invalid {self.evt_format.upper()} word "
                                       f"0x{int(words[i + bad]):0{2 * size}x}", where)
                        self._note_skip(where, where + size - 1, nbad)
                    if ne:
                        ordered = ordered and bool(ok) and (n == 0 or bool(t[n] >= t[n - 1]))
                        mx, my = max(mx, int(bx)), max(my, int(by))
                        n += ne
                    if nt:
                        held = np.concatenate([held, trig[:nt]])
                        held[-nt:, 0] += off
                    i += used
                    if i < words.shape[0]:  # the columns are full: the rest of the piece goes to the next packet
                        full = True
                        break
                if full:  # the words not decoded are read again
                    f.seek(pos + i * size)
                    pos += i * size
                else:
                    pos += got
            del t, x, y, p  # views of the chunk's columns: once its packets are gone, the set is free again
            yield from asm.commit(n, at, self._where_of(f, at, pos, before), (ordered, mx, my))
            if held.shape[0]:
                k = self._last_run(held)
                yield from self._triggers(tiler, held[:k], at)
                held = held[k:]
        self.untimed_events = int(state[4] if self.evt_format == "evt2" else state[7])
        yield from asm.finish()
        yield from self._triggers(tiler, held, pos)

    @staticmethod
    def _last_run(rows: np.ndarray) -> int:
        """Where the trailing run of ``rows`` sharing the last row's time
        starts: those wait for the next chunk (a trigger may follow at that
        time, and a time is never split across packets)."""
        other = np.flatnonzero(rows[:, 0] != rows[-1, 0])
        return int(other[-1]) + 1 if other.size else 0

    @staticmethod
    def _triggers(tiler: SampleTiler, rows: np.ndarray, pos: int) -> Iterator[Packet]:
        """The trigger packet of ``rows`` (t µs, channel, value), if any."""
        if rows.shape[0]:
            tp = tiler.push(TriggerPacket, "triggers", rows[:, 0], pos,
                            channel=rows[:, 1].astype(np.int16), value=rows[:, 2].astype(np.int8))
            if tp is not None:
                yield tp

    def _where_of(self, f: Any, at: int, end: int, state: np.ndarray) -> Any:
        """A function giving the byte offset of each event decoded from the
        words in bytes ``[at, end)`` of the file, by reading them again and
        decoding them from ``state`` (called only when an event is bad)."""
        size = np.dtype(self.word).itemsize

        def where() -> np.ndarray:
            back = f.tell()
            f.seek(at)
            words = read_array(f, (end - at) // size, np.dtype(self.word).newbyteorder("<"))
            f.seek(back)
            return at + self._decode(words, state.copy())[4] * size
        return where


#: Bytes of RAW words read at a time (they stay in the core's L2 cache
#: until decoded; as :data:`_DAT_READ`).
_RAW_READ = 1 << 19

#: Words an EVT 2.0 bisection probe reads (64 KB) looking for a TIME_HIGH word.
_PROBE_WORDS = 1 << 14


def _time_base_from(f: Any, start: int, n: int, i: int) -> tuple[int, int] | None:
    """(word index, raw time base) of the first EVT 2.0 TIME_HIGH word at or
    after word ``i`` of a file of ``n`` words from byte ``start``."""
    while i < n:
        f.seek(start + 4 * i)
        words = read_array(f, min(_PROBE_WORDS, n - i), "<u4")  # (f may be unbuffered)
        hit = np.flatnonzero((words >> 28) == 8)
        if hit.size:
            return i + int(hit[0]), int(words[hit[0]]) & 0x0FFFFFFF
        i += words.shape[0]
    return None


class Evt2Source(RawSource):
    """Prophesee RAW EVT 2.0 files (``% evt 2.0``)."""

    name = "evt2"
    format = "evt2"
    evt = "evt2"


class Evt3Source(RawSource):
    """Prophesee RAW EVT 3.0 files (``% evt 3.0`` / ``% format EVT3``)."""

    name = "evt3"
    format = "evt3"
    evt = "evt3"


#: Bytes of DAT records read at a time into a chunk's time column and
#: decoded there (they stay in the core's L2 cache until decoded).
_DAT_READ = 1 << 19

#: A DAT packet's records by default (``chunk_bytes``): 64 Ki events, whose
#: columns (13 B an event, 0.9 MB; the records are read into the time
#: column) fit in a core's L2 cache (1 MiB on the AMD EPYC measured). A
#: consumer that lets packets go as they come gets pooled columns back
#: that are still in the cache (one set, or two when it holds the last
#: packet while asking for the next): the decoder's 13 B an event are
#: written to the cache, not fetched from memory first and written back
#: later. With 4 MiB packets a decode of gen4.dat (1.2 M events) took
#: 1.09-1.26x the CPU time (interleaved, loaded; the most right after
#: another program had filled the caches); 256 KiB to 1 MiB did alike
#: (more packets cost ~13 µs each); with the records decoded in place,
#: 768 KiB and 1 MiB did alike too, 384 KiB took ~7 % more. The other formats keep
#: :data:`DEFAULT_CHUNK_BYTES`.
DAT_CHUNK_BYTES = 1 << 19


class DatSource(FileSource):
    """Prophesee ``.dat`` files (EventCD and the older Event2d).

    The records are fixed-size and sorted, so a time range is found by
    bisection on the file, without decoding what comes before it. A packet
    holds :data:`DAT_CHUNK_BYTES` of records unless ``chunk_bytes`` says
    otherwise (small enough to stay in the cache, see there).
    """

    name = "dat"
    format = "dat"
    extensions = (".dat",)

    def __init__(self, path: str, chunk_bytes: int = DAT_CHUNK_BYTES, **kw: Any) -> None:
        super().__init__(path, chunk_bytes=chunk_bytes, **kw)

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        if not head.startswith(b"% "):
            return False
        low = head[:2048].lower()
        return b"% data file" in low or (b"% version" in low and b"% evt" not in low and b"format evt" not in low)

    def _header(self, f: Any) -> tuple[int, tuple[int, int] | None]:
        lines, start = read_prefixed_header(f, b"%", self.path)
        h = header_dict(lines)
        self.header = h
        self.t0_offset = t0_from_header(h, self.path)
        if raw_format_of(h) is not None:
            self._fail("this is a RAW (EVT) file, not DAT")
        tb = f.read(2)
        if len(tb) < 2:
            self._fail("file ends before the event type and size bytes (truncated)", start)
        ev_type, ev_size = tb[0], tb[1]
        if ev_size != 8:
            self._fail(f"event size {ev_size} is not 8 (type {ev_type})", start + 1)
        if ev_type not in (0, 12):
            self._fail(f"event type {ev_type} is not Event2d (0) or EventCD (12)", start)
        self.event_type = ev_type
        return start + 2, sensor_from_header(h)

    def _packets(self) -> Iterator[Packet]:
        f = self._open(buffering=0)  # big reads into its own buffers
        start, sensor = self._header(f)
        sensor = self._sensor(sensor)
        size = f.seek(0, 2)
        end = start + (size - start) // 8 * 8
        if end < size and not self.skip_bad:
            self._fail(f"file ends inside an 8-byte record (truncated, {size - end} bytes left)", end)
        if end < size:
            self._note_skip(end, size - 1, 1)
        if sensor is None:
            sensor = self._scan_extent(f, start, end)
        pos = start
        if self.t_start_us is not None:
            pos = self._bisect(f, start, end, self.t_start_us - (self.t0_offset if self.apply_t0 else 0))
        yield from self._events(f, pos, end, sensor)

    def time_span(self) -> tuple[int, int] | None:
        """The first and last records' times (None for a file of no
        records, or whose 32-bit time wrapped: the last is below the first)."""
        f = self._open()
        try:
            start, _ = self._header(f)
            n = (f.seek(0, 2) - start) // 8
            if n == 0:
                return None
            f.seek(start)
            first = int.from_bytes(f.read(4), "little")
            f.seek(start + (n - 1) * 8)
            last = int.from_bytes(f.read(4), "little")
        finally:
            self.close()
        off = self.t0_offset if self.apply_t0 else 0
        return (first + off, last + off) if last >= first else None

    def _bisect(self, f: Any, start: int, end: int, t: int) -> int:
        """First record at or after time ``t`` (raw µs), assuming no wrap."""
        lo, hi = 0, (end - start) // 8
        while lo < hi:
            mid = (lo + hi) // 2
            f.seek(start + mid * 8)
            if int.from_bytes(f.read(4), "little") < t:
                lo = mid + 1
            else:
                hi = mid
        return start + lo * 8

    def _chunks(self, f: Any, pos: int, end: int) -> Iterator[tuple[int, np.ndarray]]:
        """(file offset, records as little-endian uint64) per chunk of whole
        records; they live in one buffer, overwritten by the next chunk."""
        step = max(8, self.chunk_bytes // 8 * 8)
        buf = byte_buffer(step)
        f.seek(pos)
        while pos < end:
            got = read_full(f, buf[:min(step, end - pos)])  # unbuffered: a read may come short before the end
            if not got:
                return
            yield pos, np.frombuffer(buf, "<u8", count=got // 8)
            pos += got

    def _decode(self, records: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, ...]:
        m = records.shape[0]
        t, x, y = np.empty(m, np.int64), np.empty(m, np.uint16), np.empty(m, np.uint16)
        p = np.empty(m, np.int8)
        K.decode_dat(records, state, t, x, y, p)
        return t, x, y, p

    def _scan_extent(self, f: Any, start: int, end: int) -> tuple[int, int]:
        w = h = 1
        state = np.zeros(K.DAT_STATE, np.int64)
        for _, records in self._chunks(f, start, end):
            _, x, y, _ = self._decode(records, state)
            if x.shape[0]:
                w, h = max(w, int(x.max()) + 1), max(h, int(y.max()) + 1)
        return self._sensor_guessed((w, h))

    def _events(self, f: Any, pos: int, end: int, sensor: tuple[int, int]) -> Iterator[Packet]:
        """One packet per ``chunk_bytes`` of records, read :data:`_DAT_READ`
        bytes at a time into the chunk's time column and decoded in place
        (a record and its time are both 8 bytes; the kernel reads each
        record before it writes its time). No read buffer: the column set
        alone (13 B an event, 0.9 MB for the default chunk) stays in a
        core's L2 cache from the copy out of the OS to the consumer, where
        a separate 512 KiB buffer beside it did not fit a 1 MiB L2 (CPU time
        after a peer's decode of gen4.dat 1.08x less, interleaved, loaded)."""
        state = np.zeros(K.DAT_STATE, np.int64)
        asm = EventAssembler(self, sensor, offset=self.t0_offset if self.apply_t0 else 0)
        step = max(8, self.chunk_bytes // 8 * 8)
        piece = min(step, _DAT_READ) // 8  # step and _DAT_READ are whole records
        w, h = sensor if asm.check_geometry else (1 << 16, 1 << 16)
        f.seek(pos)
        while pos < end:
            at, m = pos, min(step, end - pos) // 8
            t, x, y, p = asm.reserve(m)
            n, ok = 0, True
            while n < m:
                records = t[n:n + min(piece, m - n)].view(np.uint64)  # the records, then their times
                raw = records.view(np.uint8)
                k = read_full(f, raw) // 8  # short only where the file ends
                if not k:
                    break
                ok = decode_dat_within(records, k, state, t, x, y, p, n, w, h)[1] and ok
                n += k
            pos += 8 * n
            del t, x, y, p, records, raw  # views of the chunk's columns: once its packets go, the set is free again
            yield from asm.commit(n, at, partial(record_offsets, at, 8, n), (ok, 0, 0))
            if asm.past_end() or n < m:  # the end, or the file shrank while read
                break
        yield from asm.finish()


def check_raw_header(path: str) -> str:
    """"evt2" or "evt3" for a RAW file (from its header), else FormatError."""
    with open(path, "rb") as f:
        lines, _ = read_prefixed_header(f, b"%", path)
    fmt = raw_format_of(header_dict(lines))
    if fmt is None:
        raise FormatError("RAW header names no event format (% evt / % format)", path=path, offset=0)
    return fmt
