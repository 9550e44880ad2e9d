"""Prophesee readers on a file whose reads come short (the RAW and DAT
readers open files unbuffered, where the OS may return fewer bytes than
asked before the end, as network and FUSE file systems do): the same
events, triggers and error offsets as on whole reads, on every path that
reads (decoding, the coordinate scan of a file without geometry, EVT 2.0's
bisection for a start time, the offsets of a bad event)."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest

from tectum import EventPacket, FormatError
from tectum.sources.files._common import FileSource
from tectum.sources.files.prophesee import DatSource, Evt2Source


class _Short:
    """A file whose reads return at most ``cap`` bytes (odd: words and
    records come cut)."""

    def __init__(self, f: Any, cap: int) -> None:
        self._f, self._cap = f, cap

    def readinto(self, b: Any) -> int:
        return self._f.readinto(memoryview(b).cast("B")[:self._cap])

    def read(self, n: int = -1) -> bytes:
        return self._f.read(self._cap if n < 0 else min(n, self._cap))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


@pytest.fixture
def short_reads(monkeypatch: pytest.MonkeyPatch) -> None:
    opened = FileSource._open

    def _open(self: FileSource, buffering: int = -1) -> Any:
        f = opened(self, buffering)
        return _Short(f, 1021) if buffering == 0 else f

    monkeypatch.setattr(FileSource, "_open", _open)


def _events(src: Any) -> list[tuple[Any, ...]]:
    """(t, x, y, p, sensor) of every event."""
    out: list[tuple[Any, ...]] = []
    for q in src.packets():
        if isinstance(q, EventPacket):
            out += zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), q.p.tolist(), [q.sensor] * len(q))
    return out


def _dat(path: Path, geometry: bool, x_last: int = 5) -> None:
    head = b"% Data file containing CD events\n% Version 2\n" + (b"% Width 64\n% Height 48\n" if geometry else b"")
    body = b"".join(struct.pack("<II", 10 * i, (i % 60) | ((i % 40) << 14) | ((i & 1) << 28)) for i in range(3000))
    body += struct.pack("<II", 30_000, x_last | (3 << 14))
    path.write_bytes(head + bytes([12, 8]) + body)


def _evt2(path: Path, geometry: bool, x_last: int = 5) -> None:
    words = []
    for th in range(40):  # a TIME_HIGH word a 64 µs, 100 events under each
        words.append(0x8 << 28 | th)
        words += [(th & 1) << 28 | (i * 64 // 100) << 22 | (i % 60) << 11 | (th + i) % 40 for i in range(100)]
    words += [0x8 << 28 | 40, 1 << 28 | x_last << 11 | 3]
    head = "% evt 2.0\n" + ("% geometry 64x48\n" if geometry else "") + "% end\n"
    path.write_bytes(head.encode() + struct.pack(f"<{len(words)}I", *words))


@pytest.mark.parametrize("geometry", [True, False])
@pytest.mark.parametrize("kind", ["dat", "evt2"])
def test_short_reads_decode_the_same(tmp_path: Path, kind: str, geometry: bool, monkeypatch: pytest.MonkeyPatch,
                                     short_reads: None) -> None:
    path = tmp_path / f"f.{'dat' if kind == 'dat' else 'raw'}"
    (_dat if kind == "dat" else _evt2)(path, geometry)
    cls = DatSource if kind == "dat" else Evt2Source
    kw: dict[str, Any] = {"chunk_bytes": 4096}
    got = {t: _events(cls(str(path), **kw, t_start_us=t)) for t in (None, 1200)}
    monkeypatch.undo()  # whole reads
    want = {t: _events(cls(str(path), **kw, t_start_us=t)) for t in (None, 1200)}
    assert len(want[None]) > 3000 and 0 < len(want[1200]) < len(want[None])
    assert got == want


@pytest.mark.parametrize("kind", ["dat", "evt2"])
def test_a_bad_events_offset_with_short_reads(tmp_path: Path, kind: str, monkeypatch: pytest.MonkeyPatch,
                                              short_reads: None) -> None:
    path = tmp_path / f"bad.{'dat' if kind == 'dat' else 'raw'}"
    (_dat if kind == "dat" else _evt2)(path, True, x_last=93)  # the last event's x past the 64 px geometry
    cls = DatSource if kind == "dat" else Evt2Source
    with pytest.raises(FormatError, match="outside the 64x48 sensor") as short:
        _events(cls(str(path), chunk_bytes=4096))
    monkeypatch.undo()
    with pytest.raises(FormatError) as whole:
        _events(cls(str(path), chunk_bytes=4096))
    assert short.value.offset == whole.value.offset == path.stat().st_size - (8 if kind == "dat" else 4)
