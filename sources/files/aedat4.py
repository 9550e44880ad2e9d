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

from tectum import EventPacket, FramePacket, ImuPacket, Kind, Packet, SamplePacket

from . import aedat4_codec as codec
from ._common import EventAssembler, FileSource
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
    """

    name = "aedat4"
    format = "aedat4"
    extensions = (".aedat4",)
    produces = (Kind.EVENTS, Kind.FRAMES, Kind.IMU)

    def __init__(self, path: str, use_index: bool = True, **kw: Any) -> None:
        super().__init__(path, **kw)
        self.use_index = use_index

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
        asm = EventAssembler(self, sensor) if sensor is not None else None
        ends: dict[int, int] = {}
        for pos, sid, payload in self._walk(f, start, limit, offsets):
            s = streams.get(sid)
            if s is None or s.type_id not in ("EVTS", "FRME", "IMUS"):
                continue
            try:
                pkt = codec.decode_packet(s.type_id, payload, comp, sensor)
            except (ValueError, FlatError, struct.error) as e:
                if not self.skip_bad:
                    self._fail(f"packet of stream {sid} ({s.type_id}) does not decode: {e}", pos)
                self._note_skip(pos, pos + 8 + len(payload) - 1, 1)
                continue
            if isinstance(pkt, EventPacket):
                assert asm is not None
                yield from asm.push(pkt.t, pkt.x, pkt.y, pkt.p, pos)
                if self.t_end_us is not None and asm.last_t is not None and asm.last_t >= self.t_end_us:
                    break
            else:
                out = self._sample(pkt, sid, ends, pos)
                if out is not None:
                    yield out
        if asm is not None:
            yield from asm.finish()

    def _sample(self, pkt: Packet, sid: int, ends: dict[int, int], pos: int) -> Packet | None:
        """Clip to the time range, drop out-of-order samples, tile intervals."""
        assert isinstance(pkt, (FramePacket, ImuPacket))
        t = pkt.t
        keep = np.ones(len(t), bool)
        if self.t_start_us is not None:
            keep &= t >= self.t_start_us
        if self.t_end_us is not None:
            keep &= t < self.t_end_us
        prev = ends.get(sid)
        if prev is not None:
            late = t < prev
            if np.any(late & keep):
                if not self.skip_bad:
                    self._fail(f"stream {sid} timestamps decrease ({int(t[late][0])} µs after {prev - 1} µs)", pos)
                self._note_skip(pos, pos, int((late & keep).sum()))
                keep &= ~late
        if not keep.any():
            return None
        data = {k: v[keep] for k, v in pkt.data.items()}
        tk = t[keep]
        start = prev if prev is not None else int(tk[0])
        ends[sid] = int(tk[-1]) + 1
        cls: type[SamplePacket] = type(pkt)
        return cls(tk, t_start=start, t_end=ends[sid], **data)

    def _walk(self, f: Any, start: int, limit: int,
              offsets: list[tuple[int, int, int]] | None) -> Iterator[tuple[int, int, bytes]]:
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
        while pos < limit:
            hdr = f.read(8)
            if len(hdr) < 8:
                if not self.skip_bad:
                    self._fail("file ends inside a packet header (truncated)", pos)
                self._note_skip(pos, limit - 1, 1)
                return
            sid, size = struct.unpack("<ii", hdr)
            if size < 0 or size > _MAX_PACKET or pos + 8 + size > limit:
                if not self.skip_bad:
                    self._fail(f"packet size {size} (stream {sid}) runs past the end of the data "
                               "(truncated or corrupt)", pos)
                self._note_skip(pos, limit - 1, 1)
                return
            yield pos, sid, self._payload(f, pos, size, limit)
            pos += 8 + size

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
