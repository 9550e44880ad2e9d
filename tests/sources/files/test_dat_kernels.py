"""The DAT reader's vector kernel (decode_dat_within) against the scalar
kernel decode_dat, its plain-Python lanes against the compiled ones, and
the reader's errors for a bad record where the vector lanes, the read
pieces and the packets end."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from tectum import EventPacket, FormatError
from tectum.sources.files import _dat_kernels as DK
from tectum.sources.files import _kernels as K
from tectum.sources.files.prophesee import DatSource


def records(n: int, seed: int, w: int, h: int, n_jumps: int, n_out: int) -> np.ndarray:
    """``n`` DAT records: rising times with ``n_jumps`` jumps of about half
    the 32-bit range (wraps, falls and steps back), coordinates inside
    ``w`` x ``h`` but ``n_out`` outside, every polarity nibble."""
    rng = np.random.default_rng(seed)
    steps = rng.integers(0, 1 << 12, n).astype(np.int64)
    steps[rng.integers(0, n, n_jumps)] += (1 << 31) - (1 << 11)
    times = ((rng.integers(0, 1 << 32) + np.cumsum(steps)) & 0xFFFFFFFF).astype(np.uint64)
    w, h = min(w, 1 << 14), min(h, 1 << 14)  # 14-bit fields
    x = rng.integers(0, w, n).astype(np.uint64)
    y = rng.integers(0, h, n).astype(np.uint64)
    out = rng.integers(0, n, n_out if w < 1 << 14 else 0)
    x[out[::2]] = rng.integers(w, 1 << 14, out[::2].shape[0]).astype(np.uint64)
    y[out[1::2]] = rng.integers(h, 1 << 14, out[1::2].shape[0]).astype(np.uint64)
    pol = rng.integers(0, 16, n).astype(np.uint64)
    return times | ((x | (y << np.uint64(14)) | (pol << np.uint64(28))) << np.uint64(32))


def columns(n: int) -> tuple[np.ndarray, ...]:
    return (np.full(n, -7, np.int64), np.full(n, 7, np.uint16), np.full(n, 7, np.uint16), np.full(n, 7, np.int8))


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 9000), st.lists(st.integers(0, 9000), max_size=3), st.integers(0, 4), st.integers(0, 2),
       st.sampled_from([(1280, 720), (640, 480), (1 << 16, 1 << 16)]), st.integers(0, 40))
def test_within_equals_decode_dat_in_any_chunking(n, cuts, n_jumps, n_out, sensor, at):
    """Same events and state as decode_dat over calls cut anywhere (inside
    and between the 16-record lanes and the 4096-record blocks), written
    from ``at`` on and nothing outside; ``ok`` exactly when decode_dat's
    order holds and its largest x and y are inside the sensor."""
    rec = records(n, n + 17 * n_jumps, *sensor, n_jumps, n_out)
    w, h = sensor
    ref_state, state = np.zeros(K.DAT_STATE, np.int64), np.zeros(K.DAT_STATE, np.int64)
    for part in np.split(rec, sorted(c % (n + 1) for c in cuts)):
        want = columns(len(part))
        _, ordered, mx, my = K.decode_dat(part, ref_state, *want)
        got = columns(len(part) + at + 5)
        k, ok = DK.decode_dat_within(part, len(part), state, *got, at, w, h)
        assert k == len(part)
        for a, b, fill in zip(got, want, (-7, 7, 7, 7)):
            assert np.array_equal(a[at:at + len(part)], b)
            assert (a[:at] == fill).all() and (a[at + len(part):] == fill).all()
        assert state.tolist() == ref_state.tolist()
        assert ok == (ordered and mx < w and my < h)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 9000), st.lists(st.integers(0, 9000), max_size=3), st.integers(0, 4), st.integers(0, 2),
       st.sampled_from([(1280, 720), (1 << 16, 1 << 16)]), st.integers(0, 40))
def test_within_decodes_in_place(n, cuts, n_jumps, n_out, sensor, at):
    """The records read into the time column (as the DAT reader does) and
    decoded there give decode_dat's events, state and bounds: each record
    is read before its time overwrites it, also in the blocks whose times
    are unrolled again (wraps, falls, steps back), and whatever the
    column's alignment (``at``)."""
    rec = records(n, 3 * n + n_jumps, *sensor, n_jumps, n_out)
    w, h = sensor
    ref_state, state = np.zeros(K.DAT_STATE, np.int64), np.zeros(K.DAT_STATE, np.int64)
    got = columns(n + at)
    done = 0
    for part in np.split(rec, sorted(c % (n + 1) for c in cuts)):
        want = columns(len(part))
        _, ordered, mx, my = K.decode_dat(part, ref_state, *want)
        place = got[0][at + done:at + done + len(part)].view(np.uint64)
        place[:] = part
        k, ok = DK.decode_dat_within(place, len(part), state, *got, at + done, w, h)
        assert k == len(part)
        for a, b in zip(got, want):
            assert np.array_equal(a[at + done:at + done + len(part)], b)
        assert state.tolist() == ref_state.tolist()
        assert ok == (ordered and mx < w and my < h)
        done += len(part)


