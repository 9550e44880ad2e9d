"""Prophesee DAT files against a decoder written from Prophesee's format description.

DAT ("DAT File Format" page): ``% keyword value`` header lines, then two
bytes, the event type (Event2d 0, EventCD 12, EventExtTrigger 14, ...) and
the event size (8), then little-endian 8-byte records: uint32 time (µs),
uint32 with x in bits 0-13, y in bits 14-27 and the polarity in bits 28-31.
tectum reads the two CD layouts (types 0 and 12: p = +1 when the polarity
bits are non-zero, else -1), unrolls the 32-bit time (a fall of more than
half the range is a wrap) and refuses other types and sizes with a
FormatError at the type byte.

Hypothesis draws a clock (often just before the 2^32 µs wrap, with steps up
to 2^31 - 1 µs), records and a type; :func:`reference` decodes the bytes
the slow, obvious way and must read what was meant, and tectum's reader (in
drawn chunk sizes, whole and from a drawn start time) must give the same t,
x, y and p value by value.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError
from tectum.sources.files._common import FROM_EXTENT
from tectum.sources.files.prophesee import DatSource

WRAP = 1 << 32


def reference(raw: bytes) -> list[tuple[int, int, int, int]]:
    """The events (t, x, y, p) of a DAT file's bytes."""
    pos = 0
    while raw.startswith(b"%", pos):
        pos = raw.index(b"\n", pos) + 1
    kind, size = raw[pos], raw[pos + 1]
    assert kind in (0, 12) and size == 8
    out, wraps, last = [], 0, None
    for at in range(pos + 2, len(raw) - 7, 8):
        t, d = struct.unpack_from("<II", raw, at)
        if last is not None and last - t > WRAP // 2:
            wraps += 1
        last = t
        out.append((wraps * WRAP + t, d & 0x3FFF, (d >> 14) & 0x3FFF, 1 if d >> 28 else -1))
    return out


@st.composite
def files(draw: st.DrawFn) -> tuple[bytes, int, list[tuple[int, int, int, int]], tuple[int, int]]:
    """(file bytes, header length, the events meant, sensor)."""
    w, h = draw(st.sampled_from([(304, 240), (640, 480), (1280, 720)]))
    kind = draw(st.sampled_from([0, 12]))
    clock = draw(st.one_of(st.integers(WRAP - 3000, WRAP - 1), st.integers(0, WRAP - 1), st.integers(0, 100)))
    origin = clock // WRAP * WRAP
    body, events = b"", []
    for _ in range(draw(st.integers(1, 60))):
        x, y = draw(st.integers(0, w - 1)), draw(st.integers(0, h - 1))
        pol = draw(st.sampled_from([0, 1, 1, 0xF]))  # 4 polarity bits: non-zero is ON
        body += struct.pack("<II", clock % WRAP, x | (y << 14) | (pol << 28))
        events.append((clock - origin, x, y, 1 if pol else -1))
        clock += draw(st.one_of(st.integers(0, 30), st.integers(0, 5000), st.integers(0, WRAP // 2 - 1)))
    head = (f"% Data file containing {'CD' if kind else '2D'} events\n% Date 2020-09-14 14:18:29\n% Version 2\n"
            f"% Width {w}\n% Height {h}\n").encode()
    return head + bytes([kind, 8]) + body, len(head), events, (w, h)


def read(path: Path, **kw) -> list[tuple[int, int, int, int]]:
    ev = [q for q in DatSource(str(path), **kw).packets() if isinstance(q, EventPacket) and len(q)]
    return list(zip(*[np.concatenate([getattr(q, c) for q in ev]).tolist() if ev else [] for c in "txyp"]))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=files(), chunk=st.sampled_from([64, 72, 1 << 16]), data=st.data())
def test_dat_equals_the_reference(tmp_path: Path, case: tuple, chunk: int, data: st.DataObject) -> None:
    raw, _, events, sensor = case
    assert reference(raw) == events  # the reference reads what was meant
    path = tmp_path / "r.dat"
    path.write_bytes(raw)
    assert read(path, chunk_bytes=chunk) == events
    assert all(q.sensor == sensor for q in DatSource(str(path)).packets() if isinstance(q, EventPacket))
    if events[-1][0] < WRAP:  # a start time is found by bisection, in a file without a wrap
        start = data.draw(st.integers(0, events[-1][0] + 1))
        assert read(path, chunk_bytes=chunk, t_start_us=start) == [e for e in events if e[0] >= start]


@pytest.mark.parametrize("kind,size", [(14, 8), (0, 16), (1, 8)])
def test_other_types_and_sizes_are_refused(tmp_path: Path, kind: int, size: int) -> None:
    head = b"% Data file containing CD events\n% Version 2\n% Width 640\n% Height 480\n"
    path = tmp_path / "t.dat"
    path.write_bytes(head + bytes([kind, size]) + struct.pack("<II", 5, 1 | (2 << 14)))
    with pytest.raises(FormatError, match="event (type|size)") as e:
        read(path)
    assert e.value.offset in (len(head), len(head) + 1)


def test_geometry_truncation_and_end_time(tmp_path: Path) -> None:
    """No Width/Height lines: the sensor is the extent of the coordinates; a
    file cut inside a record is named at the cut (``skip_bad`` drops the
    partial record); ``t_end_us`` stops before the first later event; a
    RAW header is refused."""
    events = [(10, 3, 4, 1), (20, 7, 2, -1), (30, 1, 9, 1)]
    body = b"".join(struct.pack("<II", t, x | y << 14 | (p > 0) << 28) for t, x, y, p in events)
    head = b"% Data file containing CD events\n% Version 2\n"
    path = tmp_path / "g.dat"
    path.write_bytes(head + bytes([12, 8]) + body + b"\x01\x02\x03")
    with pytest.raises(FormatError, match="inside an 8-byte record") as e:
        read(path)
    assert e.value.offset == len(head) + 2 + len(body)
    assert read(path, skip_bad=True) == events
    src = DatSource(str(path), skip_bad=True)
    assert [q.sensor for q in src.packets() if isinstance(q, EventPacket)][0] == (8, 10)
    assert src.sensor_from == FROM_EXTENT
    assert read(path, skip_bad=True, t_end_us=25) == events[:2]
    path.write_bytes(b"% evt 3.0\n" + bytes([12, 8]) + body)
    with pytest.raises(FormatError, match="RAW"):
        read(path)
