"""A ROS 1 bag read record by record, without its index: for a bag cut short
(the index is written last, so a cut bag does not open in ``rosbags``).

Format 2.0 (``#ROSBAG V2.0``): records of int32 header length, header
fields (int32 length, ``name=value``), int32 data length, data. The ``op``
field says what a record is: 0x03 bag header, 0x05 chunk (``compression``
``none``/``bz2``/``lz4``; its data holds connection and message records),
0x07 connection (``conn``, ``topic``; its data is the connection header:
``type=pkg/Name``...), 0x02 message (``conn``, ``time``), 0x04 index data,
0x06 chunk info.
"""

from __future__ import annotations

import bz2
import mmap
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

__all__ = ["Connection", "scan_ros1", "ros1_messages"]

MAGIC = b"#ROSBAG V2.0\n"
#: What the scan reads: the file's bytes, or the file mapped (slices are bytes).
Buffer = bytes | memoryview | mmap.mmap
_OP_MESSAGE, _OP_CHUNK, _OP_CONNECTION = 0x02, 0x05, 0x07


@dataclass(frozen=True)
class Connection:
    """A connection as the bag's readers describe one: id, topic, message type (``pkg/msg/Name``)."""

    id: int
    topic: str
    msgtype: str


@dataclass
class Scan:
    """What a scan found: the connections, and where the complete records
    end (``cut`` is None when the file ends between records)."""

    connections: dict[int, Connection]
    cut: int | None


def _fields(raw: bytes | memoryview) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    i = 0
    while i + 4 <= len(raw):
        (n,) = struct.unpack_from("<i", raw, i)
        if n < 0 or i + 4 + n > len(raw):
            raise ValueError(f"header field of {n} bytes runs past its record")
        name, _, value = bytes(raw[i + 4:i + 4 + n]).partition(b"=")
        out[name.decode("latin1")] = value
        i += 4 + n
    return out


def _records(buf: Buffer, pos: int, end: int) -> Iterator[tuple[dict[str, bytes], int, int]]:
    """(header fields, data start, data end) of the complete records
    in ``buf[pos:end]``; stops at the first incomplete one."""
    while pos + 4 <= end:
        (hl,) = struct.unpack_from("<i", buf, pos)
        if hl < 0 or pos + 8 + hl > end:
            return
        (dl,) = struct.unpack_from("<i", buf, pos + 4 + hl)
        if dl < 0 or pos + 8 + hl + dl > end:
            return
        yield _fields(buf[pos + 4:pos + 4 + hl]), pos + 8 + hl, pos + 8 + hl + dl
        pos += 8 + hl + dl


def _connection(fields: dict[str, bytes], data: bytes | memoryview) -> Connection:
    (cid,) = struct.unpack("<I", fields["conn"])
    typ = _fields(data).get("type", b"").decode("latin1")
    pkg, _, name = typ.partition("/")
    return Connection(cid, fields.get("topic", b"").decode("latin1"), f"{pkg}/msg/{name}" if name else typ)


def _unpack(fields: dict[str, bytes], data: bytes | memoryview) -> bytes | memoryview:
    comp = fields.get("compression", b"none").decode("latin1")
    if comp == "none":
        return data
    if comp == "bz2":
        return bz2.decompress(data)
    if comp == "lz4":
        import lz4.frame  # the aedat4 extra; ROS's roslz4 chunks are LZ4 frames

        return lz4.frame.decompress(bytes(data))
    raise ValueError(f"chunk compression {comp!r} is not none, bz2 or lz4")


def ros1_messages(data: Buffer, scan: Scan) -> Iterator[tuple[Connection, int, bytes]]:
    """The complete messages of a ROS 1 bag's bytes ``data``, in file order
    (``(connection, time ns, serialized message)``), filling ``scan`` with
    the connections met and where the complete records end. A chunk cut
    short still gives its complete messages when it is uncompressed."""
    if bytes(data[:len(MAGIC)]) != MAGIC:
        raise ValueError("not a ROS 1 bag (no #ROSBAG V2.0 line)")
    end = len(MAGIC)
    for fields, a, b in _records(data, len(MAGIC), len(data)):
        end = b
        yield from _in(fields, data[a:b], scan)
    if end < len(data):
        scan.cut = end
        cut = _cut_chunk(data, end)
        if cut is not None:
            yield from _in(*cut, scan)


def _cut_chunk(data: Buffer, at: int) -> tuple[dict[str, bytes], bytes | memoryview] | None:
    """The header and the bytes present of an uncompressed chunk cut short at ``at``."""
    if at + 4 > len(data):
        return None
    (hl,) = struct.unpack_from("<i", data, at)
    if hl < 0 or at + 8 + hl > len(data):
        return None
    fields = _fields(data[at + 4:at + 4 + hl])
    if fields.get("op") != bytes([_OP_CHUNK]) or fields.get("compression", b"none") != b"none":
        return None
    return fields, data[at + 8 + hl:]


def _in(fields: dict[str, bytes], body: bytes | memoryview, scan: Scan) -> Iterator[tuple[Connection, int, Any]]:
    op = fields.get("op", b"\0")[0]
    if op == _OP_CONNECTION:
        c = _connection(fields, body)
        scan.connections[c.id] = c
    elif op == _OP_CHUNK:
        inner = _unpack(fields, body)
        for f, a, b in _records(inner, 0, len(inner)):
            yield from _in(f, inner[a:b], scan)
    elif op == _OP_MESSAGE:
        (cid,) = struct.unpack("<I", fields["conn"])
        sec, nsec = struct.unpack("<II", fields["time"])
        if cid in scan.connections:
            yield scan.connections[cid], sec * 1_000_000_000 + nsec, bytes(body)


def scan_ros1(data: Buffer) -> Scan:
    """The connections of a ROS 1 bag and where its complete records end."""
    scan = Scan({}, None)
    for _ in ros1_messages(data, scan):
        pass
    return scan
