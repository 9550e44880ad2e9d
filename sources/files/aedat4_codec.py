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
    :class:`FramePacket`, :class:`ImuPacket` or :class:`TriggerPacket`.
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

import functools
import struct
from typing import Any, overload

import numpy as np

from tectum import EventPacket, FramePacket, ImuPacket, Packet, TriggerPacket

from . import _aedat4_kernels as K
from ._flatbuf import FlatError, build_table, root

__all__ = ["COMPRESSION", "EVENT_DTYPE", "FlatError", "compress", "decompress", "decode_packet", "decode_events",
           "imus_of", "triggers_of", "table_of",
           "encode_events", "encode_frames", "encode_imu", "encode_packet", "events_buffer", "compression_code"]

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

            out = _lz4_simple_frame(payload)
            return out if out is not None else lz4.frame.decompress(payload)
        import zstandard

        return zstandard.ZstdDecompressor().decompress(payload, max_output_size=1 << 30)
    except ImportError as e:
        raise ImportError(f"AEDAT4 compression needs {e.name}: pip install 'tectum[aedat4]'") from None
    except Exception as e:  # lz4/zstd raise their own types
        raise ValueError(f"corrupt compressed packet: {e}") from None


def _lz4_simple_frame(payload: bytes | memoryview) -> bytes | None:
    """Decompress an LZ4 frame holding one block, without checksums or
    dictionary (what DV writes), with ``lz4.block``: the frame decoder, not
    knowing the output size, grows its buffer and runs at half the speed.
    None for any other frame (the caller uses ``lz4.frame``, which also
    reports errors)."""
    buf = np.frombuffer(payload, np.uint8)
    lo, _, size, _, _, blocks = K.lz4_frame(buf, 0, buf.shape[0])
    if lo < 0 or blocks != 1:
        return None
    n = int.from_bytes(payload[lo:lo + 4], "little")
    return lz4_block_data(payload[lo + 4:lo + 4 + (n & 0x7FFFFFFF)], size, n >> 31)


def lz4_block_data(block: bytes | memoryview, size: int, raw: int) -> bytes | None:
    """The data of one LZ4 block (at most ``size`` bytes; ``raw``: stored
    uncompressed), None when it does not decompress."""
    if raw:
        return bytes(block)
    try:
        return _lz4_block().decompress(block, uncompressed_size=size)
    except ImportError:
        raise
    except Exception:  # corrupt: let the frame decoder say why
        return None


@functools.cache
def _lz4_block() -> Any:
    """``lz4.block``, imported once (an import statement per packet costs
    the import lock, which threads then wait on)."""
    import lz4.block

    return lz4.block


def as_buffer(buf: bytes | np.ndarray) -> bytes | memoryview:
    """``buf`` as the bytes-like object that file and compressor calls are
    typed for (numpy declares an array a buffer only from Python 3.12)."""
    return buf.data if isinstance(buf, np.ndarray) else buf


@overload
def compress(buf: bytes, compression: int | str, acceleration: int = 1) -> bytes: ...
@overload
def compress(buf: np.ndarray, compression: int | str, acceleration: int = 1) -> bytes | np.ndarray: ...
def compress(buf: bytes | np.ndarray, compression: int | str, acceleration: int = 1) -> bytes | np.ndarray:
    """``buf`` compressed with the AEDAT 4.0 ``compression`` (name or code);
    uncompressed, ``buf`` itself. ``acceleration``: LZ4's fast-mode
    acceleration for ``lz4`` (1, LZ4's and DV's default: the smallest output
    of the fast mode; n > 1 looks for fewer matches, the frame format is the
    same); other compressions ignore it."""
    c = compression_code(compression)
    if c == 0:
        return buf
    if c in (1, 2):
        import lz4.frame

        # lz4.frame's level -k is LZ4F's acceleration k + 1; 0 is acceleration 1
        level = 9 if c == 2 else 1 - acceleration if acceleration > 1 else 0
        return lz4.frame.compress(buf, compression_level=level, content_checksum=False)
    import zstandard

    return zstandard.ZstdCompressor(level=9 if c == 4 else 3).compress(as_buffer(buf))


