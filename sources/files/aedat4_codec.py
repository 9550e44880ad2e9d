"""AEDAT 4.0 packet codec: FlatBuffer packets <-> tectum packets.

Shared by the AEDAT 4.0 file reader/writer and the AEDAT 4.0 network stream
(the wire format is the same: an 8-byte header, int32 stream id and int32
size, then a compressed, size-prefixed FlatBuffer).

Public API
----------
``decompress(payload, compression) -> bytes`` and ``compress(buf, compression)``
    ``compression`` is an :data:`COMPRESSION` code or name (``"none"``,
    ``"lz4"``, ``"lz4_high"``, ``"zstd"``, ``"zstd_high"``); LZ4 uses the LZ4
    frame format, Zstd a standard frame (packages ``lz4``/``zstandard``,
    the ``aedat4`` extra).
``decode_packet(type_id, payload, compression, sensor=None) -> Packet``
    ``type_id`` is the stream's ``typeIdentifier`` (``EVTS``, ``FRME``,
    ``IMUS``, ``TRIG``): gives an :class:`EventPacket` (needs ``sensor``),
    :class:`FramePacket`, :class:`ImuPacket` or :class:`ResultPacket` of
    ``(type, t)`` trigger items.
``encode_events(pkt) / encode_frames(pkt) / encode_imu(pkt) -> bytes``
    The uncompressed size-prefixed FlatBuffer of one packet.
``encode_packet(pkt, compression) -> (type_id, bytes)``
    The compressed payload for a stream of the packet's kind.

Schemas (dv-processing's ``events.fbs``, ``frame.fbs``, ``imu.fbs``,
``trigger.fbs``): ``Event`` is a 16-byte struct (int64 timestamp µs, int16 x,
int16 y, bool polarity 1 = ON, 3 padding bytes); ``Frame`` a table (timestamp,
start/end of frame, start/end of exposure, format, sizeX, sizeY, positionX,
positionY, pixels, exposure, source); ``IMU`` a table (timestamp,
temperature °C, accelerometer x, y, z in g, gyroscope x, y, z in °/s,
magnetometer x, y, z); ``Trigger`` a table (timestamp, type). IMU values are
converted to m/s² and rad/s.
"""

from __future__ import annotations

import struct

import numpy as np
from numba import njit

from tectum import EventPacket, FramePacket, ImuPacket, Packet, ResultPacket

from ._flatbuf import FlatError, Table, build_table, root

__all__ = ["COMPRESSION", "EVENT_DTYPE", "FlatError", "compress", "decompress", "decode_packet", "decode_events",
           "encode_events", "encode_frames", "encode_imu", "encode_packet", "compression_code"]

#: AEDAT 4.0 compression codes (IOHeader ``compression``).
COMPRESSION = {"none": 0, "lz4": 1, "lz4_high": 2, "zstd": 3, "zstd_high": 4}

#: One dv ``Event`` struct as stored in an EventPacket vector.
EVENT_DTYPE = np.dtype({"names": ["t", "x", "y", "p"], "formats": ["<i8", "<i2", "<i2", "u1"],
                        "offsets": [0, 8, 10, 12], "itemsize": 16})

_G = 9.80665


def compression_code(c: int | str) -> int:
    if isinstance(c, str):
        key = c.lower().replace("-", "_")
        if key not in COMPRESSION:
            raise ValueError(f"unknown AEDAT4 compression {c!r}; known: {list(COMPRESSION)}")
        return COMPRESSION[key]
    if c not in COMPRESSION.values():
        raise ValueError(f"unknown AEDAT4 compression code {c}")
    return int(c)


def decompress(payload: bytes | memoryview, compression: int | str) -> bytes:
    """Undo a packet's compression (raises ValueError on corrupt data)."""
    c = compression_code(compression)
    if c == 0:
        return bytes(payload)
    try:
        if c in (1, 2):
            import lz4.frame

            return lz4.frame.decompress(payload)
        import zstandard

        return zstandard.ZstdDecompressor().decompress(payload, max_output_size=1 << 30)
    except ImportError as e:
        raise ImportError(f"AEDAT4 compression needs {e.name}: pip install 'tectum[aedat4]'") from None
    except Exception as e:  # lz4/zstd raise their own types
        raise ValueError(f"corrupt compressed packet: {e}") from None


def compress(buf: bytes, compression: int | str) -> bytes:
    c = compression_code(compression)
    if c == 0:
        return buf
    if c in (1, 2):
        import lz4.frame

        return lz4.frame.compress(buf, compression_level=9 if c == 2 else 0, content_checksum=False)
    import zstandard

    return zstandard.ZstdCompressor(level=9 if c == 4 else 3).compress(buf)


