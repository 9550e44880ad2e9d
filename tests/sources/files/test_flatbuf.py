"""The small FlatBuffers reader and table writer behind AEDAT 4.0: a table
of scalars, an inline struct, a string and a vector written and read back;
every accessor on absent fields gives its default; damaged buffers (bytes
overwritten, cut short) read or raise FlatError, never read past the
buffer or raise anything else."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum.sources.files._flatbuf import FlatError, Table, build_table, root

FIELDS = [("q", -(1 << 40)), None, ("raw", struct.pack("<qhh4x", 7, 3, 4)), ("f", 1.5), ("b", -3)]
BLOB = struct.pack("<5I", 1, 2, 3, 4, 5)


def built(size_prefixed: bool = True) -> bytes:
    return build_table(FIELDS + [None], b"TEST", size_prefixed=size_prefixed, blob=BLOB, blob_field=5, blob_count=5)


def read_all(t: Table) -> tuple:
    """Every accessor on every field."""
    out = [t.scalar(0, "q"), t.scalar(1, "i", default=9), t.struct_at(2, 16), t.scalar(3, "f"), t.scalar(4, "b"),
           t.vector(5, 4), t.vector(1, 4), t.string(1), t.scalar(40, "i"), t.struct_at(1, 4)]
    start, n = t.vector(5, 4)
    out.append(struct.unpack_from(f"<{n}I", t.buf, start) if n else ())
    out.append(t.string(5))
    return tuple(out)


@pytest.mark.parametrize("size_prefixed", [True, False])
def test_a_table_reads_back(size_prefixed: bool) -> None:
    buf = built(size_prefixed)
    t = root(buf, size_prefixed=size_prefixed, ident=b"TEST")
    got = read_all(t)
    assert got[0] == -(1 << 40) and got[1] == 9 and got[3] == 1.5 and got[4] == -3
    assert struct.unpack_from("<qhh", buf, got[2]) == (7, 3, 4)
    assert got[5][1] == 5 and got[6] == (0, 0) and got[7] == "" and got[8] == 0 and got[9] is None
    assert got[10] == (1, 2, 3, 4, 5)
    assert t.tables(1) == []


def test_root_checks_are_named() -> None:
    buf = built()
    with pytest.raises(FlatError, match="too short"):
        root(buf[:8], size_prefixed=True)
    with pytest.raises(FlatError, match="size prefix"):
        root(struct.pack("<I", 10_000) + buf[4:], size_prefixed=True)
    with pytest.raises(FlatError, match="identifier b'TEST' is not b'EVTS'"):
        root(buf, size_prefixed=True, ident=b"EVTS")
    with pytest.raises(FlatError, match="table offset"):
        Table(buf, len(buf))
    with pytest.raises(FlatError, match="vector 5 of 5 elements runs past"):
        root(buf, size_prefixed=True).vector(5, 400)
    with pytest.raises(FlatError):  # tables whose offsets point outside the buffer
        root(buf, size_prefixed=True).tables(5)


@settings(max_examples=300, deadline=None)
@given(edits=st.lists(st.tuples(st.integers(0, 200), st.integers(0, 255)), min_size=1, max_size=4),
       cut=st.one_of(st.none(), st.integers(0, 200)), size_prefixed=st.booleans())
def test_damaged_tables_read_or_raise_flat_error(edits: list[tuple[int, int]], cut: int | None,
                                                 size_prefixed: bool) -> None:
    raw = bytearray(built(size_prefixed))
    for at, value in edits:
        raw[at % len(raw)] = value
    if cut is not None:
        raw = raw[:cut % (len(raw) + 1)]
    buf = bytes(raw)
    try:
        t = root(buf, size_prefixed=size_prefixed)
        read_all(t)
        t.tables(5)
    except FlatError as e:
        assert str(e)
