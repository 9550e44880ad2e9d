"""What the sources of sample files (TUM, CSV, PLY) share: the base class,
text lines with their numbers, row parsing with the checks every row gets,
and the assembly of checked rows into packets.

Bad rows (a token that is no number of the column's type, a wrong number of
columns, a time going backwards, or what the format's own check refuses)
raise :class:`tectum.FormatError` naming the file, the byte offset and the
line; with ``skip_bad=True`` they are dropped and counted
(:attr:`FileSource.skipped_events`, shown as ``skipped_rows`` in ``--stats``).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import IO, Any

import numpy as np

from tectum import EventPacket, SamplePacket
from tectum.tables import Group

from ._common import FileSource, SampleTiler

__all__ = ["SampleFileSource", "RowStream", "RowParser", "Line", "text_lines", "whole_us"]


@dataclass(frozen=True)
class Line:
    """A line of a text file: its number (from 1), byte offset and text
    without the line end."""

    number: int
    offset: int
    text: bytes


class SampleFileSource(FileSource):
    """Base of the sample-file sources: skipped rows as counters, and
    ``info`` that gives the span of the samples when there are no events."""

    def __init__(self, path: str, **kw: Any) -> None:
        super().__init__(path, **kw)
        #: Counters for the run's stats: rows dropped with ``skip_bad``.
        self.counts = {"skipped_rows": 0}

    def _open(self, buffering: int = -1) -> Any:
        """The file, which must not be empty: no bytes is no file of the
        format, never a stream of no samples."""
        f = super()._open(buffering)
        if os.fstat(f.fileno()).st_size == 0:
            self._fail("empty file: no header and no rows", 0)
        return f

    def _note_skip(self, first: int, last: int, n: int) -> None:
        super()._note_skip(first, last, n)
        self.counts["skipped_rows"] += n

    def bad_row(self, line: Line | None, offset: int, message: str) -> None:
        """Raise :class:`tectum.FormatError` for a bad row, or with
        ``skip_bad`` count it and go on."""
        if not self.skip_bad:
            self._fail(message if line is None else f"line {line.number}: {message}", offset)
        self._note_skip(offset, offset, 1)

    def info(self) -> dict[str, Any]:
        counts: dict[str, int] = {}
        first: int | None = None
        last: int | None = None
        for pkt in self.packets():
            counts[str(pkt.kind)] = counts.get(str(pkt.kind), 0) + len(pkt)
            if len(pkt) and not isinstance(pkt, EventPacket):
                first = int(pkt.t[0]) if first is None else min(first, int(pkt.t[0]))
                last = int(pkt.t[-1]) if last is None else max(last, int(pkt.t[-1]))
        return {"format": self.format, "path": self.path, "sensor": None, "events": 0, "t_first_us": first,
                "t_last_us": last, "duration_us": (last - first) if first is not None and last is not None else 0,
                "rate_mev_s": 0.0, "streams": counts, "t0_offset_us": 0, "skipped_events": self.skipped_events}


def text_lines(f: IO[bytes], chunk_bytes: int, number: int = 0, offset: int = 0) -> Iterator[list[Line]]:
    """The lines of ``f`` from where it stands (line ``number + 1`` at byte
    ``offset``), a chunk of about ``chunk_bytes`` at a time; blank lines
    and ``#`` comments are left out, a last line needs no line end."""
    rest = b""
    while True:
        data = f.read(chunk_bytes)
        buf = rest + data
        if not data:
            if not buf:
                return
            buf += b"\n"
        cut = buf.rfind(b"\n") + 1
        rest = buf[cut:]
        out = []
        for raw in buf[:cut].split(b"\n")[:-1]:
            number += 1
            text = raw.rstrip(b"\r")
            s = text.strip()
            if s and not s.startswith(b"#"):
                out.append(Line(number, offset, text))
            offset += len(raw) + 1
        if out:
            yield out


#: A row check: the parsed values of one row (``t`` first) -> why it is bad, or None.
RowCheck = Callable[[Sequence[Any]], "str | None"]


