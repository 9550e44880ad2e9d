"""iniVation's AEDAT 4.0 network stream (dv-processing ``dv::io::NetworkWriter``
/ ``NetworkReader``, DV's ``net_tcp_server`` / ``net_tcp_client``).

A connection carries, from the server to the client::

    int32 n | IOHeader FlatBuffer (n bytes, identifier ``IOHE``: compression,
              dataTablePosition = -1, infoNode XML declaring the streams)
    then packets: int32 stream id | int32 size | payload (size bytes)

Each payload is a size-prefixed FlatBuffer (``EVTS``, ``IMUS``, ``FRME``,
``TRIG``) compressed as the IOHeader says: exactly the packets of an AEDAT
4.0 file, so the codec is shared (:mod:`tectum.sources.files.aedat4_codec`).
There is no end marker: the server closing the connection ends the stream.

:class:`DvParser` cuts a byte stream into the header and packets with hard
limits (header and packet sizes), so hostile input costs at most
``max_packet`` bytes of memory; :class:`DvDecoder` turns packets into valid
tectum packets (events at the newest timestamp are held back until a later
time arrives, so equal timestamps never straddle two packets) and counts
what it rejects, by reason.
"""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from tectum import EventPacket, FramePacket, ImuPacket, Packet, TriggerPacket
from tectum.sources.files import aedat4_codec as codec
from tectum.sources.files._flatbuf import FlatError, build_table, root
from tectum.sources.files.aedat4 import Stream, parse_info_node

__all__ = ["StreamDecl", "io_header", "info_xml", "packet_bytes", "DvParser", "DvDecoder", "KINDS",
           "MAX_HEADER"]

#: tectum stream names -> (AEDAT4 type identifier, description)
KINDS = {"events": ("EVTS", "Array of events (polarity ON/OFF)."),
         "frames": ("FRME", "Standard frame (8-bit image)."),
         "imu": ("IMUS", "Inertial Measurement Unit data samples."),
         "triggers": ("TRIG", "External triggers and special signals.")}
MAX_HEADER = 1 << 20
_PKT = struct.Struct("<ii")


@dataclass(frozen=True)
class StreamDecl:
    """One declared stream: id, tectum kind name, and (events/frames) the
    image size in pixels."""

    id: int
    kind: str
    size: tuple[int, int] | None = None
    source: str = "tectum"


def info_xml(streams: list[StreamDecl], compression: int) -> str:
    """The IOHeader ``infoNode`` document (DV's config-tree XML)."""
    comp = {v: k for k, v in codec.COMPRESSION.items()}[compression].upper()
    out = ['<dv version="2.0">', '<node name="outInfo" path="/outInfo/">']
    for s in streams:
        type_id, _desc = KINDS[s.kind]
        p = f"/outInfo/{s.id}/"
        info = ""
        if s.size is not None:
            info += (f'<attr key="sizeX" type="int">{s.size[0]}</attr>'
                     f'<attr key="sizeY" type="int">{s.size[1]}</attr>')
        info += f'<attr key="source" type="string">{_xml_text(s.source)}</attr>'
        out.append(f'<node name="{s.id}" path="{p}">'
                   f'<attr key="compression" type="string">{comp}</attr>'
                   f'<attr key="originalModuleName" type="string">tectum</attr>'
                   f'<attr key="originalOutputName" type="string">{s.kind}</attr>'
                   f'<attr key="typeIdentifier" type="string">{type_id}</attr>'
                   f'<node name="info" path="{p}info/">{info}</node></node>')
    out.append("</node></dv>")
    return "\n".join(out)


def _xml_text(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def io_header(streams: list[StreamDecl], compression: int | str) -> bytes:
    """What a server sends first: int32 length, then the IOHeader FlatBuffer."""
    comp = codec.compression_code(compression)
    xml = info_xml(streams, comp).encode()
    buf = build_table([("i", comp), ("q", -1), None], b"IOHE", size_prefixed=False,
                      blob=xml + b"\0", blob_field=2, blob_align=4, blob_count=len(xml))
    return struct.pack("<i", len(buf)) + buf


def packet_bytes(stream_id: int, payload: bytes) -> bytes:
    """One packet on the wire: stream id, size, payload."""
    return _PKT.pack(stream_id, len(payload)) + payload


def parse_header(buf: bytes) -> tuple[int, dict[int, Stream]]:
    """(compression code, streams by id) of an IOHeader FlatBuffer;
    ValueError when malformed."""
    try:
        tab = root(buf, ident=b"IOHE")
        comp = tab.scalar(0, "i", 0)
        xml = tab.string(2)
        codec.compression_code(comp)
        streams = parse_info_node(xml)
    except (FlatError, ET.ParseError, struct.error, ValueError) as e:
        raise ValueError(f"malformed IOHeader: {e}") from None
    if not streams:
        raise ValueError("the IOHeader declares no streams")
    return comp, streams


@dataclass
class DvParser:
    """Cuts the server's byte stream into (stream id, payload) packets.

    ``feed`` takes any chunking; after the header, :attr:`compression` and
    :attr:`streams` are set. A header or packet over its size limit, or a
    malformed header, raises ValueError (the stream cannot be resynchronised:
    the caller drops the connection and counts it).
    """

    max_packet: int = 1 << 26
    compression: int | None = None
    streams: dict[int, Stream] | None = None
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes | bytearray | memoryview) -> list[tuple[int, bytes]]:
        self._buf += data
        buf = self._buf
        out: list[tuple[int, bytes]] = []
        pos = 0
        if self.streams is None:
            if len(buf) < 4:
                return out
            n = struct.unpack_from("<i", buf, 0)[0]
            if not 8 <= n <= MAX_HEADER:
                raise ValueError(f"IOHeader length {n} is implausible")
            if len(buf) < 4 + n:
                return out
            self.compression, self.streams = parse_header(bytes(buf[4:4 + n]))
            pos = 4 + n
        while len(buf) - pos >= 8:
            sid, size = _PKT.unpack_from(buf, pos)
            if not 0 <= size <= self.max_packet:
                raise ValueError(f"packet size {size} (stream {sid}) outside 0..{self.max_packet}")
            if len(buf) - pos < 8 + size:
                break
            out.append((sid, bytes(buf[pos + 8:pos + 8 + size])))
            pos += 8 + size
        del buf[:pos]
        return out

    @property
    def pending(self) -> int:
        """Bytes received but not yet part of a whole packet."""
        return len(self._buf)


