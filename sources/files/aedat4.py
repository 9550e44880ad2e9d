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

import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from tectum import EventPacket, Kind, Packet, SamplePacket

from . import aedat4_codec as codec
from ._common import EventAssembler, FileSource, SampleTiler
from ._flatbuf import FlatError, root

__all__ = ["Aedat4Source", "Stream", "PacketEntry", "read_io_header"]

MAGIC = b"#!AER-DAT4.0\r\n"
_MAX_PACKET = 1 << 30


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
    """Streams declared by an IOHeader ``infoNode`` XML document."""
    out: dict[int, Stream] = {}
    doc = ET.fromstring(xml.strip().rstrip("\0").strip() or "<dv/>")
    info = next((n for n in doc.iter("node") if n.get("name") == "outInfo"), None)
    if info is None:
        return out
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
    return out


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
        Use the file's packet table to skip packets outside the time range
        (default); off, every packet is walked.
    streams:
        Comma-separated kinds to decode (``events,frames,imu,triggers``, the
        default); packets of other streams are skipped undecompressed.

    Event packets are decoded many at a time (up to ``chunk_bytes`` of
    events): one FlatBuffer walk in compiled code per batch, one
    :class:`tectum.EventPacket` out per batch rather than per file packet.
    Only the first events stream is read (one sensor per source).
    """

    name = "aedat4"
    format = "aedat4"
    extensions = (".aedat4",)
    produces = (Kind.EVENTS, Kind.FRAMES, Kind.IMU, Kind.TRIGGERS)

    def __init__(self, path: str, use_index: bool = True, streams: str = "events,frames,imu,triggers",
                 **kw: Any) -> None:
        super().__init__(path, **kw)
        self.use_index = use_index
        names = {"events": "EVTS", "frames": "FRME", "imu": "IMUS", "triggers": "TRIG"}
        wanted = [w.strip() for w in streams.split(",") if w.strip()]
        if not set(wanted) <= set(names):
            raise ValueError(f"streams must be among {list(names)}, got {streams!r}")
        self._kinds = {names[w] for w in wanted}

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"#!AER-DAT4.0")

    def _open_header(self) -> tuple[Any, int, int, dict[int, Stream], int]:
        f = self._open()
        comp, dtp, xml, start = read_io_header(f, self.path)
        try:
            streams = parse_info_node(xml)
        except ET.ParseError as e:
            self._fail(f"infoNode XML does not parse: {e}", len(MAGIC) + 4)
        self.compression = comp
        self.streams = streams
        ev = [s for s in streams.values() if s.type_id == "EVTS"]
        self.t0_offset = ev[0].ts_offset if ev else 0
        return f, comp, dtp, streams, start

    def packet_table(self) -> list[PacketEntry] | None:
        """The file's packet table, or None when it has none (or it is corrupt)."""
        f, comp, dtp, _, start = self._open_header()
        try:
            return self._table(f, comp, dtp, start)
        finally:
            self.close()

    def _table(self, f: Any, comp: int, dtp: int, start: int) -> list[PacketEntry] | None:
        size = f.seek(0, 2)
        if dtp < start or dtp >= size:
            return None
        f.seek(dtp)
        try:
            buf = codec.decompress(f.read(size - dtp), comp)
            tab = root(buf, size_prefixed=True, ident=b"FTAB")
            out = []
            for e in tab.tables(0):
                at = e.struct_at(1, 8)
                sid, sz = struct.unpack_from("<ii", buf, at) if at is not None else (0, 0)
                out.append(PacketEntry(e.scalar(0, "q"), sid, sz, e.scalar(2, "q"), e.scalar(3, "q"),
                                       e.scalar(4, "q")))
            return out
        except (ValueError, FlatError, struct.error):
            return None

    def _packets(self) -> Iterator[Packet]:
        f, comp, dtp, streams, start = self._open_header()
        ev_ids = [s.id for s in streams.values() if s.type_id == "EVTS"]
        sensor = self._sensor(streams[ev_ids[0]].sensor if ev_ids else None)
        if ev_ids and sensor is None:
            self._fail("the events stream declares no sizeX/sizeY: give sensor=WxH")
        limit = dtp if dtp >= start else f.seek(0, 2)
        entries = None
        if self.use_index and (self.t_start_us is not None or self.t_end_us is not None):
            entries = self._table(f, comp, dtp, start)
        if entries is not None:
            lo = self.t_start_us if self.t_start_us is not None else -(1 << 62)
            hi = self.t_end_us if self.t_end_us is not None else 1 << 62
            offsets = [(e.offset, e.stream, e.size) for e in entries if e.t_last >= lo and e.t_first < hi]
        else:
            offsets = None
        batch = _Batch(self, comp, sensor, ev_ids[0] if ev_ids else None)
        want = {s.id for s in streams.values() if s.type_id in self._kinds}
        for pos, sid, payload in self._walk(f, start, limit, offsets, want):
            s = streams.get(sid)
            if s is None or s.type_id not in self._kinds:
                continue
            try:
                buf = codec.decompress(payload, comp)
            except ValueError as e:
                if not self.skip_bad:
                    self._fail(f"packet of stream {sid} ({s.type_id}) does not decompress: {e}", pos)
                self._note_skip(pos, pos + 8 + len(payload) - 1, 1)
                continue
            if s.type_id == "FRME":
                yield from batch.frame(sid, buf, pos)
            elif s.type_id != "EVTS" or sid == batch.ev_id:
                batch.add(s.type_id, sid, buf, pos)
            if batch.full():
                yield from batch.flush()
                if batch.done():
                    break
        yield from batch.flush()
        yield from batch.finish()

    def _walk(self, f: Any, start: int, limit: int, offsets: list[tuple[int, int, int]] | None,
              want: set[int] | None = None) -> Iterator[tuple[int, int, bytes]]:
        """(file offset, stream id, payload) of each packet (in ``want``, a
        set of stream ids, when given)."""
        if offsets is not None:
            for off, sid, size in offsets:  # the table points at payloads, after the 8-byte header
                f.seek(off - 8)
                hdr = f.read(8)
                if len(hdr) < 8 or struct.unpack("<ii", hdr) != (sid, size):
                    self._fail("packet table entry does not match the packet header", off - 8)
                yield off - 8, sid, self._payload(f, off - 8, size, limit)
            return
        pos = start
        f.seek(pos)
        buf = bytearray(max(self.chunk_bytes, 64))  # reused: a payload is consumed before the next refill
        base = have = 0  # buf[:have] holds the file from offset base

        def refill(need: int) -> None:
            """Make buf hold [pos, pos + need) when the file has it."""
            nonlocal buf, base, have
            keep = max(0, have - (pos - base))
            if need > len(buf):
                grown = bytearray(need)
                grown[:keep] = buf[have - keep:have]
                buf = grown
            elif keep:
                buf[:keep] = buf[have - keep:have]
            base, have = pos, keep
            if keep == 0:
                f.seek(pos)
            view = memoryview(buf)
            while have < len(buf):
                got = f.readinto(view[have:])
                if not got:
                    break
                have += got

        while pos < limit:
            if pos + 8 > base + have:
                refill(8)
            if base + have - pos < 8:
                if not self.skip_bad:
                    self._fail("file ends inside a packet header (truncated)", pos)
                self._note_skip(pos, limit - 1, 1)
                return
            sid, size = struct.unpack_from("<ii", buf, pos - base)
            if size < 0 or size > _MAX_PACKET or pos + 8 + size > limit:
                if not self.skip_bad:
                    self._fail(f"packet size {size} (stream {sid}) runs past the end of the data "
                               "(truncated or corrupt)", pos)
                self._note_skip(pos, limit - 1, 1)
                return
            end = pos + 8 + size
            if want is not None and sid not in want:  # skipped unread
                pos = end
                continue
            if end > base + have:
                refill(end - pos)
                if end > base + have:
                    self._fail("file ends inside a packet (truncated)", pos)
            yield pos, sid, memoryview(buf)[pos - base + 8:end - base]
            pos = end

    def _payload(self, f: Any, pos: int, size: int, limit: int) -> bytes:
        data = f.read(size)
        if len(data) < size:
            self._fail("file ends inside a packet (truncated)", pos)
        return data

    def info(self) -> dict[str, Any]:
        """From the packet table when there is one (no decoding)."""
        entries = self.packet_table()
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
    """Decompressed packets waiting to be decoded together, per stream."""

    _DECODERS = {"IMUS": codec.imus_of, "TRIG": codec.triggers_of}

    def __init__(self, src: Aedat4Source, comp: int, sensor: tuple[int, int] | None, ev_id: int | None) -> None:
        self.src = src
        self.ev_id = ev_id
        self.asm = EventAssembler(src, sensor) if sensor is not None else None
        self.tiler = SampleTiler(src)
        self.parts: dict[tuple[str, int], tuple[list[bytes], list[int]]] = {}
        self.ev_bytes = 0

    def add(self, type_id: str, sid: int, buf: bytes, pos: int) -> None:
        bufs, poss = self.parts.setdefault((type_id, sid), ([], []))
        bufs.append(buf)
        poss.append(pos)
        if type_id == "EVTS":
            self.ev_bytes += len(buf)

    def full(self) -> bool:
        return self.ev_bytes >= self.src.chunk_bytes

    def done(self) -> bool:
        end = self.src.t_end_us
        return end is not None and self.asm is not None and self.asm.last_t is not None and self.asm.last_t >= end

    def frame(self, sid: int, buf: bytes, pos: int) -> Iterator[Packet]:
        try:
            pkt = codec.decode_packet("FRME", buf, 0)
        except (ValueError, struct.error) as e:
            if not self.src.skip_bad:
                self.src._fail(f"packet of stream {sid} (FRME) does not decode: {e}", pos)
            self.src._note_skip(pos, pos, 1)
            return
        assert isinstance(pkt, SamplePacket)
        out = self.tiler.push(type(pkt), sid, pkt.t, pos, **pkt.data)
        if out is not None:
            yield out

    def _decode(self, type_id: str, bufs: list[bytes], poss: list[int]) -> tuple[Any, list[int]]:
        """Decode the packets together; a malformed one is dropped (skip_bad)
        or reported with its file offset."""
        while True:
            try:
                if type_id == "EVTS":
                    return codec.events_of(bufs), poss
                sizes = np.fromiter((len(b) for b in bufs), np.int64, len(bufs))
                ends = np.cumsum(sizes)
                return self._DECODERS[type_id](b"".join(bufs), ends - sizes, ends), poss
            except FlatError as e:
                k = getattr(e, "packet", 0)
                if not self.src.skip_bad:
                    self.src._fail(f"packet of a {type_id} stream does not decode: {e}", poss[k])
                self.src._note_skip(poss[k], poss[k] + 8 + len(bufs[k]) - 1, 1)
                bufs, poss = bufs[:k] + bufs[k + 1:], poss[:k] + poss[k + 1:]

    def flush(self) -> Iterator[Packet]:
        parts, self.parts, self.ev_bytes = self.parts, {}, 0
        for (type_id, sid), (bufs, poss) in parts.items():
            if not bufs:
                continue
            out, poss = self._decode(type_id, bufs, poss)
            if type_id == "EVTS":
                assert self.asm is not None
                t, x, y, p, counts = out
                at = np.array(poss, np.int64)
                yield from self.asm.push(t, x, y, p, poss[0], lambda: np.repeat(at, counts))
            else:
                q = self.tiler.push(type(out), sid, out.t, poss[0], **out.data)
                if q is not None:
                    yield q

    def finish(self) -> Iterator[Packet]:
        if self.asm is not None:
            yield from self.asm.finish()
