"""iniVation AEDAT 4.0 files (``#!AER-DAT4.0``), as written by DV.

Layout: the version line, an int32 length and an ``IOHeader`` FlatBuffer
(``IOHE``: compression, ``dataTablePosition``, ``infoNode`` XML naming each
stream: id, ``typeIdentifier``, ``sizeX``/``sizeY``), then packets (int32
stream id, int32 size, compressed size-prefixed FlatBuffer; see
:mod:`tectum.sources.files.aedat4_codec`), then, at ``dataTablePosition``,
the compressed ``FileDataTable`` (``FTAB``: per packet its byte offset,
stream id, size, element count and first/last timestamp; the byte offset
is the payload's, 8 bytes after its packet header).

The packet table gives ``info()`` without decoding, and a time range is read
by decoding only the packets that overlap it. Timestamps are absolute µs
(DV's ``tsOffset`` is already included; it is reported as ``t0_offset``
but never added again).
"""

from __future__ import annotations

import functools
import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from concurrent.futures import Future, wait
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from tectum import FramePacket, Kind, Packet, SamplePacket

from . import _aedat4_kernels as AK
from . import _lz4
from . import aedat4_codec as codec
from ._common import HUGE_SET, EventAssembler, FileSource, SampleTiler, byte_buffer, read_full, thread_count, workers
from ._flatbuf import FlatError, root

__all__ = ["Aedat4Source", "Stream", "PacketEntry", "read_io_header"]

MAGIC = b"#!AER-DAT4.0\r\n"
_MAX_PACKET = 1 << 30
#: Bytes read at a time, at most.
_READ_BYTES = 1 << 22
#: Packets of the packet table this close (bytes) are read together.
_GAP = 1 << 16
#: Events decoded into one set of columns, at most (unless one packet holds more).
_RUN_EVENTS = 1 << 22
#: Bytes of decompressed packets a thread takes at least.
_PART_BYTES = 1 << 19
#: Reads of at least this many bytes go into buffers of huge pages (see :func:`_read_buffer`).
_HUGE_READ = 1 << 20


@dataclass
class Stream:
    id: int
    type_id: str
    name: str
    sensor: tuple[int, int] | None
    ts_offset: int
    compression: str


@dataclass
class PacketEntry:
    offset: int
    stream: int
    size: int
    elements: int
    t_first: int
    t_last: int


def parse_info_node(xml: str) -> dict[int, Stream]:
    """Streams declared by an IOHeader ``infoNode`` XML document (each call
    its own :class:`Stream` objects; the parse of a document is cached:
    ~0.1 ms, 3 % of decoding a 2.6 MB file, for a file opened again)."""
    return {s.id: Stream(**vars(s)) for s in _parse_info_node(xml)}  # not copy.copy: 3x its speed


@functools.lru_cache(maxsize=16)
def _parse_info_node(xml: str) -> tuple[Stream, ...]:
    """:func:`parse_info_node`'s streams, parsed once per document."""
    out: dict[int, Stream] = {}
    doc = ET.fromstring(xml.strip().rstrip("\0").strip() or "<dv/>")
    info = next((n for n in doc.iter("node") if n.get("name") == "outInfo"), None)
    if info is None:
        return ()
    for node in info.findall("node"):
        try:
            sid = int(node.get("name", ""))
        except ValueError:
            continue
        attrs = {a.get("key"): (a.text or "") for a in node.findall("attr")}
        sub = next((n for n in node.findall("node") if n.get("name") == "info"), None)
        inner = {a.get("key"): (a.text or "") for a in sub.findall("attr")} if sub is not None else {}
        sensor = None
        if "sizeX" in inner and "sizeY" in inner:
            sensor = (int(inner["sizeX"]), int(inner["sizeY"]))
        out[sid] = Stream(sid, attrs.get("typeIdentifier", ""), attrs.get("originalOutputName", str(sid)),
                          sensor, int(inner.get("tsOffset", "0") or 0), attrs.get("compression", ""))
    return tuple(out.values())


