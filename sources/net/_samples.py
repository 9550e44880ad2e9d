"""Sample packets (IMU, frames, poses, triggers) on tectum's network
framing, and fragments for messages larger than a UDP datagram.

SAMPLES (type 3) is self-describing, so it needs no HELLO. After the
44-byte header (``schema`` = CRC-32 of the description, ``n`` samples)::

    description: kind u8 (1 IMU, 2 frames, 3 poses, 4 triggers) | column
                 count u8 | per column: name and numpy dtype string (u8
                 length + ASCII each), ndim u8 of one sample, dims u32 each
    data:        t - t_base as u32 x n, then each column's n samples,
                 contiguous, little-endian

FRAG (type 4) carries a piece of a longer message (a frame over UDP):
``seq`` is the whole message's, ``t_start`` the piece index, ``t_end`` the
piece count, ``t_base`` the whole message's length, ``n`` the piece's
length and ``schema`` the CRC-32 of the piece. The receiver rebuilds one
message at a time (a piece of another message drops the partial one,
counted) within ``max_message`` bytes.
"""

from __future__ import annotations

import re
import struct
import zlib
from collections.abc import Iterator

import numpy as np

from tectum import FramePacket, ImuPacket, PosePacket, SamplePacket, TriggerPacket

__all__ = ["SAMPLES", "FRAG", "KIND_CODES", "encode_samples", "decode_samples", "sample_pieces", "fragments",
           "Reassembly"]

SAMPLES, FRAG = 3, 4
KIND_CODES: dict[type[SamplePacket], int] = {ImuPacket: 1, FramePacket: 2, PosePacket: 3, TriggerPacket: 4}
_CLASSES = {v: k for k, v in KIND_CODES.items()}
_SPAN = (1 << 32) - 1
MAX_DIMS, MAX_COLUMNS = 4, 32
#: The column types a message may declare (numpy type strings): checked
#: before numpy parses them (its parser raises SyntaxError on some junk).
_DTYPE = re.compile(r"[<>|=]?(b1|[iu][1248]|f[248])")


def _description(pkt: SamplePacket) -> bytes:
    code = KIND_CODES.get(type(pkt))
    if code is None:
        raise ValueError(f"{type(pkt).__name__} cannot go over the network (kinds: imu, frames, poses, triggers)")
    out = bytearray(struct.pack("<BB", code, len(pkt.data)))
    for name, a in pkt.data.items():
        if a.dtype.kind not in "biuf" or a.dtype.itemsize > 8 or a.ndim - 1 > MAX_DIMS:
            raise ValueError(f"column {name!r} ({a.dtype}, {a.ndim}-D) cannot go over the network")
        for s in (name.encode("ascii"), a.dtype.newbyteorder("<").str.encode("ascii")):
            out += bytes([len(s)]) + s
        out += struct.pack(f"<B{a.ndim - 1}I", a.ndim - 1, *a.shape[1:])
    return bytes(out)


def encode_samples(header: bytes, pkt: SamplePacket, t_base: int) -> bytes:
    """The body after ``header`` (made by the caller with :func:`schema_of`)."""
    parts = [header, _description(pkt), (pkt.t - t_base).astype("<u4").tobytes()]
    for a in pkt.data.values():
        parts.append(np.ascontiguousarray(a, a.dtype.newbyteorder("<")).tobytes())
    return b"".join(parts)


def schema_of(pkt: SamplePacket) -> int:
    return zlib.crc32(_description(pkt))


def row_bytes(pkt: SamplePacket) -> int:
    return 4 + sum(a.dtype.itemsize * int(np.prod(a.shape[1:], dtype=np.int64)) for a in pkt.data.values())


def sample_pieces(pkt: SamplePacket, per: int) -> Iterator[tuple[SamplePacket, int, int]]:
    """At most ``per`` samples a piece (never splitting equal times, each
    piece's time span within u32); yields (piece, t_start, t_end)."""
    n, t = len(pkt), pkt.t
    if n == 0:
        yield pkt, pkt.t_start, pkt.t_end
        return
    i, start = 0, pkt.t_start
    while i < n:
        j = min(i + max(1, per), n)
        if int(t[j - 1]) - int(t[i]) > _SPAN:
            j = max(i + 1, int(np.searchsorted(t, int(t[i]) + _SPAN, side="right")))
        while j < n and t[j] == t[j - 1]:
            j += 1
        end = pkt.t_end if j == n else int(t[j])
        yield pkt._take_slice(i, j, start, end), start, end
        i, start = j, end