@njit(cache=True, nogil=True)
def _split_events(raw, t, x, y, p):  # pragma: no cover - numba
    n = t.shape[0]
    for i in range(n):
        b = 16 * i
        v = np.int64(0)
        for k in range(8):
            v |= np.int64(raw[b + k]) << (8 * k)
        t[i] = v
        x[i] = np.int32(raw[b + 8]) | (np.int32(raw[b + 9]) << 8)
        y[i] = np.int32(raw[b + 10]) | (np.int32(raw[b + 11]) << 8)
        p[i] = 1 if raw[b + 12] else -1


def decode_events(buf: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t int64 µs, x uint16, y uint16, p int8 ±1) of an EventPacket FlatBuffer.

    x and y are int16 on the wire: negative values come out >= 32768 (and
    fail geometry checks downstream)."""
    tab = root(buf, size_prefixed=True, ident=None)
    start, n = tab.vector(0, 16)
    t = np.empty(n, np.int64)
    x = np.empty(n, np.uint16)
    y = np.empty(n, np.uint16)
    p = np.empty(n, np.int8)
    if n:
        raw = np.frombuffer(buf, np.uint8, count=16 * n, offset=start)
        _split_events(raw, t, x, y, p)
    return t, x, y, p


def _frames(buf: bytes) -> FramePacket:
    tab = root(buf, size_prefixed=True)
    ts = tab.scalar(0, "q")
    fmt = tab.scalar(5, "b")
    w, h = tab.scalar(6, "h"), tab.scalar(7, "h")
    ch = {0: 1, 16: 3, 24: 4}.get(fmt)
    if ch is None:
        raise FlatError(f"unknown frame format {fmt}")
    start, n = tab.vector(10, 1)
    if w < 0 or h < 0 or n != w * h * ch:
        raise FlatError(f"frame of {w}x{h}x{ch} has {n} pixel bytes")
    img = np.frombuffer(buf, np.uint8, count=n, offset=start).reshape((1, h, w) if ch == 1 else (1, h, w, ch))
    extra = {"exposure_start": np.array([tab.scalar(3, "q")], np.int64),
             "exposure_end": np.array([tab.scalar(4, "q")], np.int64),
             "position": np.array([[tab.scalar(8, "h"), tab.scalar(9, "h")]], np.int16)}
    return FramePacket(np.array([ts], np.int64), images=img.copy(), **extra)


def _imus(buf: bytes) -> ImuPacket:
    tab = root(buf, size_prefixed=True)
    rows = []
    for e in tab.tables(0):
        rows.append((e.scalar(0, "q"), *(e.scalar(i, "f", 0.0) for i in range(1, 11))))
    a = np.array(rows, np.float64).reshape(-1, 11)
    t = np.array([r[0] for r in rows], np.int64)
    return ImuPacket(t, accel=a[:, 2:5] * _G, gyro=np.deg2rad(a[:, 5:8]), temperature=a[:, 1],
                     magnetometer=a[:, 8:11])


def _triggers(buf: bytes) -> ResultPacket:
    tab = root(buf, size_prefixed=True)
    items = [(int(e.scalar(1, "b")), int(e.scalar(0, "q"))) for e in tab.tables(0)]
    t = np.array([it[1] for it in items], np.int64)
    order = np.argsort(t, kind="stable")
    return ResultPacket(t[order], [items[i] for i in order])


def decode_packet(type_id: str, payload: bytes | memoryview, compression: int | str,
                  sensor: tuple[int, int] | None = None) -> Packet:
    """One stream packet (as stored in a file or sent on the wire) -> a packet.

    Raises ValueError (FlatError) on malformed input. Events get the packet's
    natural interval ``[t[0], t[-1] + 1)``."""
    buf = decompress(payload, compression)
    if type_id == "EVTS":
        if sensor is None:
            raise ValueError("decoding events needs the sensor size")
        t, x, y, p = decode_events(buf)
        return EventPacket(t, x, y, p, sensor=sensor)
    if type_id == "FRME":
        return _frames(buf)
    if type_id == "IMUS":
        return _imus(buf)
    if type_id == "TRIG":
        return _triggers(buf)
    raise ValueError(f"unsupported AEDAT4 stream type {type_id!r}")


# -- encoding ----------------------------------------------------------------------
def encode_events(pkt: EventPacket) -> bytes:
    """An EventPacket FlatBuffer (size-prefixed, ``EVTS``) of ``pkt``'s events."""
    n = len(pkt)
    rec = np.zeros(n, EVENT_DTYPE)
    rec["t"] = pkt.t
    rec["x"] = pkt.x.astype(np.int16)
    rec["y"] = pkt.y.astype(np.int16)
    rec["p"] = pkt.p > 0
    return build_table([None], b"EVTS", size_prefixed=True, blob=rec.tobytes(), blob_field=0, blob_count=n)