def read_io_header(f: Any, path: str) -> tuple[int, int, str, int]:
    """(compression code, data table position, infoNode XML, first packet offset)."""
    from tectum import FormatError

    f.seek(0)
    magic = f.read(len(MAGIC))
    if magic != MAGIC:
        raise FormatError("not an AEDAT 4.0 file (no #!AER-DAT4.0 line)", path=path, offset=0)
    nb = f.read(4)
    if len(nb) < 4:
        raise FormatError("file ends inside the IOHeader length (truncated)", path=path, offset=len(MAGIC))
    n = struct.unpack("<i", nb)[0]
    if n <= 8 or n > 1 << 24:
        raise FormatError(f"IOHeader length {n} is implausible", path=path, offset=len(MAGIC))
    buf = f.read(n)
    if len(buf) < n:
        raise FormatError("file ends inside the IOHeader (truncated)", path=path, offset=len(MAGIC) + 4)
    try:
        tab = root(buf, ident=b"IOHE")
        comp = tab.scalar(0, "i", 0)
        dtp = tab.scalar(1, "q", -1)
        xml = tab.string(2)
    except FlatError as e:
        raise FormatError(f"corrupt IOHeader: {e}", path=path, offset=len(MAGIC) + 4) from None
    if comp not in codec.COMPRESSION.values():
        raise FormatError(f"unknown compression code {comp}", path=path, offset=len(MAGIC) + 4)
    return comp, dtp, xml, len(MAGIC) + 4 + n