class RowParser:
    """Turns text lines into columns: ``split`` cuts a line into tokens,
    token ``time_at`` is the time (``time`` converts it to integer µs,
    raising ValueError; without ``time_at`` it gets ``b""``), the others
    fill ``groups`` at the token positions
    ``positions`` (one list per group) as ints or floats by the group's
    dtype. Rows going back in time, and rows ``check`` refuses, are bad."""

    def __init__(self, src: SampleFileSource, groups: Sequence[Group], positions: Sequence[Sequence[int]],
                 tokens: int, split: Callable[[bytes], list[bytes]], time: Callable[[bytes], int],
                 check: RowCheck | None = None, time_at: int | None = 0) -> None:
        self.src = src
        self.time_at = time_at
        self.groups = list(groups)
        self.tokens = tokens
        self.split = split
        self.time = time
        self.check = check
        self.last_t: int | None = None
        #: (token position, converter, name) per value column, in group order
        self.columns: list[tuple[int, Callable[[bytes], Any], str]] = []
        for g, pos in zip(self.groups, positions):
            conv = _int_reader(g.dtype) if g.dtype.kind in "biu" else _float
            self.columns += [(p, conv, c) for p, c in zip(pos, g.columns)]

    def parse(self, lines: Sequence[Line]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The good rows of ``lines``: ``t`` (int64 µs) and the fields."""
        ts: list[int] = []
        rows: list[list[Any]] = []
        for line in lines:
            row = self._row(line)
            if row is not None:
                ts.append(row[0])
                rows.append(row[1:])
        t = np.array(ts, np.int64)
        data: dict[str, np.ndarray] = {}
        k = 0
        for g in self.groups:
            w = 1 if g.width is None else g.width
            block = np.array([r[k:k + w] for r in rows], g.dtype).reshape(len(rows), w)
            data[g.field] = block[:, 0] if g.width is None else block
            k += w
        return t, data

    def _row(self, line: Line) -> list[Any] | None:
        toks = self.split(line.text)
        if len(toks) != self.tokens:
            self.src.bad_row(line, line.offset, f"{len(toks)} columns, expected {self.tokens}")
            return None
        if b"_" in line.text:
            self.src.bad_row(line, line.offset, "'_' inside a number")
            return None
        try:
            t = self.time(toks[self.time_at] if self.time_at is not None else b"")
        except ValueError as e:
            self.src.bad_row(line, line.offset, f"time: {e}")
            return None
        row: list[Any] = [t]
        for pos, conv, name in self.columns:
            try:
                row.append(conv(toks[pos]))
            except ValueError as e:
                self.src.bad_row(line, line.offset, f"column {name!r}: {e}")
                return None
        why = self.check(row) if self.check is not None else None
        if why is None and self.last_t is not None and t < self.last_t:
            why = f"time goes backwards: {t} µs after {self.last_t} µs"
        if why is not None:
            self.src.bad_row(line, line.offset, why)
            return None
        self.last_t = t
        return row


def _float(tok: bytes) -> float:
    try:
        return float(tok)
    except ValueError:
        raise ValueError(f"{tok.strip()[:40]!r} is not a number") from None


def _int_reader(dtype: np.dtype) -> Callable[[bytes], int]:
    info = np.iinfo(dtype) if dtype.kind != "b" else None
    lo, hi = (0, 1) if info is None else (int(info.min), int(info.max))

    def read(tok: bytes) -> int:
        try:
            v = int(tok)
        except ValueError:
            raise ValueError(f"{tok.strip()[:40]!r} is not an integer") from None
        if not lo <= v <= hi:
            raise ValueError(f"{v} is out of the {dtype} range")
        return v

    return read


def whole_us(tok: bytes) -> int:
    """An integer µs token (CSV ``t``)."""
    try:
        v = int(tok)
    except ValueError:
        raise ValueError(f"{tok.strip()[:40]!r} is not an integer µs") from None
    if not -(1 << 63) <= v < (1 << 63):
        raise ValueError(f"{v} is out of the int64 µs range")
    return v


class RowStream:
    """Checked rows of one stream (times non-decreasing) into packets: the
    rows of a chunk's last timestamp wait for the next chunk (a timestamp is
    never split across packets), then :class:`SampleTiler` clips to the
    source's time range and tiles the intervals."""

    def __init__(self, src: FileSource, cls: type[SamplePacket]) -> None:
        self.cls = cls
        self.tiler = SampleTiler(src)
        self.carry: tuple[np.ndarray, dict[str, np.ndarray]] | None = None

    def push(self, t: np.ndarray, data: dict[str, np.ndarray], pos: int = 0) -> Iterator[SamplePacket]:
        if self.carry is not None:
            ct, cd = self.carry
            t = np.concatenate([ct, t])
            data = {k: np.concatenate([cd[k], v]) for k, v in data.items()}
            self.carry = None
        if t.shape[0] == 0:
            return
        i = int(np.searchsorted(t, t[-1], side="left"))
        self.carry = (t[i:], {k: v[i:] for k, v in data.items()})
        if i:
            yield from self._emit(t[:i], {k: v[:i] for k, v in data.items()}, pos)

    def finish(self) -> Iterator[SamplePacket]:
        if self.carry is not None:
            t, data = self.carry
            self.carry = None
            yield from self._emit(t, data, 0)

    def _emit(self, t: np.ndarray, data: dict[str, np.ndarray], pos: int) -> Iterator[SamplePacket]:
        pkt = self.tiler.push(self.cls, self.cls.kind, t, pos, **data)
        if pkt is not None:
            yield pkt
