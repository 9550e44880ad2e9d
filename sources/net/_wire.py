"""tectum's network framing for event streams (UDP datagrams, TCP frames).

Every message starts with a 44-byte little-endian header::

    magic "TQ" | version u8 (1) | type u8 | session u32 | seq u32 | schema u32 |
    t_start i64 | t_end i64 | t_base i64 | n u32

``type`` is HELLO (0), EVENTS (1), END (2), SAMPLES (3: IMU, frames,
poses, triggers) or FRAG (4: a piece of a longer message), the last two
described in :mod:`._samples`. ``session`` is random per
sender run, ``seq`` counts the sender's messages (so the receiver counts
what was lost), ``schema`` is the CRC-32 of the HELLO body that describes
the columns. EVENTS carries ``n`` events: ``t - t_base`` as u32, then x u16,
y u16, p i8, then each extra column in the HELLO's order (fixed-size
numeric dtypes), every array contiguous. ``[t_start, t_end)`` is the
message's interval; ``t_end`` is a watermark, except that events exactly at
``t_end`` are allowed (a run of one timestamp split over two messages): the
receiver holds those back until the next message.

HELLO's body: sensor width u16, height u16, column count u8, then per
column its name and numpy dtype string, each as u8 length + ASCII. On TCP
each message is preceded by its length (u32). A receiver checks everything
and counts what it rejects, by reason; nothing in a message makes it
allocate more than the message's own size.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from tectum import EventPacket, Packet

from ._samples import FRAG, SAMPLES, Reassembly, decode_samples

__all__ = ["HEADER", "HELLO", "EVENTS", "END", "Header", "encode_hello", "encode_events", "encode_end",
           "chunks", "Receiver", "MAX_COLUMNS", "row_bytes"]

_HDR = struct.Struct("<2sBBIIIqqqI")
HEADER = _HDR.size  # 44
MAGIC, VERSION = b"TQ", 1
HELLO, EVENTS, END = 0, 1, 2
MAX_COLUMNS = 32
_SPAN = (1 << 32) - 1
_BASE_ROW = 4 + 2 + 2 + 1


@dataclass(frozen=True)
class Header:
    type: int
    session: int
    seq: int
    schema: int
    t_start: int
    t_end: int
    t_base: int
    n: int


def _header(typ: int, session: int, seq: int, schema: int, t_start: int, t_end: int, t_base: int, n: int) -> bytes:
    return _HDR.pack(MAGIC, VERSION, typ, session & 0xFFFFFFFF, seq & 0xFFFFFFFF, schema, t_start, t_end, t_base, n)


def schema_body(sensor: tuple[int, int], columns: list[tuple[str, np.dtype]]) -> bytes:
    out = bytearray(struct.pack("<HHB", sensor[0] & 0xFFFF, sensor[1] & 0xFFFF, len(columns)))
    for name, dt in columns:
        for s in (name.encode("ascii"), np.dtype(dt).str.encode("ascii")):
            out += bytes([len(s)]) + s
    return bytes(out)


def encode_hello(session: int, seq: int, sensor: tuple[int, int], columns: list[tuple[str, np.dtype]]) -> bytes:
    """The HELLO message; ``sensor`` 65536 is sent as 0."""
    body = schema_body(sensor, columns)
    return _header(HELLO, session, seq, zlib.crc32(body), 0, 0, 0, 0) + body


def encode_end(session: int, seq: int, schema: int, t_end: int) -> bytes:
    return _header(END, session, seq, schema, t_end, t_end, t_end, 0)


def row_bytes(columns: list[tuple[str, np.dtype]]) -> int:
    return _BASE_ROW + sum(np.dtype(d).itemsize for _, d in columns)


def encode_events(session: int, seq: int, schema: int, pkt: EventPacket, t_start: int, t_end: int,
                  names: list[str]) -> bytes:
    """One EVENTS message with all events of ``pkt`` (already a chunk)."""
    n = len(pkt)
    t_base = int(pkt.t[0]) if n else t_start
    parts = [_header(EVENTS, session, seq, schema, t_start, t_end, t_base, n),
             (pkt.t - t_base).astype("<u4").tobytes(), pkt.x.astype("<u2").tobytes(),
             pkt.y.astype("<u2").tobytes(), pkt.p.tobytes()]
    for name in names:
        a = pkt.columns[name]
        parts.append(np.ascontiguousarray(a, a.dtype.newbyteorder("<")).tobytes())
    return b"".join(parts)


def chunks(pkt: EventPacket, max_events: int) -> Iterator[tuple[EventPacket, int, int]]:
    """Cut a packet into pieces of at most ``max_events`` events whose time
    span fits the u32 offsets; yields (piece, t_start, t_end) where t_end is
    the next piece's first time (so a run of equal times may straddle)."""
    n = len(pkt)
    if n == 0:
        yield pkt, pkt.t_start, pkt.t_end
        return
    t = pkt.t
    i, start = 0, pkt.t_start
    while i < n:
        j = min(i + max_events, n)
        if int(t[j - 1]) - int(t[i]) > _SPAN:
            j = int(np.searchsorted(t, int(t[i]) + _SPAN, side="right"))
        end = pkt.t_end if j == n else int(t[j])
        yield pkt._take_slice(i, j, start, end), start, end
        i, start = j, end