def encode_frames(pkt: FramePacket) -> list[bytes]:
    """One ``FRME`` FlatBuffer per frame of ``pkt`` (uint8 gray, BGR or BGRA)."""
    out = []
    imgs = pkt.images
    for i in range(len(pkt)):
        img = np.ascontiguousarray(imgs[i])
        if img.dtype != np.uint8:
            raise ValueError("AEDAT4 frames are 8-bit: convert the images to uint8")
        h, w = img.shape[:2]
        ch = 1 if img.ndim == 2 else img.shape[2]
        fmt = {1: 0, 3: 16, 4: 24}[ch]
        ts = int(pkt.t[i])
        es = int(pkt.data["exposure_start"][i]) if "exposure_start" in pkt.data else ts
        ee = int(pkt.data["exposure_end"][i]) if "exposure_end" in pkt.data else ts
        fields = [("q", ts), ("q", es), ("q", ee), ("q", es), ("q", ee), ("b", fmt), ("h", w), ("h", h),
                  ("h", 0), ("h", 0), None, ("q", ee - es)]
        out.append(build_table(fields, b"FRME", size_prefixed=True, blob=img.tobytes(), blob_field=10,
                               blob_align=4))
    return out


def _vector_of_tables(ident: bytes, vt: bytes, bodies: list[bytes]) -> bytes:
    """Root table with field 0 = vector of tables sharing the vtable ``vt``."""
    out = bytearray(4 + 4 + 4)
    out[8:12] = ident
    rvt = len(out)
    out += struct.pack("<HHH", 6, 8, 4) + b"\0\0"
    rtab = len(out)
    out += struct.pack("<iI", rtab - rvt, 0)
    struct.pack_into("<I", out, 4, rtab - 4)
    vec = len(out)
    out += struct.pack("<I", len(bodies)) + b"\0" * (4 * len(bodies))
    struct.pack_into("<I", out, rtab + 4, vec - (rtab + 4))
    evt = len(out)
    out += vt
    while len(out) % 8:
        out += b"\0"
    for k, body in enumerate(bodies):
        pos = len(out)
        out += struct.pack("<i", pos - evt) + body[4:]
        slot = vec + 4 + 4 * k
        struct.pack_into("<I", out, slot, pos - slot)
    struct.pack_into("<I", out, 0, len(out) - 4)
    return bytes(out)


_IMU_VT = struct.pack("<HH11H", 26, 56, 48, 4, 8, 12, 16, 20, 24, 28, 32, 36, 40) + b"\0\0"


def encode_imu(pkt: ImuPacket) -> bytes:
    """An IMUPacket FlatBuffer (``IMUS``): g and °/s on the wire."""
    n = len(pkt)
    acc = np.asarray(pkt.accel, np.float64) / _G
    gyr = np.rad2deg(np.asarray(pkt.gyro, np.float64))
    temp = np.asarray(pkt.data["temperature"], np.float64) if "temperature" in pkt.data else np.zeros(n)
    mag = np.asarray(pkt.data["magnetometer"], np.float64) if "magnetometer" in pkt.data else np.zeros((n, 3))
    bodies = []
    for i in range(n):
        vals = [temp[i], *acc[i], *gyr[i], *mag[i]]
        bodies.append(struct.pack("<i10f4xq", 0, *vals, int(pkt.t[i])))
    return _vector_of_tables(b"IMUS", _IMU_VT, bodies)


def encode_packet(pkt: Packet, compression: int | str) -> list[tuple[str, bytes]]:
    """``[(type_id, compressed payload), ...]`` for one packet (frames give
    one payload per frame)."""
    if isinstance(pkt, EventPacket):
        return [("EVTS", compress(encode_events(pkt), compression))]
    if isinstance(pkt, FramePacket):
        return [("FRME", compress(b, compression)) for b in encode_frames(pkt)]
    if isinstance(pkt, ImuPacket):
        return [("IMUS", compress(encode_imu(pkt), compression))]
    raise ValueError(f"AEDAT4 cannot store {type(pkt).__name__}")


def table_of(buf: bytes) -> Table:
    """The root of a size-prefixed buffer (for callers inspecting fields)."""
    return root(buf, size_prefixed=True)
