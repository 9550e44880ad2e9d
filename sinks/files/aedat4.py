"""AEDAT 4.0 writer: events (stream 0), frames (1) and IMU samples (2).

The IOHeader is written first with room reserved for its ``infoNode`` XML
(padded with spaces) and a placeholder ``dataTablePosition``; packets follow
(one compressed EventPacket per incoming packet, split to at most
``packet_events`` events); :meth:`close` appends the compressed packet table
(``FileDataTable``) and rewrites the IOHeader in place with the streams seen
and the table's position. Readable by dv-processing and the other AEDAT 4
readers.
"""

from __future__ import annotations

import struct
from collections import deque
from concurrent.futures import Future
from typing import Any

import numpy as np

from tectum import EventPacket, FramePacket, ImuPacket, Kind, Packet
from tectum.sources.files import aedat4_codec as codec
from tectum.sources.files._common import thread_count, workers

from ._common import FileSink

__all__ = ["Aedat4Sink"]

MAGIC = b"#!AER-DAT4.0\r\n"
_XML_ROOM = 8192
#: LZ4 acceleration of event packets. Event packets are dense in short
#: matches (the high bytes of sorted times, x and y at a 16-byte stride): LZ4's
#: own setting (1) finds many 4-6 byte matches, each a token the decoder pays
#: for. 3 stores more of them as literals, copied in bulk. The same events
#: written with 1 and with 3, decode CPU per event, 21 interleaved rounds in one
#: process (machine loaded, load 4.7): imx636_evt3.raw converted, tectum 107 ->
#: 124 Mev/s per CPU second, dv-processing 85 -> 96, file +4.8 %; the bench's
#: random 1 M events 99 -> 133 and 82 -> 102, file +10.7 %; dvxplorer_2 re-written
#: 102 -> 108 and 57 -> 62, +2.2 %; gen31_evt2.raw unchanged, -0.5 %. At load
#: ~1 (13 rounds), in the same order: 106 -> 122 and 86 -> 96; 91 -> 122 and
#: 79 -> 98; 111 -> 125 and 63 -> 66; 151 -> 154 and 93 -> 97. Encode CPU
#: unchanged (+-3 %, 9-11 rounds).
DEFAULT_ACCELERATION = 3
_STREAMS = {"EVTS": (0, "events", "Array of events (polarity ON/OFF)."),
            "FRME": (1, "frames", "Standard frame (8-bit image)."),
            "IMUS": (2, "imu", "Inertial Measurement Unit data samples.")}


