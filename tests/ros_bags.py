"""ROS messages and ROS 1 bags written the slow, obvious way, from the specs,
for the bag reference tests (no rosbags serializer involved).

Serialisation (one :class:`Out` for both):

* ROS 1: fields packed in order, little-endian, no padding; ``time`` is
  uint32 sec + uint32 nsec; a string or a variable-length array is a uint32
  count then its items; ``std_msgs/Header`` starts with a uint32 ``seq``.
* ROS 2 (CDR, XCDR1 as rmw writes it): a 4-byte encapsulation header
  (``00 01 00 00`` little-endian, ``00 00 00 00`` big-endian), then each
  primitive aligned to its own size counted from the byte after that header;
  a string is a uint32 length counting its terminating NUL, then the bytes
  and the NUL; ``builtin_interfaces/Time`` is int32 sec + uint32 nanosec;
  the Header has no ``seq``.

ROS 1 bag format 2.0 (wiki.ros.org/Bags/Format/2.0): ``#ROSBAG V2.0\\n``,
then records ``<header_len u32><header><data_len u32><data>``, the header
being fields ``<len u32>name=value``. A bag header record (op 0x03:
``index_pos``, ``conn_count``, ``chunk_count``; padded to 4096 bytes), chunk
records (op 0x05, ``compression=none``, ``size``) holding connection (op
0x07) and message data (op 0x02: ``conn``, ``time``) records, each chunk
followed by one index data record (op 0x04) per connection in it; at
``index_pos`` every connection record again, then one chunk info record (op
0x06) per chunk.

:func:`ref_libcaer` decodes a ``libcaer`` EventPacket payload the slow way.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

from tectum.sources.files.rosbag import DVS_MSGS, EVENT_CAMERA_MSGS

__all__ = ["Out", "header", "dvs_event_array", "event_packet", "image", "imu", "write_ros1_bag", "ros2_bag", "ref_libcaer", "TYPES"]


class Out:
    """A message being serialised: ROS 1 (packed) or CDR (aligned)."""

    def __init__(self, ros: int, big_endian: bool = False) -> None:
        self.cdr = ros == 2
        self.e = ">" if big_endian else "<"
        self.b = bytearray(b"\x00\x00\x00\x00" if big_endian else b"\x00\x01\x00\x00") if self.cdr else bytearray()
        self.origin = 4 if self.cdr else 0

    def put(self, fmt: str, v: object) -> Out:
        size = struct.calcsize(fmt)
        if self.cdr:
            while (len(self.b) - self.origin) % size:
                self.b.append(0)
        self.b += struct.pack(self.e + fmt, v)
        return self

    def string(self, s: str) -> Out:
        raw = s.encode() + (b"\x00" if self.cdr else b"")
        self.put("I", len(raw))
        self.b += raw
        return self

    def stamp(self, t_ns: int) -> Out:
        return self.put("i" if self.cdr else "I", t_ns // 10**9).put("I", t_ns % 10**9)

    def bytes_(self) -> bytes:
        return bytes(self.b)


def header(o: Out, t_ns: int, frame_id: str = "cam", seq: int = 0) -> Out:
    if not o.cdr:
        o.put("I", seq)
    return o.stamp(t_ns).string(frame_id)


def dvs_event_array(ros: int, be: bool, stamp_ns: int, w: int, h: int,
                    events: Sequence[tuple[int, int, int, int]], frame_id: str = "cam") -> bytes:
    """``dvs_msgs/EventArray`` of ``events`` (t ns, x, y, p 0/1)."""
    o = header(Out(ros, be), stamp_ns, frame_id).put("I", h).put("I", w).put("I", len(events))
    for t, x, y, p in events:
        o.put("H", x).put("H", y).stamp(t).put("B", 1 if p else 0)
    return o.bytes_()


def event_packet(ros: int, be: bool, stamp_ns: int, w: int, h: int, seq: int, time_base: int, encoding: str,
                 payload_big_endian: bool, payload: bytes, frame_id: str = "cam") -> bytes:
    """``event_camera_msgs/EventPacket``."""
    o = header(Out(ros, be), stamp_ns, frame_id).put("I", h).put("I", w).put("Q", seq).put("Q", time_base)
    o.string(encoding).put("B", 1 if payload_big_endian else 0).put("I", len(payload))
    o.b += payload
    return o.bytes_()


def image(ros: int, be: bool, stamp_ns: int, h: int, w: int, encoding: str, big_endian_data: bool, step: int,
          data: bytes) -> bytes:
    """``sensor_msgs/Image``."""
    o = header(Out(ros, be), stamp_ns).put("I", h).put("I", w).string(encoding)
    o.put("B", 1 if big_endian_data else 0).put("I", step).put("I", len(data))
    o.b += data
    return o.bytes_()


def imu(ros: int, be: bool, stamp_ns: int, accel: Sequence[float], gyro: Sequence[float]) -> bytes:
    """``sensor_msgs/Imu`` (identity orientation, zero covariances)."""
    o = header(Out(ros, be), stamp_ns)
    for v in (0.0, 0.0, 0.0, 1.0, *[0.0] * 9, *gyro, *[0.0] * 9, *accel, *[0.0] * 9):
        o.put("d", v)
    return o.bytes_()


#: message type -> definition text for the connection records (md5 is not checked by readers here)
TYPES = {
    "dvs_msgs/EventArray": DVS_MSGS["dvs_msgs/msg/EventArray"],
    "event_camera_msgs/EventPacket": EVENT_CAMERA_MSGS["event_camera_msgs/msg/EventPacket"],
    "sensor_msgs/Image": "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
                         "uint32 step\nuint8[] data\n",
    "sensor_msgs/Imu": "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
                       "float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
                       "float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n"
                       "float64[9] linear_acceleration_covariance\n",
}


def _fields(fields: dict[str, bytes]) -> bytes:
    return b"".join(struct.pack("<I", len(k) + 1 + len(v)) + k.encode() + b"=" + v for k, v in fields.items())


def _record(fields: dict[str, bytes], data: bytes) -> bytes:
    head = _fields(fields)
    return struct.pack("<I", len(head)) + head + struct.pack("<I", len(data)) + data


def _time(t_ns: int) -> bytes:
    return struct.pack("<II", t_ns // 10**9, t_ns % 10**9)


def write_ros1_bag(path: Path, topics: dict[str, str], messages: Sequence[tuple[str, int, bytes]],
                   per_chunk: int = 3) -> None:
    """A ROS 1 bag (format 2.0, uncompressed chunks of ``per_chunk``
    messages) of ``messages`` (topic, receive time ns, serialized message);
    ``topics`` maps each topic to its type (``dvs_msgs/EventArray``)."""
    conn_id = {topic: k for k, topic in enumerate(topics)}

    def connection(topic: str) -> bytes:
        typ = topics[topic]
        body = _fields({"topic": topic.encode(), "type": typ.encode(), "md5sum": b"*" * 32,
                        "message_definition": TYPES[typ].encode()})
        return _record({"op": b"\x07", "conn": struct.pack("<I", conn_id[topic]), "topic": topic.encode()}, body)

    out = bytearray(b"#ROSBAG V2.0\n")
    bag_header_at = len(out)
    out += b"\0" * 4096  # the bag header, written last
    infos = []
    for c in range(0, len(messages), per_chunk):
        part = messages[c:c + per_chunk]
        chunk = bytearray()
        seen: dict[str, list[tuple[int, int]]] = {}
        for topic, t_ns, raw in part:
            if topic not in seen:
                chunk += connection(topic)
                seen[topic] = []
            seen[topic].append((t_ns, len(chunk)))
            chunk += _record({"op": b"\x02", "conn": struct.pack("<I", conn_id[topic]), "time": _time(t_ns)}, raw)
        pos = len(out)
        out += _record({"op": b"\x05", "compression": b"none", "size": struct.pack("<I", len(chunk))}, bytes(chunk))
        for topic, entries in seen.items():
            out += _record({"op": b"\x04", "ver": struct.pack("<I", 1), "conn": struct.pack("<I", conn_id[topic]),
                            "count": struct.pack("<I", len(entries))},
                           b"".join(_time(t) + struct.pack("<I", off) for t, off in entries))
        times = [t for _, t, _ in part]
        infos.append((pos, min(times), max(times), {conn_id[k]: len(v) for k, v in seen.items()}))
    index_pos = len(out)
    for topic in topics:
        out += connection(topic)
    for pos, lo, hi, counts in infos:
        out += _record({"op": b"\x06", "ver": struct.pack("<I", 1), "chunk_pos": struct.pack("<Q", pos),
                        "start_time": _time(lo), "end_time": _time(hi), "count": struct.pack("<I", len(counts))},
                       b"".join(struct.pack("<II", k, n) for k, n in counts.items()))
    fields = {"op": b"\x03", "index_pos": struct.pack("<Q", index_pos), "conn_count": struct.pack("<I", len(topics)),
              "chunk_count": struct.pack("<I", len(infos))}
    rec = _record(fields, b"")
    rec = _record(fields, b" " * (4096 - len(rec)))  # padded to 4096 bytes
    out[bag_header_at:bag_header_at + 4096] = rec
    path.write_bytes(bytes(out))


def ros2_bag(path: Path, topics: dict[str, str], messages: Sequence[tuple[str, int, bytes]]) -> None:
    """A ROS 2 bag folder (sqlite3, rosbags' writer for the container only)
    holding the CDR ``messages`` as given."""
    from rosbags.rosbag2 import Writer

    from tectum.sources.files.rosbag import typestore

    ts = typestore(2)
    with Writer(path, version=8) as w:
        conns = {t: w.add_connection(t, typ.replace("/", "/msg/", 1), typestore=ts) for t, typ in topics.items()}
        for topic, t_ns, raw in messages:
            w.write(conns[topic], t_ns, raw)


def ref_libcaer(payload: bytes, time_base_ns: int) -> list[tuple[int, int, int, int]]:
    """libcaer polarity events: u32 data (bit 0 valid, bit 1 ON, y bits 2-16,
    x bits 17-31), i32 time (µs, low 31 bits); a time falling by more than
    2^30 inside the packet is the 31-bit clock rolling over."""
    out, high, last = [], time_base_ns, None
    for k in range(len(payload) // 8):
        d, ts = struct.unpack_from("<Ii", payload, 8 * k)
        ts &= 0x7FFFFFFF
        if last is not None and last - ts > 1 << 30:
            high += (1 << 31) * 1000
        last = ts
        if d & 1:
            out.append(((high + ts * 1000) // 1000, d >> 17, (d >> 2) & 0x7FFF, 1 if d & 2 else -1))
    return out