def decode_samples(msg: bytes | memoryview, schema: int, n: int, t_base: int, max_samples: int
                   ) -> tuple[type[SamplePacket], np.ndarray, dict[str, np.ndarray]] | str:
    """(packet class, t, columns) of a SAMPLES message, or the reason to
    reject it. Sizes are checked against the message before any array is
    made."""
    from ._wire import HEADER

    body = bytes(msg[HEADER:])
    try:
        code, k = struct.unpack_from("<BB", body, 0)
        if code not in _CLASSES or k > MAX_COLUMNS:
            return "schema"
        pos = 2
        cols: list[tuple[str, np.dtype, tuple[int, ...]]] = []  # name, dtype, dimensions
        for _ in range(k):
            strs = []
            for _ in range(2):
                ln = body[pos]
                strs.append(body[pos + 1:pos + 1 + ln].decode("ascii"))
                if len(strs[-1]) != ln:
                    return "schema"
                pos += 1 + ln
            nd = body[pos]
            if nd > MAX_DIMS:
                return "schema"
            dims = struct.unpack_from(f"<{nd}I", body, pos + 1)
            pos += 1 + 4 * nd
            if not _DTYPE.fullmatch(strs[1]):
                return "schema"
            dt = np.dtype(strs[1])
            if dt.kind not in "biuf" or dt.itemsize > 8 or not strs[0].isidentifier() \
                    or strs[0] in [c[0] for c in cols] or strs[0] == "t":
                return "schema"
            cols.append((strs[0], dt, dims))
    except (IndexError, struct.error, UnicodeDecodeError, TypeError, ValueError):
        return "schema"
    if zlib.crc32(body[:pos]) != schema:
        return "schema"
    if n > max_samples:
        return "length"
    per = [dt.itemsize * int(np.prod(dims, dtype=np.int64)) for _, dt, dims in cols]
    if any(p > len(body) for p in per) or len(body) != pos + n * (4 + sum(per)):
        return "length"
    t = np.frombuffer(body, "<u4", n, pos).astype(np.int64) + t_base
    pos += 4 * n
    data = {}
    for (name, dt, dims), size in zip(cols, per):
        data[name] = np.frombuffer(body, dt, n * size // dt.itemsize if size else 0, pos).reshape(n, *dims) \
            .astype(dt.newbyteorder("="))
        pos += n * size
    return _CLASSES[code], t, data


def fragments(msg: bytes, piece: int) -> Iterator[tuple[int, int, bytes]]:
    """(index, count, piece bytes) of ``msg`` cut into ``piece``-byte parts."""
    count = -(-len(msg) // piece)
    for i in range(count):
        yield i, count, msg[i * piece:(i + 1) * piece]


class Reassembly:
    """One message being rebuilt from FRAG pieces (bounded by ``max_message``)."""

    def __init__(self, max_message: int) -> None:
        self.max_message = max_message
        self.key: tuple[int, int] | None = None
        self.total = self.count = self.have = 0
        self.parts: dict[int, bytes] = {}
        self.incomplete = 0

    def add(self, session: int, seq: int, index: int, count: int, total: int, piece: bytes) -> bytes | None | str:
        """The whole message once complete, None while waiting, or a reason to reject the piece."""
        if not (0 <= index < count <= 1 << 16) or not (0 < total <= self.max_message) or not piece \
                or len(piece) > total:
            return "fragment"
        key = (session, seq)
        if key != self.key or total != self.total or count != self.count:
            if self.key is not None and self.parts:
                self.incomplete += 1
            self.key, self.total, self.count, self.have, self.parts = key, total, count, 0, {}
        if index in self.parts:
            return "fragment"
        if self.have + len(piece) > total:
            self.key, self.parts = None, {}
            return "fragment"
        self.parts[index] = piece
        self.have += len(piece)
        if len(self.parts) < count:
            return None
        whole = b"".join(self.parts[i] for i in range(count))
        self.key, self.parts = None, {}
        return whole if len(whole) == total else "fragment"