class DvDecoder:
    """Decodes packets of the declared streams into tectum packets.

    Only the first events stream is read (one sensor per source); packets of
    undeclared or unread streams are counted in ``skipped``. Malformed
    packets (corrupt compression or FlatBuffer, events outside the sensor,
    time going backwards) are dropped and counted in ``rejected_<reason>``.
    """

    def __init__(self, compression: int, streams: dict[int, Stream], kinds: set[str],
                 max_held: int = 1 << 20) -> None:
        self.compression = compression
        self.streams = streams
        self.kinds = kinds
        self.max_held = max_held
        ev = [s for s in streams.values() if s.type_id == "EVTS"]
        self.ev_id = ev[0].id if ev and "events" in kinds else None
        self.sensor = ev[0].sensor if ev else None
        if self.ev_id is not None and (self.sensor is None or min(self.sensor) <= 0 or max(self.sensor) > 65535):
            raise ValueError(f"the events stream declares no usable sizeX/sizeY ({self.sensor})")
        self.counts: dict[str, int] = {"packets": 0, "events": 0, "samples": 0, "skipped": 0}
        self._held: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None  # t, x, y, p
        self._ev_end: int | None = None
        self._ends: dict[int, int] = {}

    def _reject(self, why: str) -> list[Packet]:
        k = "rejected_" + why
        self.counts[k] = self.counts.get(k, 0) + 1
        return []

    def decode(self, sid: int, payload: bytes) -> list[Packet]:
        s = self.streams.get(sid)
        kind = {"EVTS": "events", "FRME": "frames", "IMUS": "imu", "TRIG": "triggers"}.get(s.type_id) if s else None
        if s is None or kind not in self.kinds or (kind == "events" and sid != self.ev_id):
            self.counts["skipped"] += 1
            return []
        try:
            buf = codec.decompress(payload, self.compression)
            if kind == "events":
                t, x, y, p = codec.decode_events(buf)
                return self._events(t, x, y, p)
            pkt = codec.decode_packet(s.type_id, buf, 0)
        except ImportError:
            raise
        except (ValueError, struct.error, IndexError) as e:
            return self._reject("corrupt" if not isinstance(e, FlatError) else "flatbuffer")
        return self._samples(sid, pkt)

    def _events(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> list[Packet]:
        assert self.sensor is not None
        n = len(t)
        if n == 0:
            return []
        w, h = self.sensor
        if np.any(x >= w) or np.any(y >= h):
            return self._reject("bad_event")
        first = int(t[0]) if self._held is None else int(self._held[0][0])
        if np.any(t[1:] < t[:-1]) or (self._held is not None and int(t[0]) < first) or \
                (self._ev_end is not None and int(t[0]) < self._ev_end):
            return self._reject("time")
        self.counts["packets"] += 1
        self.counts["events"] += n
        if self._held is not None:
            t, x, y, p = (np.concatenate([a, b]) for a, b in zip(self._held, (t, x, y, p)))
        cut = int(t[-1])
        i = int(np.searchsorted(t, cut, side="left"))
        if len(t) - i > self.max_held:  # a hostile run of one timestamp: let it go
            i, cut = len(t), cut + 1
            self._reject("held")
        self._held = (t[i:], x[i:], y[i:], p[i:]) if i < len(t) else None
        return self._emit(t[:i], x[:i], y[:i], p[:i], cut)

    def _emit(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, cut: int) -> list[Packet]:
        assert self.sensor is not None
        start = self._ev_end if self._ev_end is not None else (int(t[0]) if len(t) else cut)
        if cut <= start and not len(t):
            return []
        self._ev_end = cut
        return [EventPacket(t, x, y, p, sensor=self.sensor, t_start=start, t_end=cut)]

    def _samples(self, sid: int, pkt: Packet) -> list[Packet]:
        assert isinstance(pkt, (ImuPacket, FramePacket, TriggerPacket))
        n = len(pkt)
        if n == 0:
            return []
        t = pkt.t
        prev = self._ends.get(sid)
        if np.any(t[1:] < t[:-1]) or (prev is not None and int(t[0]) < prev):
            return self._reject("time")
        end = int(t[-1]) + 1
        self._ends[sid] = end
        self.counts["packets"] += 1
        self.counts["samples"] += n
        start = prev if prev is not None else int(t[0])
        return [pkt._take_slice(0, n, start, end)]

    def flush(self) -> list[Packet]:
        """End of stream: the held-back events."""
        h, self._held = self._held, None
        if h is None:
            return []
        return self._emit(*h, int(h[0][-1]) + 1)
