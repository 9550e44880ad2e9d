"""A small, bounds-checked FlatBuffers reader and a writer for flat tables.

Enough of the FlatBuffers binary format for AEDAT 4.0: tables (vtable
lookup), scalars, strings, vectors of structs and vectors of tables. Every
read checks bounds and raises :class:`FlatError` (the callers turn it into a
:class:`tectum.FormatError` with the file offset), so corrupt input never
reads past a buffer or loops.

Writer: :func:`build_table` lays out one table whose fields are scalars,
structs (bytes) or one trailing byte blob (a vector), which is all the
AEDAT 4.0 writer needs; nested tables are built by the callers.
"""

from __future__ import annotations

import struct
from typing import Any

__all__ = ["FlatError", "Table", "root", "build_table"]


class FlatError(ValueError):
    """The bytes are not a well-formed FlatBuffer of the expected shape."""


class Table:
    """A table at byte ``pos`` of ``buf``."""

    __slots__ = ("buf", "pos", "vt", "nfields")

    def __init__(self, buf: memoryview | bytes, pos: int) -> None:
        n = len(buf)
        if pos < 0 or pos + 4 > n:
            raise FlatError(f"table offset {pos} outside the buffer ({n} bytes)")
        vt = pos - struct.unpack_from("<i", buf, pos)[0]
        if vt < 0 or vt + 4 > n:
            raise FlatError(f"vtable offset {vt} outside the buffer")
        vsize, _ = struct.unpack_from("<HH", buf, vt)
        if vsize < 4 or vsize % 2 or vt + vsize > n:
            raise FlatError(f"bad vtable size {vsize}")
        self.buf, self.pos, self.vt, self.nfields = buf, pos, vt, (vsize - 4) // 2

    def _field(self, i: int) -> int:
        if i >= self.nfields:
            return 0
        return struct.unpack_from("<H", self.buf, self.vt + 4 + 2 * i)[0]

    def scalar(self, i: int, fmt: str, default: Any = 0) -> Any:
        off = self._field(i)
        if not off:
            return default
        at = self.pos + off
        if at + struct.calcsize(fmt) > len(self.buf):
            raise FlatError(f"field {i} runs past the buffer")
        return struct.unpack_from("<" + fmt, self.buf, at)[0]

    def struct_at(self, i: int, size: int) -> int | None:
        """Byte position of an inline struct field (or None when absent)."""
        off = self._field(i)
        if not off:
            return None
        if self.pos + off + size > len(self.buf):
            raise FlatError(f"struct field {i} runs past the buffer")
        return self.pos + off

    def _ref(self, i: int) -> int | None:
        off = self._field(i)
        if not off:
            return None
        at = self.pos + off
        if at + 4 > len(self.buf):
            raise FlatError(f"offset field {i} runs past the buffer")
        return at + struct.unpack_from("<I", self.buf, at)[0]

    def vector(self, i: int, elem_size: int) -> tuple[int, int]:
        """(byte position of the first element, length); (0, 0) when absent."""
        at = self._ref(i)
        if at is None:
            return 0, 0
        if at + 4 > len(self.buf):
            raise FlatError(f"vector {i} header outside the buffer")
        n = struct.unpack_from("<I", self.buf, at)[0]
        if at + 4 + n * elem_size > len(self.buf):
            raise FlatError(f"vector {i} of {n} elements runs past the buffer")
        return at + 4, n

    def string(self, i: int) -> str:
        start, n = self.vector(i, 1)
        return bytes(self.buf[start:start + n]).decode("utf-8", "replace") if n else ""

    def tables(self, i: int) -> list[Table]:
        start, n = self.vector(i, 4)
        out = []
        for k in range(n):
            at = start + 4 * k
            out.append(Table(self.buf, at + struct.unpack_from("<I", self.buf, at)[0]))
        return out


def root(buf: memoryview | bytes, size_prefixed: bool = False, ident: bytes | None = None) -> Table:
    """The root table of a buffer (optionally size-prefixed, with identifier)."""
    base = 4 if size_prefixed else 0
    if len(buf) < base + 8:
        raise FlatError(f"buffer of {len(buf)} bytes is too short for a FlatBuffer")
    if size_prefixed:
        n = struct.unpack_from("<I", buf, 0)[0]
        if n + 4 > len(buf):
            raise FlatError(f"size prefix {n} exceeds the buffer ({len(buf) - 4} bytes)")
    if ident is not None and bytes(buf[base + 4:base + 8]) != ident:
        raise FlatError(f"identifier {bytes(buf[base + 4:base + 8])!r} is not {ident!r}")
    return Table(buf, base + struct.unpack_from("<I", buf, base)[0])


def build_table(fields: list[tuple[str, Any] | None], ident: bytes, *, size_prefixed: bool,
                blob: bytes = b"", blob_field: int | None = None, blob_align: int = 8,
                blob_count: int | None = None) -> bytes:
    """One root table: ``fields[i]`` is ``(struct_fmt, value)`` (a scalar),
    ``("raw", bytes)`` (an inline struct, 8-aligned) or None (absent); the
    field ``blob_field`` is an offset to a vector whose bytes are ``blob``
    (``blob_count`` elements, aligned to ``blob_align`` from the buffer start).
    """
    base = 4 if size_prefixed else 0
    nf = len(fields)
    vt_pos = base + 8
    vt_size = 4 + 2 * nf
    table_pos = vt_pos + vt_size
    table_pos += (-table_pos) % 8
    # lay out the table body: soffset, then fields (8-byte values first, 8-aligned)
    order = sorted((i for i, f in enumerate(fields) if f is not None or i == blob_field),
                   key=lambda i: -_size(fields[i], i == blob_field))
    body = bytearray(4)
    offsets = [0] * nf
    for i in order:
        f = fields[i]
        sz = _size(f, i == blob_field)
        al = min(sz, 8)
        while (table_pos + len(body)) % al:
            body += b"\0"
        offsets[i] = len(body)
        if i == blob_field:
            body += b"\0\0\0\0"
        elif f[0] == "raw":  # type: ignore[index]
            body += f[1]  # type: ignore[index]
        else:
            body += struct.pack("<" + f[0], f[1])  # type: ignore[index]
    vec_len_pos = table_pos + len(body)
    while (vec_len_pos + 4) % blob_align:
        vec_len_pos += 1
    out = bytearray(vec_len_pos + (4 + len(blob) if blob_field is not None else 0))
    struct.pack_into("<I", out, base, table_pos - base)
    out[base + 4:base + 8] = ident
    struct.pack_into("<HH", out, vt_pos, vt_size, len(body))
    for i, off in enumerate(offsets):
        struct.pack_into("<H", out, vt_pos + 4 + 2 * i, off)
    out[table_pos:table_pos + len(body)] = body
    struct.pack_into("<i", out, table_pos, table_pos - vt_pos)
    if blob_field is not None:
        ref = table_pos + offsets[blob_field]
        struct.pack_into("<I", out, ref, vec_len_pos - ref)
        count = blob_count if blob_count is not None else len(blob)
        struct.pack_into("<I", out, vec_len_pos, count)
        out[vec_len_pos + 4:] = blob
    if size_prefixed:
        struct.pack_into("<I", out, 0, len(out) - 4)
    return bytes(out)


def _size(f: tuple[str, Any] | None, is_blob: bool) -> int:
    if is_blob or f is None:
        return 4
    if f[0] == "raw":
        return 8 if len(f[1]) % 8 == 0 else len(f[1])
    return struct.calcsize(f[0])