def decode_events(buf: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t int64 µs, x uint16, y uint16, p int8 ±1) of an EventPacket FlatBuffer.

    x and y are int16 on the wire: negative values come out >= 32768 (and
    fail geometry checks downstream)."""
    raw = np.frombuffer(buf, np.uint8)
    cap = raw.shape[0] // 16
    t, x, y, p = np.empty(cap, np.int64), np.empty(cap, np.uint16), np.empty(cap, np.uint16), np.empty(cap, np.int8)
    n = K.fill_events(raw, 0, t, x, y, p)
    if n < 0:
        raise FlatError("malformed EventPacket FlatBuffer")
    return t[:n], x[:n], y[:n], p[:n]


def _gather(raw: np.ndarray, pos: np.ndarray, dtype: str, default: float | int) -> np.ndarray:
    """Values of type ``dtype`` at byte positions ``pos`` (-1: ``default``)."""
    size = np.dtype(dtype).itemsize
    idx = np.where(pos >= 0, pos, 0)[..., None] + np.arange(size)
    vals = raw[idx].view(dtype)[..., 0] if raw.size else np.zeros(pos.shape, dtype)
    return np.where(pos >= 0, vals, default)


def _fields(buf: bytes | bytearray, fields: list[int], sizes: list[int], offs: np.ndarray | None = None,
            ends: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    raw = np.frombuffer(buf, np.uint8)
    if offs is None or ends is None:
        offs, ends = np.zeros(1, np.int64), np.full(1, len(buf), np.int64)
    pos, _, bad = K.table_fields(raw, offs, ends, np.array(fields, np.int64), np.array(sizes, np.int64))
    if bad >= 0:
        err = FlatError("malformed vector of tables")
        err.packet = int(bad)  # type: ignore[attr-defined]
        raise err
    return raw, pos


def table_of(buf: bytes | bytearray) -> np.ndarray:
    """The rows ``(payload offset, stream id, size, elements, first µs, last
    µs)`` of a size-prefixed ``FileDataTable`` FlatBuffer (``FTAB``)."""
    if len(buf) < 12 or bytes(buf[8:12]) != b"FTAB":
        raise FlatError("not a FileDataTable (FTAB)")
    raw, pos = _fields(buf, [0, 1, 2, 3, 4], [8, 8, 8, 8, 8])
    info = pos[:, 1]
    out = np.empty((pos.shape[0], 6), np.int64)
    out[:, [0, 3, 4, 5]] = _gather(raw, pos[:, [0, 2, 3, 4]], "<i8", 0)
    out[:, 1] = _gather(raw, info, "<i4", 0)
    out[:, 2] = _gather(raw, np.where(info >= 0, info + 4, -1), "<i4", 0)
    return out


def _frames(buf: bytes, copy: bool = True) -> FramePacket:
    """The frame of a Frame FlatBuffer (``copy=False``: the image is a view
    of ``buf``)."""
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
    extra: dict[str, Any] = {"exposure_start": np.array([tab.scalar(3, "q")], np.int64),
                             "exposure_end": np.array([tab.scalar(4, "q")], np.int64),
                             "position": np.array([[tab.scalar(8, "h"), tab.scalar(9, "h")]], np.int16)}
    return FramePacket(np.array([ts], np.int64), images=img.copy() if copy else img, **extra)


def imus_of(buf: bytes | bytearray, offs: np.ndarray | None = None, ends: np.ndarray | None = None) -> ImuPacket:
    """The IMU samples of one packet, or of the packets ``buf[offs[k]:ends[k]]``."""
    raw, pos = _fields(buf, list(range(11)), [8] + [4] * 10, offs, ends)
    t = _gather(raw, pos[:, 0], "<i8", 0).astype(np.int64)
    a = _gather(raw, pos[:, 1:], "<f4", 0.0).astype(np.float64)
    return ImuPacket(t, accel=a[:, 1:4] * _G, gyro=np.deg2rad(a[:, 4:7]), temperature=a[:, 0],
                     magnetometer=a[:, 7:10])


#: dv ``TriggerType`` codes that mark a falling edge or an end (value 0); the
#: others (reset, rising edges, pulses, starts) get value 1.
_TRIGGER_FALLING = (2, 5, 7, 9)


def triggers_of(buf: bytes | bytearray, offs: np.ndarray | None = None,
                ends: np.ndarray | None = None) -> TriggerPacket:
    """A ``TRIG`` packet: ``channel`` = dv ``TriggerType`` code (0 timestamp
    reset, 1/2 external signal rising/falling, 3 pulse, 4/5 generator
    rising/falling, 6/7 APS frame start/end, 8/9 exposure start/end) and
    ``value`` 1 (rising/start) or 0 (falling/end)."""
    raw, pos = _fields(buf, [0, 1], [8, 1], offs, ends)
    t = _gather(raw, pos[:, 0], "<i8", 0).astype(np.int64)
    typ = _gather(raw, pos[:, 1], "i1", 0).astype(np.int16)
    order = np.argsort(t, kind="stable")
    t, typ = t[order], typ[order]
    value = np.where(np.isin(typ, _TRIGGER_FALLING), 0, 1).astype(np.int8)
    return TriggerPacket(t, channel=typ, value=value)


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
        return imus_of(buf)
    if type_id == "TRIG":
        return triggers_of(buf)
    raise ValueError(f"unsupported AEDAT4 stream type {type_id!r}")


# -- encoding ----------------------------------------------------------------------
def encode_events(pkt: EventPacket) -> bytes:
    """An EventPacket FlatBuffer (size-prefixed, ``EVTS``) of ``pkt``'s events."""
    return events_buffer(pkt).tobytes()


def events_buffer(pkt: EventPacket) -> np.ndarray:
    """:func:`encode_events` as a uint8 array, built in place (no copies)."""
    n = len(pkt)
    head = bytearray(build_table([None], b"EVTS", size_prefixed=True, blob_field=0, blob_count=n))
    struct.pack_into("<I", head, 0, len(head) + 16 * n - 4)  # the size prefix counts the events
    out = np.empty(len(head) + 16 * n, np.uint8)
    out[:len(head)] = np.frombuffer(head, np.uint8)
    K.pack_events(pkt.t, pkt.x, pkt.y, pkt.p, out[len(head):])
    return out


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