@pytest.mark.parametrize("seed", range(6))
def test_plain_lanes_equal_the_compiled_ones(seed):
    """dat_lanes' plain form (NUMBA_DISABLE_JIT) gives the compiled vector
    code's columns and mask: falls against ``prev`` and within, and
    coordinates outside in any lane."""
    rec = records(48, seed, 640, 480, 3, 6)
    compiled = njit(lambda r, i, t, x, y, p, hi, prev, w, h: DK.dat_lanes(r, i, t, x, y, p, hi, prev, w, h))
    for i, prev in ((0, 0), (16, int(rec[15]) & 0xFFFFFFFF), (32, 1 << 31)):
        a, b = columns(48), columns(48)
        hi = seed << 32
        got = compiled(rec, i, *a, hi, prev, 640, 480)
        want = DK.dat_lanes(rec, i, *b, hi, prev, 640, 480)
        assert got == want
        assert all(np.array_equal(u, v) for u, v in zip(a, b))
    assert want != 0  # the draws put something in the mask


def dat_file(path: Path, n: int, bad: int, what: str) -> Path:
    """A 640x480 DAT file of ``n`` records with rising times, record
    ``bad`` broken by ``what``: "x" outside the sensor, "y" likewise,
    "time" below the one before."""
    t = np.arange(n, dtype=np.int64) * 3 + 1000
    x, y = np.arange(n) % 640, np.arange(n) % 480
    if what == "x":
        x[bad] = 640
    elif what == "y":
        y[bad] = 480 + 77
    else:
        t[bad] = t[bad - 1] - 1
    body = b"".join(struct.pack("<II", int(a), int(b) | (int(c) << 14) | (1 << 28)) for a, b, c in zip(t, x, y))
    path.write_bytes(b"% Data file containing CD events\n% Width 640\n% Height 480\n" + bytes([12, 8]) + body)
    return path


#: Header bytes of :func:`dat_file`'s files (the first record's offset)
HEAD = len(b"% Data file containing CD events\n% Width 640\n% Height 480\n") + 2


@pytest.mark.parametrize("what", ["x", "y", "time"])
@pytest.mark.parametrize("bad", [1, 15, 16, 17, 4095, 4096, 8191, 8192, 8200])
def test_a_bad_record_where_lanes_pieces_and_packets_end(tmp_path: Path, what: str, bad: int) -> None:
    """A record outside the sensor or back in time is refused with its
    byte offset wherever it lies: last or first of a 16-record lane, of a
    4096-record block, of a read piece and of a packet (chunk_bytes 64 KiB,
    so 8192 records a packet), or among the last few after the lanes; with
    skip_bad it alone is dropped."""
    path = dat_file(tmp_path / "f.dat", 8203, bad, what)
    for chunk in (1 << 16, 8 * 4096, 8 * 100):
        with pytest.raises(FormatError) as e:
            list(DatSource(str(path), chunk_bytes=chunk).packets())
        assert e.value.offset == HEAD + 8 * bad, (chunk, str(e.value))
        assert ("sensor" in str(e.value)) == (what != "time")
        src = DatSource(str(path), chunk_bytes=chunk, skip_bad=True)
        n = sum(len(q) for q in src.packets() if isinstance(q, EventPacket))
        assert (n, src.skipped_events) == (8202, 1)