@dataclass
class Receiver:
    """Turns received messages into valid EventPackets; counts everything.

    Counters: ``accepted`` messages, ``events``; ``lost`` messages (gaps in
    ``seq``), ``late`` (duplicates or reordered, dropped), ``rejected`` by
    reason (``short``, ``magic``, ``version``, ``type``, ``length``,
    ``schema``, ``no_hello``, ``bad_event``, ``time``, ``window``),
    ``sessions`` seen. ``max_held`` bounds the events held back at one
    timestamp.
    """

    max_events: int = 1 << 20
    max_held: int = 1 << 20
    seq_window: int = 1 << 20
    sensor: tuple[int, int] | None = None
    columns: list[tuple[str, np.dtype]] | None = None
    schema: int | None = None
    session: int | None = None
    last_seq: int | None = None
    ended: bool = False
    end_t: int | None = None
    accepted: int = 0
    events: int = 0
    lost: int = 0
    late: int = 0
    sessions: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    max_message: int = 1 << 23
    _held: EventPacket | None = None
    _prev_end: int | None = None
    _kind_end: dict[type, int] = field(default_factory=dict)
    _frag: Reassembly | None = None
    samples: int = 0

    def counts(self) -> dict[str, object]:
        return {"accepted": self.accepted, "events": self.events, "samples": self.samples, "lost": self.lost,
                "late": self.late, "fragments_incomplete": self._frag.incomplete if self._frag else 0,
                "sessions": self.sessions, "rejected": dict(self.rejected),
                "rejected_total": sum(self.rejected.values())}

    def _reject(self, why: str) -> list[Packet]:
        self.rejected[why] = self.rejected.get(why, 0) + 1
        return []

    def feed(self, msg: bytes | memoryview, inner: bool = False) -> list[Packet]:
        """One message (a datagram, or a TCP frame without its length)."""
        if len(msg) < HEADER:
            return self._reject("short")
        magic, ver, typ, session, seq, schema, t0, t1, tb, n = _HDR.unpack_from(msg, 0)
        if magic != MAGIC:
            return self._reject("magic")
        if ver != VERSION:
            return self._reject("version")
        if typ not in (HELLO, EVENTS, END, SAMPLES, FRAG) or (inner and typ == FRAG):
            return self._reject("type")
        if typ == HELLO:
            return self._hello(msg, session, seq, schema)
        if typ == FRAG:
            return self._fragment(msg, session, seq, schema, t0, t1, tb, n)
        if typ == SAMPLES:
            return self._samples(msg, session, seq, schema, t0, t1, tb, n)
        if typ == END and self.schema is None and schema == 0:  # a stream without events
            if len(msg) != HEADER or not self._sequence(session, seq):
                return self._reject("length") if len(msg) != HEADER else []
            self.accepted += 1
            self.ended, self.end_t = True, t1
            return []
        if self.schema is None:
            return self._reject("no_hello")
        if schema != self.schema:
            return self._reject("schema")
        if typ == END:
            if len(msg) != HEADER or (self._prev_end is not None and t1 < self._prev_end):
                return self._reject("length" if len(msg) != HEADER else "time")
            if not self._sequence(session, seq):
                return []
            self.accepted += 1
            self.ended, self.end_t = True, t1
            return self.flush(t1)
        pkt = self._events(msg, t0, t1, tb, n)  # checked whole before it counts in the sequence
        if pkt is None or not self._sequence(session, seq):
            return []
        self.accepted += 1
        self.events += len(pkt)
        return self._release(pkt, t1)

    def _fragment(self, msg: bytes | memoryview, session: int, seq: int, crc: int, index: int, count: int,
                  total: int, n: int) -> list[Packet]:
        piece = bytes(msg[HEADER:])
        if len(piece) != n or zlib.crc32(piece) != crc:
            return self._reject("fragment")
        if self._frag is None:
            self._frag = Reassembly(self.max_message)
        got = self._frag.add(session, seq, index, count, total, piece)
        if isinstance(got, str):
            return self._reject(got)
        return [] if got is None else self.feed(got, inner=True)

    def _samples(self, msg: bytes | memoryview, session: int, seq: int, schema: int, t0: int, t1: int, tb: int,
                 n: int) -> list[Packet]:
        got = decode_samples(msg, schema, n, tb, self.max_events)
        if isinstance(got, str):
            return self._reject(got)
        cls, t, data = got
        prev = self._kind_end.get(cls)
        if t1 < t0 or (prev is not None and t0 < prev) or (n and (tb < t0 or tb > (1 << 62) or int(t[-1]) >= t1
                                                               or np.any(t[1:] < t[:-1]))):
            return self._reject("time")
        try:
            pkt = cls(t, t_start=t0 if prev is None else prev, t_end=t1, **data)
        except Exception:  # a required field missing, shapes that do not agree
            return self._reject("bad_sample")
        if not self._sequence(session, seq):
            return []
        self.accepted += 1
        self.samples += n
        self._kind_end[cls] = t1
        return [pkt]

    def _sequence(self, session: int, seq: int) -> bool:
        if session != self.session:
            self.session, self.last_seq = session, None
            self.sessions += 1
        if self.last_seq is not None:
            gap = (seq - self.last_seq) & 0xFFFFFFFF
            if gap == 0 or gap > 0x80000000:
                self.late += 1
                return False
            if gap > self.seq_window:
                self._reject("window")
                return False
            self.lost += gap - 1
        self.last_seq = seq
        return True

    def _hello(self, msg: bytes | memoryview, session: int, seq: int, schema: int) -> list[Packet]:
        body = bytes(msg[HEADER:])
        if zlib.crc32(body) != schema:
            return self._reject("schema")
        if self.schema is not None:
            if schema != self.schema:
                return self._reject("schema")
            if session != self.session:  # a new sender run: its numbering starts here
                self._sequence(session, seq)
            return []  # a repeat for late joiners: its number is not in the sequence
        try:
            w, h, k = struct.unpack_from("<HHB", body, 0)
            pos = 5
            cols: list[tuple[str, np.dtype]] = []
            if k > MAX_COLUMNS or w == 0 or h == 0:
                raise ValueError
            for _ in range(k):
                strs = []
                for _ in range(2):
                    ln = body[pos]
                    strs.append(body[pos + 1: pos + 1 + ln].decode("ascii"))
                    if len(strs[-1]) != ln:
                        raise ValueError
                    pos += 1 + ln
                dt = np.dtype(strs[1])
                if dt.kind not in "biuf" or dt.itemsize > 8 or not strs[0].isidentifier() \
                        or strs[0] in ("t", "x", "y", "p") or strs[0] in [c for c, _ in cols]:
                    raise ValueError
                cols.append((strs[0], dt))
            if pos != len(body):
                raise ValueError
        except (ValueError, IndexError, struct.error, TypeError, UnicodeDecodeError):
            return self._reject("schema")
        self.sensor, self.columns, self.schema = (w, h), cols, schema
        self._sequence(session, seq)
        self.accepted += 1
        return []

    def _events(self, msg: bytes | memoryview, t0: int, t1: int, tb: int, n: int) -> EventPacket | None:
        assert self.columns is not None and self.sensor is not None
        if n > self.max_events or len(msg) != HEADER + n * row_bytes(self.columns):
            self._reject("length")
            return None
        if t1 < t0 or (self._prev_end is not None and t1 < self._prev_end) or (n and tb < t0):
            self._reject("time")
            return None
        pos = HEADER
        dt = np.frombuffer(msg, "<u4", n, pos)
        pos += 4 * n
        x = np.frombuffer(msg, "<u2", n, pos).astype(np.uint16)
        pos += 2 * n
        y = np.frombuffer(msg, "<u2", n, pos).astype(np.uint16)
        pos += 2 * n
        p = np.frombuffer(msg, np.int8, n, pos).copy()
        pos += n
        cols: dict[str, np.ndarray] = {}
        for name, d in self.columns:
            cols[name] = np.frombuffer(msg, d.newbyteorder("<"), n, pos).astype(d)
            pos += d.itemsize * n
        if tb > (1 << 62):
            self._reject("time")
            return None
        t = dt.astype(np.int64) + tb
        w, h = self.sensor
        if n and (np.any(x >= w) or np.any(y >= h) or np.any((p != 1) & (p != -1))):
            self._reject("bad_event")
            return None
        if n and (np.any(t[1:] < t[:-1]) or int(t[-1]) > t1
                  or (self._prev_end is not None and int(t[0]) < self._prev_end)
                  or (self._held is not None and len(self._held) and int(t[0]) < int(self._held.t[0]))):
            self._reject("time")
            return None
        return EventPacket(t, x, y, p, sensor=self.sensor, t_start=min(t0, int(t[0])) if n else t0,
                           t_end=max(t1, int(t[-1]) + 1) if n else t1, columns=cols)

    def _release(self, pkt: EventPacket, cut: int) -> list[Packet]:
        h = self._held
        if h is not None and len(h):
            pkt = EventPacket(*(np.concatenate([h[k], pkt[k]]) for k in ("t", "x", "y", "p")),
                              sensor=pkt.sensor, t_start=min(h.t_start, pkt.t_start), t_end=pkt.t_end,
                              columns={k: np.concatenate([h.columns[k], v]) for k, v in pkt.columns.items()})
        start = self._prev_end if self._prev_end is not None else pkt.t_start
        i = int(np.searchsorted(pkt.t, cut, side="left"))
        if len(pkt) - i > self.max_held:  # a hostile run of one timestamp: let it go
            self._reject("held")
            cut, i = int(pkt.t[-1]) + 1, len(pkt)
        held = pkt._take_slice(i, len(pkt), cut, max(cut, pkt.t_end))
        self._held = held if len(held) else None
        if cut <= start and i == 0:
            return []
        self._prev_end = max(cut, start)
        return [pkt._take_slice(0, i, start, self._prev_end)]

    def flush(self, t_end: int | None = None) -> list[Packet]:
        """Release everything held (end of stream)."""
        h = self._held
        self._held = None
        if h is None or not len(h):
            if t_end is not None and self._prev_end is not None and t_end > self._prev_end and self.sensor:
                pkt = EventPacket.empty(self.sensor, self._prev_end, t_end)
                self._prev_end = t_end
                return [pkt]
            return []
        start = self._prev_end if self._prev_end is not None else h.t_start
        end = max(int(h.t[-1]) + 1, t_end or 0)
        self._prev_end = end
        return [h._take_slice(0, len(h), start, end)]
