"""Point clouds from PLY files (``.ply``): ASCII, binary little- and
big-endian, as tectum writes them (:mod:`tectum.sinks.files.ply`) and as
other tools do.

The ``vertex`` element gives the points: ``x y z`` (any numeric type, read
as float64 metres), ``intensity`` when present (float32), and the time
``t_us`` in µs when present (a whole number in any numeric type; tectum
writes it as a ``double``, exact up to 2**53 µs). A file without ``t_us``
is one cloud at the time given by the ``t_us`` option (default 0). Other
vertex properties and other elements (faces ...) are ignored.

A malformed header, a vertex element without ``x y z`` or with list
properties, or a file shorter than its vertex count is a
:class:`tectum.FormatError`; so are rows whose time is not a whole number
or goes back (named by line, ASCII, or byte offset, binary), unless
``skip_bad=true`` drops and counts them.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

from tectum import FormatError, Kind, Packet, PointPacket
from tectum.tables import Group, PlyElement, PlyHeader, parse_ply_header

from ._rows import RowParser, RowStream, SampleFileSource, text_lines

__all__ = ["PlySource"]

_MAX_T = 2.0**53


def _whole_us(tok: bytes) -> int:
    """A ``t_us`` token: an integer, or a float that is a whole number."""
    try:
        return int(tok)
    except ValueError:
        pass
    try:
        v = float(tok)
    except ValueError:
        raise ValueError(f"{tok.strip()[:40]!r} is not a number") from None
    if not math.isfinite(v) or v != round(v) or abs(v) > _MAX_T:
        raise ValueError(f"t_us={v!r} is not a whole number of µs within 2**53")
    return int(v)


class PlySource(SampleFileSource):
    """Point clouds (``PointPacket``) from a PLY file.

    Parameters (besides :class:`FileSource`'s)
    ------------------------------------------
    t_us:
        Time (µs) of the points of a file without a ``t_us`` property.
    """

    name = "ply"
    format = "ply"
    extensions = (".ply",)
    produces = (Kind.POINTS,)

    def __init__(self, path: str, t_us: int = 0, **kw: Any) -> None:
        super().__init__(path, **kw)
        self.t_us = int(t_us)

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith((b"ply\n", b"ply\r\n"))

    def _header(self, f: IO[bytes]) -> tuple[PlyHeader, int]:
        """The header and the index of the vertex element."""
        try:
            h = parse_ply_header(f)
        except ValueError as e:
            raise FormatError(str(e), path=self.path, offset=0) from None
        names = [e.name for e in h.elements]
        if "vertex" not in names:
            raise FormatError(f"no 'vertex' element (elements: {names})", path=self.path, offset=h.size)
        v = h.elements[names.index("vertex")]
        props = dict(v.properties)
        missing = [c for c in "xyz" if c not in props]
        if missing:
            raise FormatError(f"the vertex element has no {', '.join(missing)} (properties: {list(props)})",
                              path=self.path, offset=h.size)
        lists = [n for n, ty in v.properties if not isinstance(ty, str)]
        if lists:
            raise FormatError(f"vertex list properties {lists} are not supported", path=self.path, offset=h.size)
        return h, names.index("vertex")

    def _packets(self) -> Iterator[Packet]:
        f = self._open()
        h, k = self._header(f)
        stream = RowStream(self, PointPacket)
        if h.format == "ascii":
            yield from self._ascii(f, h, k, stream)
        else:
            yield from self._binary(f, h, k, stream)
        yield from stream.finish()

    # -- ASCII ----------------------------------------------------------------------------------------------------
    def _ascii(self, f: IO[bytes], h: PlyHeader, k: int, stream: RowStream) -> Iterator[Packet]:
        f.seek(0)
        number = f.read(h.size).count(b"\n")
        offset = h.size
        for e in h.elements[:k]:  # one line per row
            for _ in range(e.count):
                offset += len(f.readline())
                number += 1
        v = h.elements[k]
        names = [n for n, _ in v.properties]
        groups = [Group("position", ("x", "y", "z"), np.dtype(np.float64), 3)]
        positions = [[names.index(c) for c in "xyz"]]
        if "intensity" in names:
            groups.append(Group("intensity", ("intensity",), np.dtype(np.float32), None))
            positions.append([names.index("intensity")])
        at = names.index("t_us") if "t_us" in names else None
        const = self.t_us
        parser = RowParser(self, groups, positions, len(names), bytes.split,
                           _whole_us if at is not None else (lambda _: const), time_at=at)
        left = v.count
        if not left:
            return
        for lines in text_lines(f, self.chunk_bytes, number, offset):
            lines = lines[:left]
            left -= len(lines)
            t, data = parser.parse(lines)
            yield from stream.push(t, data, lines[0].offset)
            if not left:
                return
        self._short(v, v.count - left, h.size)

    def _short(self, v: PlyElement, got: int, offset: int) -> None:
        if not self.skip_bad:
            self._fail(f"the header says {v.count} vertices, the file holds {got}", offset)
        self._note_skip(offset, offset, v.count - got)

    # -- binary ---------------------------------------------------------------------------------------------------
    def _binary(self, f: IO[bytes], h: PlyHeader, k: int, stream: RowStream) -> Iterator[Packet]:
        f.seek(h.size)
        for e in h.elements[:k]:
            _skip_rows(f, e, h.byte_order)
        v = h.elements[k]
        dtype = v.dtype(h.byte_order)
        assert dtype is not None
        step = max(1, self.chunk_bytes // dtype.itemsize)
        last: int | None = None
        done = 0
        while done < v.count:
            n = min(step, v.count - done)
            pos = f.tell()
            buf = f.read(n * dtype.itemsize)
            rec = np.frombuffer(buf[:len(buf) - len(buf) % dtype.itemsize], dtype)
            got = rec.shape[0]
            keep, t = self._binary_times(rec, pos, dtype.itemsize, last, done)
            rec, t = rec[keep], t[keep]
            if t.shape[0]:
                last = int(t[-1])
            data = {"position": np.stack([rec[c].astype(np.float64) for c in "xyz"], axis=1)}
            if "intensity" in (rec.dtype.names or ()):
                data["intensity"] = rec["intensity"].astype(np.float32)
            yield from stream.push(t, data, pos)
            done += got
            if got < n:
                self._short(v, done, pos + len(buf))
                return

    def _binary_times(self, rec: np.ndarray, pos: int, size: int, last: int | None,
                      first: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows to keep and their times (µs) of the vertices from index
        ``first`` at byte ``pos``: bad rows (time not whole, or going back)
        raise, or with ``skip_bad`` are dropped and counted."""
        n = rec.shape[0]
        if "t_us" not in (rec.dtype.names or ()):
            return np.ones(n, bool), np.full(n, self.t_us, np.int64)
        raw = rec["t_us"]
        if raw.dtype.kind == "f":
            whole = np.isfinite(raw) & (np.abs(raw) <= _MAX_T)
            whole[whole] &= raw[whole] == np.round(raw[whole])
        else:
            whole = np.ones(n, bool)
        t = np.where(whole, raw, 0).astype(np.int64)
        run = np.maximum.accumulate(np.where(whole, t, np.iinfo(np.int64).min))
        before = np.concatenate([[np.iinfo(np.int64).min if last is None else last], run[:-1]])
        if last is not None:
            before = np.maximum(before, last)
        bad = ~whole | (t < before)
        for i in np.flatnonzero(bad):
            why = (f"t_us={raw[i]!r} is not a whole number of µs within 2**53" if not whole[i]
                   else f"time goes backwards: {int(t[i])} µs after {int(before[i])} µs")
            self.bad_row(None, pos + int(i) * size, f"vertex {first + int(i)}: {why}")
        return ~bad, t


def _skip_rows(f: IO[bytes], e: PlyElement, order: str) -> None:
    """Move ``f`` past the rows of element ``e`` (binary)."""
    dtype = e.dtype(order)
    if dtype is not None:
        f.seek(e.count * dtype.itemsize, 1)
        return
    for _ in range(e.count):
        for _, ty in e.properties:
            if isinstance(ty, str):
                f.seek(np.dtype(ty).itemsize, 1)
            else:
                count = np.frombuffer(f.read(np.dtype(ty[0]).itemsize), order + ty[0])
                f.seek(int(count[0]) * np.dtype(ty[1]).itemsize if count.size else 0, 1)