class Aedat4Source(FileSource):
    """Events, frames and IMU samples from AEDAT 4.0 files.

    Parameters (besides :class:`FileSource`'s)
    ------------------------------------------
    use_index:
        Use the file's packet table to read only the packets in the time
        range, and to skip frames when they are not asked for (default);
        off, every packet is read.
    streams:
        Comma-separated kinds to decode (``events,frames,imu,triggers``, the
        default); packets of other streams are skipped undecompressed.
    threads:
        Threads decoding LZ4 event packets, this one included (0, the
        default: one per CPU, at most 4; 1: this thread only).

    Event packets are decoded a read (up to ``chunk_bytes``) at a time:
    LZ4 frames are decompressed and split into columns in compiled code
    (calling the liblz4 inside the ``lz4`` package), on up to ``threads``
    threads, into one :class:`tectum.EventPacket` per read rather than one
    per file packet; other compressions go through Python one packet at a
    time. Only the first events stream is read (one sensor per source).

    With ``skip_bad``, a packet that does not decode is skipped and counted
    in :attr:`skipped_events` as the elements (events, samples, frames) the
    packet table lists for it (1 when the file has no table); when a packet
    header is broken, reading resumes at the next packet the table lists.
    """

    name = "aedat4"
    format = "aedat4"
    extensions = (".aedat4",)
    produces = (Kind.EVENTS, Kind.FRAMES, Kind.IMU, Kind.TRIGGERS)

    def __init__(self, path: str, use_index: bool = True, streams: str = "events,frames,imu,triggers",
                 threads: int = 0, **kw: Any) -> None:
        super().__init__(path, **kw)
        self.use_index = use_index
        self.threads = thread_count(threads)
        names = {"events": "EVTS", "frames": "FRME", "imu": "IMUS", "triggers": "TRIG"}
        wanted = [w.strip() for w in streams.split(",") if w.strip()]
        if not set(wanted) <= set(names):
            raise ValueError(f"streams must be among {list(names)}, got {streams!r}")
        self._kinds = {names[w] for w in wanted}
        self._tab: np.ndarray | None = None  # the packet table, for skip_bad's counts and resumption

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"#!AER-DAT4.0")

    def _open_header(self) -> tuple[Any, int, int, dict[int, Stream], int]:
        f = self._open()
        comp, dtp, xml, start = read_io_header(f, self.path)
        try:
            streams = parse_info_node(xml)
        except (ET.ParseError, ValueError) as e:  # ValueError: a number attribute (sizeX, tsOffset) is not one
            self._fail(f"infoNode XML does not parse: {e}", len(MAGIC) + 4)
        self.compression = comp
        self.streams = streams
        ev = [s for s in streams.values() if s.type_id == "EVTS"]
        self.t0_offset = ev[0].ts_offset if ev else 0
        return f, comp, dtp, streams, start

    def packet_table(self) -> list[PacketEntry] | None:
        """The file's packet table, or None when it has none (or it is corrupt)."""
        try:  # a header that fails (an empty or corrupt file) closes the file too
            f, comp, dtp, _, start = self._open_header()
            tab = self._table(f, comp, dtp, start)
        finally:
            self.close()
        return None if tab is None else [PacketEntry(*r) for r in tab.tolist()]

    def _table(self, f: Any, comp: int, dtp: int, start: int) -> np.ndarray | None:
        """The packet table as rows of :func:`aedat4_codec.table_of`, or None."""
        size = f.seek(0, 2)
        if dtp < start or dtp >= size:
            return None
        f.seek(dtp)
        try:
            return codec.table_of(codec.decompress(f.read(size - dtp), comp))
        except (ValueError, FlatError):
            return None

    def _packets(self) -> Iterator[Packet]:
        f, comp, dtp, streams, start = self._open_header()
        ev_ids = [s.id for s in streams.values() if s.type_id == "EVTS"]
        sensor = self._sensor(streams[ev_ids[0]].sensor if ev_ids else None)
        if ev_ids and sensor is None:
            self._fail("the events stream declares no sizeX/sizeY: give sensor=WxH")
        limit = dtp if dtp >= start else f.seek(0, 2)
        want = {s.id for s in streams.values() if s.type_id in self._kinds}
        lo = self.t_start_us if self.t_start_us is not None else -(1 << 62)
        hi = self.t_end_us if self.t_end_us is not None else 1 << 62
        ranged = self.t_start_us is not None or self.t_end_us is not None
        # the table also saves reading frames (most of a DAVIS file) when they are not asked for
        frames_unread = any(s.type_id == "FRME" and s.id not in want for s in streams.values())
        wants_table = self.use_index and (ranged or frames_unread or self.skip_bad)
        entries = self._table(f, comp, dtp, start) if wants_table else None
        self._tab = entries if self.skip_bad else None
        if entries is not None and (ranged or frames_unread) and (ranged or _tiles(entries, start, dtp)):
            pick = np.isin(entries[:, 1], list(want)) & (entries[:, 5] >= lo) & (entries[:, 4] < hi)
            chunks = self._indexed(f, entries[pick, 0] - 8, entries[pick, 0] + entries[pick, 2], comp)
        else:
            chunks = self._chunks(f, start, limit, comp)
        kinds = {s.id: s.type_id for s in streams.values() if s.type_id in self._kinds}
        batch = _Batch(self, comp, sensor, ev_ids[0] if ev_ids else None, kinds)
        for buf, rows in chunks:
            batch.add(buf, rows)
            yield from batch.flush()  # while the chunk is still in cache
            if batch.done():
                break
        yield from batch.finish()

    def _chunks(self, f: Any, start: int, limit: int, comp: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """(buffer, rows) per read of about ``chunk_bytes``: the rows of
        :func:`scan_packets` for the complete packets in the buffer, with
        the file offset of each packet's header appended. A packet cut by
        the end of a read starts the next buffer; a buffer is never
        overwritten while a row's view of it lives (it comes from the
        buffer pool)."""
        rows = np.empty((4096, 9), np.int64)
        lz4 = comp in (1, 2)
        carry = np.empty(0, np.uint8)
        need = 8
        pos = start  # next unread byte
        f.seek(pos)
        while True:
            base = pos - carry.shape[0]
            n = min(max(min(self.chunk_bytes, _READ_BYTES), need), limit - base)
            if n <= 0:
                return
            buf = _read_buffer(n)
            buf[:carry.shape[0]] = carry
            have = carry.shape[0] + read_full(f, buf[carry.shape[0]:n])
            pos = base + have
            i, status = 0, 0
            while True:
                k, i, status = AK.scan_packets(buf, i, have, _MAX_PACKET, lz4, rows, base)
                if k:
                    yield buf, rows[:k].copy()
                if k < rows.shape[0] or status:
                    break
            if status or (i < have and (have < n or pos >= limit)):  # broken, or cut by the end of the data
                resume = self._bad_tail(buf, base, i, have, limit)
                if resume is None:
                    return
                pos, carry, need = resume, carry[:0], 8
                f.seek(pos)
                continue
            if have < n:
                return
            carry = buf[i:have].copy()
            need = 8 + int.from_bytes(carry[4:8].tobytes(), "little") if carry.shape[0] >= 8 else 8

    def _bad_tail(self, buf: np.ndarray, base: int, i: int, have: int, limit: int) -> int | None:
        """The data ends (or breaks) at ``buf[i]`` inside a packet: raise, or
        with ``skip_bad`` count what is lost as skipped and return where the
        next packet the table lists starts (None: nothing to resume at)."""
        at = base + i
        if not self.skip_bad:
            if have - i < 8:
                self._fail("file ends inside a packet header (truncated)", at)
            sid, size = struct.unpack_from("<ii", buf.data, i)
            self._fail(f"packet size {size} (stream {sid}) runs past the end of the data (truncated or corrupt)", at)
        heads = self._tab[:, 0] - 8 if self._tab is not None else np.empty(0, np.int64)
        after = heads[heads > at]
        resume = int(after.min()) if after.shape[0] else None
        end = limit if resume is None else resume
        self._note_skip(at, end - 1, self.lost(at, end))
        return resume

    def lost(self, first: int, end: int) -> int:
        """Elements (events, samples, frames) the packet table lists in the
        packets whose headers lie in ``[first, end)``: what a skip of those
        bytes loses (1 when the file has no table, or lists none there)."""
        if self._tab is None:
            return 1
        heads = self._tab[:, 0] - 8
        inside = (heads >= first) & (heads < end)
        return int(self._tab[inside, 3].sum()) if inside.any() else 1

    def _indexed(self, f: Any, heads: np.ndarray, ends: np.ndarray,
                 comp: int) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Chunks (as :meth:`_chunks`) holding the packets ``[heads[k],
        ends[k])`` (file offsets) the packet table points at, read into one
        buffer up to ``_READ_BYTES`` at a time. Packets less than ``_GAP``
        apart are read together, with what lies between (skipped later like
        any unwanted packet); larger gaps are seeked over."""
        order = np.argsort(heads, kind="stable")
        spans: list[tuple[int, int, list[int]]] = []  # (start, end, headers of the packets asked for)
        for a, b in zip(heads[order].tolist(), ends[order].tolist()):
            if spans and a - spans[-1][1] < _GAP and b - spans[-1][0] <= _READ_BYTES:
                spans[-1][2].append(a)
                spans[-1] = (spans[-1][0], max(spans[-1][1], b), spans[-1][2])
            else:
                spans.append((a, b, [a]))
        i = 0
        while i < len(spans):
            j, size = i, 0
            while j < len(spans) and (j == i or size + spans[j][1] - spans[j][0] <= _READ_BYTES):
                size += spans[j][1] - spans[j][0]
                j += 1
            buf = _read_buffer(size)
            at = np.empty(j - i, np.int64)  # where each span starts in the buffer
            o = 0
            for k, (a, b, _) in enumerate(spans[i:j]):
                at[k] = o
                f.seek(a)
                got = read_full(f, buf[o:o + b - a])
                if got < b - a:
                    self._fail("file ends inside a packet (truncated)", a + got)
                o += got
            first = np.array([s[0] for s in spans[i:j]], np.int64)
            asked = np.array([a for sp in spans[i:j] for a in sp[2]], np.int64)
            sp = np.searchsorted(first, asked, side="right") - 1
            into = at[sp] + asked - first[sp]  # where each asked packet starts in buf
            rows = self._scan_all(buf, comp, np.sort(into))
            span = np.searchsorted(at, rows[:, 0] - 8, side="right") - 1
            rows[:, 8] = first[span] + rows[:, 0] - 8 - at[span]
            missing = asked[~np.isin(asked, rows[:, 8])]
            if missing.shape[0] and not self.skip_bad:
                self._fail("packet table entry does not match the packet header", int(missing[0]))
            for a in missing.tolist():
                self._note_skip(a, a + 7, self.lost(a, a + 1))
            yield buf, rows
            i = j

    def _scan_all(self, buf: np.ndarray, comp: int, starts: np.ndarray) -> np.ndarray:
        """The rows of the packets in ``buf`` (from its start, while they
        parse; where one does not, from the next of ``starts``, the buffer
        offsets of the packets the table lists), with room for the file
        offset (the last column)."""
        rows = np.empty((4096, 9), np.int64)
        found, at = [], 0
        while at < buf.shape[0]:
            k, at, _ = AK.scan_packets(buf, at, buf.shape[0], _MAX_PACKET, comp in (1, 2), rows)
            if k:
                found.append(rows[:k].copy())
            if k < rows.shape[0] and at < buf.shape[0]:  # stopped at a broken header: resume after it
                nxt = starts[starts > at]
                if not nxt.shape[0]:
                    break
                at = int(nxt[0])
        return np.concatenate(found) if found else rows[:0].copy()

    def info(self) -> dict[str, Any]:
        """From the packet table when there is one (no decoding: the counts
        are the table's, and a packet that does not decode goes unnoticed;
        ``indexed`` says so), else, or with ``use_index=False``, by decoding
        every packet."""
        entries = self.packet_table() if self.use_index else None
        if entries is None or self.t_start_us is not None or self.t_end_us is not None:
            return super().info()
        ev_ids = {s.id for s in self.streams.values() if s.type_id == "EVTS"}
        kinds = {"EVTS": "events", "FRME": "frames", "IMUS": "imu", "TRIG": "triggers"}
        counts: dict[str, int] = {}
        for e in entries:
            s = self.streams.get(e.stream)
            k = kinds.get(s.type_id, s.type_id) if s else str(e.stream)
            counts[k] = counts.get(k, 0) + e.elements
        ev = [e for e in entries if e.stream in ev_ids]
        first = min((e.t_first for e in ev), default=None)
        last = max((e.t_last for e in ev), default=None)
        n = counts.get("events", 0)
        dur = (last - first) if first is not None and last is not None else 0
        sensor = next((s.sensor for s in self.streams.values() if s.id in ev_ids), None)
        return {"format": self.format, "path": self.path, "sensor": sensor, "events": n, "t_first_us": first,
                "t_last_us": last, "duration_us": dur, "rate_mev_s": n / dur if dur > 0 else 0.0,
                "streams": counts, "t0_offset_us": self.t0_offset, "compression": self.compression,
                "indexed": True, "skipped_events": 0}


class _Batch:
    """The packets of a read, decoded together per stream when it is
    flushed: event packets into one set of columns, IMU, trigger and frame
    packets into one packet each (LZ4 frames decompressed in compiled
    code)."""

    _DECODERS = {"IMUS": codec.imus_of, "TRIG": codec.triggers_of}

    def __init__(self, src: Aedat4Source, comp: int, sensor: tuple[int, int] | None, ev_id: int | None,
                 kinds: dict[int, str]) -> None:
        self.src = src
        self.comp = comp
        self.ev_id = ev_id
        self.kinds = kinds  # stream id -> type of the streams asked for
        self.asm = EventAssembler(src, sensor) if sensor is not None else None
        self.tiler = SampleTiler(src)
        self.events: list[tuple[np.ndarray, np.ndarray]] = []
        self.samples: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}

    def add(self, buf: np.ndarray, rows: np.ndarray) -> None:
        """The packets ``rows`` (of :meth:`Aedat4Source._chunks`) in ``buf``,
        decoded by :meth:`flush`."""
        for sid, type_id in self.kinds.items():
            mine = rows[rows[:, 2] == sid]
            if not mine.shape[0]:
                continue
            if sid == self.ev_id:
                self.events.append((buf, mine))
            elif type_id in self._DECODERS or type_id == "FRME":
                self.samples.setdefault(sid, []).append((buf, mine))

    def _decompressed(self, sid: int, payload: memoryview, pos: int) -> Any:
        """A packet decompressed in Python; None when it does not decompress
        (and ``skip_bad``)."""
        d = _inflate(payload, self.comp)
        if isinstance(d, ValueError):
            self._bad(sid, f"does not decompress: {d}", pos, len(payload))
            return None
        return d

    def done(self) -> bool:
        end = self.src.t_end_us
        return end is not None and self.asm is not None and self.asm.last_t is not None and self.asm.last_t >= end

    def _frames(self, sid: int, bufs: list[Any], poss: list[int]) -> Iterator[Packet]:
        """Frame packets decoded one by one, out as one packet per run of
        frames of the same size."""
        frames: list[tuple[SamplePacket, int]] = []
        for buf, pos in zip(bufs, poss):
            try:
                frames.append((codec._frames(buf, copy=False), pos))  # copied once, by the concatenation
            except (ValueError, struct.error) as e:
                self._bad(sid, f"does not decode: {e}", pos, len(buf))
        while frames:
            shape = frames[0][0].images.shape[1:]
            k = next((i for i, (q, _) in enumerate(frames) if q.images.shape[1:] != shape), len(frames))
            run, frames = frames[:k], frames[k:]
            data = {f: np.concatenate([q.data[f] for q, _ in run]) for f in run[0][0].data}
            out = self.tiler.push(FramePacket, sid, np.concatenate([q.t for q, _ in run]), run[0][1], **data)
            if out is not None:
                yield out

    def _decode(self, type_id: str, bufs: list[bytes], poss: list[int]) -> tuple[Any, list[int]]:
        """Decode IMU or trigger packets together; a malformed one is dropped
        (skip_bad) or reported with its file offset."""
        while True:
            try:
                sizes = np.fromiter((len(b) for b in bufs), np.int64, len(bufs))
                ends = np.cumsum(sizes)
                return self._DECODERS[type_id](b"".join(bufs), ends - sizes, ends), poss
            except FlatError as e:
                k = getattr(e, "packet", 0)
                if not self.src.skip_bad:
                    self.src._fail(f"packet of a {type_id} stream does not decode: {e}", poss[k])
                self.src._note_skip(poss[k], poss[k] + 8 + len(bufs[k]) - 1, self.src.lost(poss[k], poss[k] + 1))
                bufs, poss = bufs[:k] + bufs[k + 1:], poss[:k] + poss[k + 1:]

    def _bad(self, sid: int | None, what: str, pos: int, size: int) -> None:
        if not self.src.skip_bad:
            self.src._fail(f"packet of stream {sid} ({self.kinds.get(sid or 0, '?')}) {what}", pos)
        self.src._note_skip(pos, pos + 8 + size - 1, self.src.lost(pos, pos + 1))

    def _samples(self, sid: int, parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[list[Any], list[int]]:
        """The decompressed packets of an IMU or trigger stream, and where
        they are in the file."""
        bufs: list[Any] = []
        poss: list[int] = []
        for buf, rows in parts:
            starts = np.zeros(rows.shape[0], np.int64)
            ends = np.full(rows.shape[0], -2, np.int64)
            out = byte_buffer(int(rows[:, 5].sum()))
            if _lz4.AVAILABLE:
                AK.inflate_packets(buf, rows, out, starts, ends)
            mv = buf.data
            for (a, b, *_, at), s, e in zip(rows.tolist(), starts.tolist(), ends.tolist()):
                d = out[s:e] if e >= 0 else self._decompressed(sid, mv[a:b], at) if e == -2 else None
                if e == -1:
                    self._bad(sid, f"does not decompress: {_why(mv[a:b], self.comp)}", at, b - a)
                if d is not None:
                    bufs.append(d)
                    poss.append(at)
        return bufs, poss

    def _flush_events(self) -> Iterator[Packet]:
        """Decode the batch's event packets: runs of plain LZ4 blocks in
        compiled code (:func:`inflate_events`, on several threads), other
        packets one by one."""
        events, self.events = self.events, []
        for buf, rows in events:
            if _lz4.AVAILABLE:
                plan = AK.plan_run(rows, self.src.threads, _RUN_EVENTS, _PART_BYTES)
                if plan[0]:  # the common case: one run (no search for its end)
                    yield from self._inflate_run(buf, rows, plan)
                    continue
            fast = (rows[:, 3] >= 0) & _lz4.AVAILABLE
            room = np.cumsum(np.where(fast, rows[:, 5] // 16, 0))  # events each packet can hold, summed
            k = 0
            while k < rows.shape[0]:
                if not fast[k]:
                    yield from self._one(buf.data[rows[k, 0]:rows[k, 1]], int(rows[k, 8]))
                    k += 1
                    continue
                # a run of plain LZ4 packets whose events fit in _RUN_EVENTS (at least one packet)
                j = max(k + 1, int(np.searchsorted(room, (room[k - 1] if k else 0) + _RUN_EVENTS, side="right")))
                if not fast[k:j].all():
                    j = k + int(np.argmin(fast[k:j]))
                yield from self._inflate_run(buf, rows[k:j])
                k = j

    def _inflate_run(self, buf: np.ndarray, rows: np.ndarray, plan: Any = None) -> Iterator[Packet]:
        """Plain LZ4 event packets: parts of the run go to ``threads``
        threads (the kernel releases the GIL), each into its own stretch of
        one reservation of columns, committed in turn where it lies (see
        :meth:`EventAssembler.resume_at`; moved only when the run of equal
        times held back from the part before does not fit in the gap). A
        part no worker has started when this thread ends its own, this
        thread decodes: on a loaded machine the woken worker often waits for
        a CPU, and this thread waited for it (wall 2973-3076 against
        2871-2893 us a decode, its upper quartile 5988-6117 against
        3134-3232; CPU 1.3-2 % less; dvxplorer_2, 201 alternated rounds x 3).
        Tried, no gain: every part's arguments made before a worker is woken
        and the worker calling the kernel itself (no frame of ours), so it
        would not wake to a GIL this thread holds: 0.994x the CPU, voluntary
        context switches 4.04 -> 4.06 a decode (201 rounds, loaded); a
        1-thread pool in place of the shared 3: 0.998x; this thread taking 8
        or 15 % more than an equal share: 0.996x (loaded).
        ``plan``: :func:`plan_run` of the rows, when already made."""
        assert self.asm is not None
        _, c, a, size = plan if plan is not None else AK.plan_run(rows, self.src.threads, _RUN_EVENTS, _PART_BYTES)
        cuts, at, scratch = c.tolist(), a.tolist(), int(size)
        w = len(cuts) - 1
        cols = self.asm.reserve(at[-1])
        counts = np.zeros(rows.shape[0], np.int64)

        def part(i: int) -> tuple[int, bool, int, int]:
            n, _, rising, mx, my = AK.inflate_events(buf, rows[cuts[i]:cuts[i + 1]], 0, byte_buffer(scratch),
                                                     *(c[at[i]:at[i + 1]] for c in cols),
                                                     counts[cuts[i]:cuts[i + 1]])
            return n, rising, mx, my

        futures = [workers().submit(part, i) for i in range(1, w)]
        try:
            parts = [part(0)]
            for i, fu in enumerate(futures, 1):  # a part no worker has started yet: this thread's
                parts.append(part(i) if fu.cancel() else fu.result())
        except BaseException:  # an error or a Ctrl-C: no worker left writing into the columns given up
            _finish(futures)
            raise
        pos = rows[:, 8]
        for i in np.flatnonzero(counts < 0).tolist():
            size = int(rows[i, 1] - rows[i, 0])
            if counts[i] == -1:
                self._bad(self.ev_id, "does not decode: malformed EventPacket FlatBuffer", int(pos[i]), size)
            else:
                why = _why(buf.data[rows[i, 0]:rows[i, 1]], self.comp)
                self._bad(self.ev_id, f"does not decompress: {why}", int(pos[i]), size)
        for i, (n, rising, mx, my) in enumerate(parts):
            if i and not self.asm.resume_at(at[i]):
                for a, c in zip(self.asm.reserve(n), cols):
                    a[:n] = c[at[i]:at[i] + n]
            p, k = pos[cuts[i]:cuts[i + 1]], counts[cuts[i]:cuts[i + 1]]
            yield from self.asm.commit(n, int(p[0]), partial(_where, p, k), (rising, mx, my))

    def _one(self, payload: memoryview, pos: int) -> Iterator[Packet]:
        """One event packet, decompressed in Python."""
        assert self.asm is not None and self.ev_id is not None
        d = self._decompressed(self.ev_id, payload, pos)
        if d is None:
            return
        t, x, y, p = self.asm.reserve(len(d) // 16)
        n = AK.fill_events(np.frombuffer(d, np.uint8), 0, t, x, y, p)
        if n < 0:
            self._bad(self.ev_id, "does not decode: malformed EventPacket FlatBuffer", pos, len(payload))
            n = 0
        yield from self.asm.commit(n, pos)

    def flush(self) -> Iterator[Packet]:
        if self.events:
            yield from self._flush_events()
        samples, self.samples = self.samples, {}
        for sid, parts in samples.items():
            bufs, poss = self._samples(sid, parts)
            if not bufs:
                continue
            type_id = self.kinds[sid]
            if type_id == "FRME":
                yield from self._frames(sid, bufs, poss)
                continue
            out, poss = self._decode(type_id, bufs, poss)
            if not poss:  # every packet was bad (and skipped)
                continue
            q = self.tiler.push(type(out), sid, out.t, poss[0], **out.data)
            if q is not None:
                yield q

    def finish(self) -> Iterator[Packet]:
        if self.asm is not None:
            yield from self.asm.finish()


def _read_buffer(n: int) -> np.ndarray:
    """A pooled buffer of ``n`` bytes to read into: from :data:`_HUGE_READ`
    bytes on, the start of a set of at least :data:`HUGE_SET` bytes, which
    the pool carves from a block of 2 MiB huge pages, so the kernel's copy
    into it and the decompression reading it miss the TLB once per 2 MiB,
    not per 4 KiB page: the dvxplorer recording's 2.6 MB read took 218
    against 358 us of CPU (caches evicted, 200 alternating rounds, loaded).
    Smaller reads take a set of their size (a huge page is zeroed when first
    touched, ~0.1 ms: not for a small file read once)."""
    return byte_buffer(n) if n < _HUGE_READ else byte_buffer(max(n, HUGE_SET))[:n]


def _finish(futures: list[Future[Any]]) -> None:
    """Wait until the ``futures`` (of :func:`workers`) have ended, those not
    started cancelled; a Ctrl-C meanwhile is raised once they have."""
    for fu in futures:
        fu.cancel()
    interrupted = None
    while True:
        try:
            wait(futures)
            break
        except KeyboardInterrupt as e:  # the parts run for milliseconds: wait them out, then stop
            interrupted = e
    if interrupted is not None:
        raise interrupted


def _inflate(payload: memoryview, comp: int) -> Any:
    """A packet's decompressed FlatBuffer, or the ValueError saying why it
    does not decompress."""
    if comp == 0:
        return payload
    try:
        return codec.decompress(payload, comp)
    except ValueError as e:
        return e


def _why(payload: memoryview, comp: int) -> str:
    """Why a packet does not decompress, in the words of the frame decoder."""
    e = _inflate(payload, comp)
    return str(e) if isinstance(e, ValueError) else "corrupt LZ4 block"


def _where(pos: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The file offset of each event decoded from packets at ``pos`` (their
    headers) holding ``counts`` events each (below 0: none)."""
    good = counts > 0
    return np.repeat(pos[good], counts[good])


def _tiles(table: np.ndarray, start: int, end: int) -> bool:
    """Whether the table's packets cover ``[start, end)`` exactly, one after
    the other (then reading only some streams' packets loses nothing)."""
    tab = table[np.argsort(table[:, 0], kind="stable")]
    heads, ends = tab[:, 0] - 8, tab[:, 0] + tab[:, 2]
    return bool(tab.shape[0] and heads[0] == start and ends[-1] == end and np.array_equal(heads[1:], ends[:-1]))