class Aedat4Sink(FileSink):
    """Write AEDAT 4.0.

    Parameters
    ----------
    compression:
        ``lz4`` (default, as DV), ``lz4_high``, ``zstd``, ``zstd_high`` or ``none``.
    acceleration:
        LZ4's fast-mode acceleration of event packets with ``lz4`` (1: LZ4's
        and DV's setting, the smallest files of the fast mode; frames, IMU and
        the packet table always use 1). Higher finds fewer, longer matches:
        the file is a little larger and decodes faster, in tectum and in
        dv-processing alike (the same LZ4 frame format). The default, 3, is
        measured under :data:`DEFAULT_ACCELERATION`.
    packet_events:
        Most events per stored packet.
    threads:
        Threads compressing event packets (0, the default: one per CPU, at
        most 4; 1: this thread only). The file is the same either way.
    """

    name = "aedat4"
    format = "aedat4"
    title = "AEDAT 4.0"
    extensions = (".aedat4",)
    stores_sensor = True
    consumes = (Kind.EVENTS, Kind.FRAMES, Kind.IMU)

    def __init__(self, path: str, compression: str = "lz4", packet_events: int = 1 << 16, threads: int = 0,
                 acceleration: int = DEFAULT_ACCELERATION) -> None:
        super().__init__(path)
        self.threads = thread_count(threads)
        #: event packets being compressed, in file order: (payload, count, first and last µs)
        self._pending: deque[tuple[Future[Any], int, int, int]] = deque()
        self.comp = codec.compression_code(compression)
        self.comp_name = {v: k for k, v in codec.COMPRESSION.items()}[self.comp].upper()
        if packet_events < 1:
            raise ValueError("packet_events must be >= 1")
        self.packet_events = packet_events
        if acceleration < 1:
            raise ValueError("acceleration must be >= 1")
        self.acceleration = int(acceleration)
        self.table: list[tuple[int, int, int, int, int, int]] = []
        self.seen: set[str] = set()
        self.frame_size: tuple[int, int] | None = None
        self._hdr_len = 0

    def open(self) -> None:
        super().open()
        assert self.f is not None
        self.f.write(self._header(-1, " " * _XML_ROOM))

    def _header(self, dtp: int, xml: str) -> bytes:
        body = xml.encode()
        body += b"\0" * ((-len(body)) % 4)
        hdr = _io_header(self.comp, dtp, body)
        if self._hdr_len and len(hdr) != self._hdr_len:
            raise AssertionError("IOHeader size changed")
        self._hdr_len = len(hdr)
        return MAGIC + struct.pack("<i", len(hdr)) + hdr

    def _begin(self, packet: EventPacket) -> None:
        pass

    def _events(self, packet: EventPacket) -> None:
        for ev in packet.batches(self.packet_events):
            buf, n, t0, t1 = codec.events_buffer(ev), len(ev), int(ev.t[0]), int(ev.t[-1])
            if self.threads == 1:
                self._put("EVTS", codec.compress(buf, self.comp, self.acceleration), n, t0, t1)
                continue
            self._pending.append((workers().submit(codec.compress, buf, self.comp, self.acceleration), n, t0, t1))
            self._drain(2 * self.threads)

    def _drain(self, keep: int) -> None:
        """Write compressed event packets, in order, until ``keep`` are left."""
        while len(self._pending) > keep:
            fu, n, t0, t1 = self._pending.popleft()
            self._put("EVTS", fu.result(), n, t0, t1)

    def _other(self, packet: Packet) -> None:
        self._drain(0)  # packets stay in the order they came
        if isinstance(packet, FramePacket):
            for i, buf in enumerate(codec.encode_frames(packet)):
                img = packet.images[i]
                self.frame_size = (int(img.shape[1]), int(img.shape[0]))
                t = int(packet.t[i])
                self._put("FRME", codec.compress(buf, self.comp), 1, t, t)
        elif isinstance(packet, ImuPacket) and len(packet):
            self._put("IMUS", codec.compress(codec.encode_imu(packet), self.comp), len(packet),
                      int(packet.t[0]), int(packet.t[-1]))

    def _put(self, type_id: str, payload: bytes | np.ndarray, n: int, t0: int, t1: int) -> None:
        assert self.f is not None
        sid = _STREAMS[type_id][0]
        self.seen.add(type_id)
        pos = self.f.tell()
        self.f.write(struct.pack("<ii", sid, len(payload)))
        self.f.write(codec.as_buffer(payload))
        self.table.append((pos + 8, sid, len(payload), n, t0, t1))

    def _empty(self) -> None:
        pass

    def abort(self) -> None:
        for fu, *_ in self._pending:
            fu.cancel()
        self._pending.clear()
        super().abort()

    def _end(self) -> None:
        assert self.f is not None
        self._drain(0)
        dtp = self.f.tell()
        self.f.write(codec.compress(_data_table(self.table), self.comp))
        xml = self._xml()
        if len(xml) > _XML_ROOM:
            raise ValueError("infoNode XML exceeds its reserved room")
        self.f.seek(0)
        self.f.write(self._header(dtp, xml + " " * (_XML_ROOM - len(xml))))

    def _xml(self) -> str:
        parts = ['<dv version="2.0">', '<node name="outInfo" path="/mainloop/Recorder/outInfo/">']
        seen = self.seen | ({"EVTS"} if self.sensor else set())
        for type_id in ("EVTS", "FRME", "IMUS"):
            if type_id not in seen:
                continue
            sid, out, desc = _STREAMS[type_id]
            p = f"/mainloop/Recorder/outInfo/{sid}/"
            size = self.sensor if type_id == "EVTS" else self.frame_size if type_id == "FRME" else None
            info = ""
            if size:
                info += (f'<attr key="sizeX" type="int">{size[0]}</attr>'
                         f'<attr key="sizeY" type="int">{size[1]}</attr>')
            info += '<attr key="source" type="string">tectum</attr><attr key="tsOffset" type="long">0</attr>'
            parts.append(
                f'<node name="{sid}" path="{p}"><attr key="compression" type="string">{self.comp_name}</attr>'
                f'<attr key="originalModuleName" type="string">tectum</attr>'
                f'<attr key="originalOutputName" type="string">{out}</attr>'
                f'<attr key="typeDescription" type="string">{desc}</attr>'
                f'<attr key="typeIdentifier" type="string">{type_id}</attr>'
                f'<node name="info" path="{p}info/">{info}</node></node>')
        parts.append("</node></dv>")
        return "".join(parts)


def _io_header(comp: int, dtp: int, xml: bytes) -> bytes:
    """IOHeader table (``IOHE``, not size-prefixed): compression, position, infoNode."""
    # fields: 0 compression (int32), 1 dataTablePosition (int64), 2 infoNode (string)
    out = bytearray(8)
    out[4:8] = b"IOHE"
    vt = len(out)
    out += struct.pack("<HHHHH", 10, 24, 8, 16, 4) + b"\0\0"
    while len(out) % 8:
        out += b"\0"
    tab = len(out)
    out += struct.pack("<iIiiq", tab - vt, 0, comp, 0, dtp)
    struct.pack_into("<I", out, 0, tab)
    s = len(out)
    out += struct.pack("<I", len(xml)) + xml + b"\0"
    while len(out) % 4:
        out += b"\0"
    struct.pack_into("<I", out, tab + 4, s - (tab + 4))
    return bytes(out)


def _data_table(rows: list[tuple[int, int, int, int, int, int]]) -> bytes:
    """FileDataTable (``FTAB``, size-prefixed): a vector of FileDataDefinition
    tables (ByteOffset, PacketInfo struct {StreamID, Size}, NumElements,
    TimestampStart, TimestampEnd)."""
    vt = struct.pack("<HH5H", 14, 48, 8, 16, 24, 32, 40) + b"\0\0"
    bodies = [struct.pack("<i4xqiiqqq", 0, off, sid, size, n, t0, t1) for off, sid, size, n, t0, t1 in rows]
    return codec._vector_of_tables(b"FTAB", vt, bodies)


def write_aedat4(path: str, packets: Any, **kw: Any) -> None:
    from ._common import write_all

    write_all(Aedat4Sink(path, **kw), packets)
