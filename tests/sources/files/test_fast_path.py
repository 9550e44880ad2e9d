"""The zero-copy decode path: pooled output columns are never overwritten
while a packet (or view) still uses them, kernels resume where a full output
stopped them, the event check matches a plain reference, and the LZ4 fast
path gives what ``lz4.frame`` gives."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError, concat
from tectum.sinks.files import SINKS
from tectum.sinks.files._common import write_all
from tectum.sources.files import _kernels as K
from tectum.sources.files import open_file, prophesee
from tectum.sources.files._common import HUGE_SET, ColumnPool

EXT = {"text": ".txt", "aedat4": ".aedat4", "evt2": ".raw", "evt3": ".evt3.raw", "dat": ".dat"}


def _events(n: int = 3000, seed: int = 1) -> EventPacket:
    rng = np.random.default_rng(seed)
    t = 1000 + np.cumsum(rng.integers(0, 40, n))
    t[100:112] = t[100]  # a run of equal times (one EVT3 vector)
    return EventPacket.from_arrays(t, rng.integers(0, 64, n), rng.integers(0, 48, n), rng.choice([-1, 1], n),
                                   sensor=(64, 48))


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("fast")
    out = {}
    pkt = _events()
    for cls in SINKS:
        if cls.name in EXT:
            out[cls.name] = d / ("f" + EXT[cls.name])
            write_all(cls(str(out[cls.name])), list(pkt.batches(700)))
    return out


def test_pool_never_hands_out_columns_in_use() -> None:
    pool = ColumnPool(max_sets=2)
    a = pool.take(100)
    view = a[0][10:20]  # what a packet holds
    del a
    b = pool.take(50)
    assert b[0].base is None and b[0] is not view.base  # the view keeps its set busy
    del b
    c = pool.take(100)
    c_id = id(c[0])  # an id, not a reference: a reference would keep the set busy
    assert c[0] is not view.base and c[0].shape[0] == 100
    assert id(pool.take(100)[0]) != c_id  # the caller still holds c
    del c, view
    again = pool.take(80)
    assert id(again[0]) == c_id  # a freed set comes back
    assert all(len(s) == 4 for s in pool._sets) and len(pool._sets) <= 2


def test_pool_hands_out_the_smallest_free_set_that_fits() -> None:
    """Of the free sets holding at least ``n`` events, the smallest (the
    first of equal ones); bigger sets and busy ones are passed over."""
    pool = ColumnPool(max_sets=6)
    held = [pool.take(n) for n in (400, 100, 300, 100, 200, 150)]
    ids = [id(c[0]) for c in held]
    busy = held[5]  # 150: the smallest that fits 120, but in use
    del held
    assert id(pool.take(120)[0]) == ids[4]  # 200, not 400 or 300
    assert id(pool.take(100)[0]) == ids[1]  # the first of the two of 100
    assert id(pool.take(350)[0]) == ids[0]
    got = pool.take(10_000)  # none fits: a new set
    assert got[0].shape[0] == 10_000 and id(got[0]) not in ids
    del busy


def test_pool_big_sets_share_an_aligned_block_and_stay_busy_while_viewed() -> None:
    """A set from HUGE_SET bytes on is carved from one block (huge-page
    aligned, columns apart): a packet's view of any column refers to the
    block, and keeps the set from being handed out again."""
    pool = ColumnPool(max_sets=2)
    n = HUGE_SET // 13 + 1000
    cols = pool.take(n)
    assert [c.dtype for c in cols] == [np.int64, np.uint16, np.uint16, np.int8]
    assert all(c.shape[0] >= n and c.base is cols[0].base is not None for c in cols)
    assert cols[0].ctypes.data % (1 << 21) == 0
    for k in range(4):  # no column overlaps another
        cols[k][:] = k + 1
    assert [int(c.min()) == int(c.max()) == k + 1 for k, c in enumerate(cols)] == [True] * 4
    first = id(cols[0])
    for j in range(4):
        held = cols[j][5:10]  # what a packet holds: a view of one column, whose base is the block
        del cols
        assert id(pool.take(n)[0]) != first  # busy: another set
        del held
        cols = pool.take(n)
        assert id(cols[0]) == first  # free again: the same set
    del cols


@pytest.mark.parametrize("fmt", list(EXT))
def test_kept_packets_stay_intact_while_decoding_goes_on(fmt: str, files) -> None:
    kw = {"sensor": "64x48"} if fmt == "text" else {}
    ref = _events()
    kept = [q for q in open_file(str(files[fmt]), chunk_bytes=256, **kw).packets() if isinstance(q, EventPacket)]
    assert len(kept) > 5
    ev = concat(kept)
    for c in "txyp":
        assert np.array_equal(getattr(ev, c), getattr(ref, c)), c
    # dropping packets as they come lets the pool reuse columns: the copies agree too
    copies = [(q.t.copy(), q.x.copy(), q.y.copy(), q.p.copy())
              for q in open_file(str(files[fmt]), chunk_bytes=256, **kw).packets() if isinstance(q, EventPacket)]
    assert np.array_equal(np.concatenate([c[0] for c in copies]), ref.t)
    assert np.array_equal(np.concatenate([c[1] for c in copies]), ref.x)


def test_kept_big_packets_stay_intact_while_decoding_goes_on(tmp_path: Path) -> None:
    """Packets of chunks big enough for block-carved column sets (see
    test_pool_big_sets...) stay intact while later chunks, and a second
    pass over the file, are decoded; so do packets of the second pass."""
    n = 3 * (HUGE_SET // 13) + 777
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.integers(0, 3, n)).astype(np.uint64)
    data = rng.integers(0, 640, n).astype(np.uint64) | (rng.integers(0, 480, n).astype(np.uint64) << np.uint64(14))
    data |= rng.integers(0, 2, n).astype(np.uint64) << np.uint64(28)
    path = tmp_path / "big.dat"
    path.write_bytes(b"% Width 640\n% Height 480\n\x0c\x08" + (t | (data << np.uint64(32))).astype("<u8").tobytes())
    chunk = 8 * (HUGE_SET // 13 + 100)  # each chunk's set past HUGE_SET bytes

    def copies(pkts):
        return [(q, q.t.copy(), q.x.copy(), q.y.copy(), q.p.copy()) for q in pkts]
    first = copies(q for q in open_file(str(path), chunk_bytes=chunk).packets() if isinstance(q, EventPacket))
    second = copies(q for q in open_file(str(path), chunk_bytes=chunk).packets() if isinstance(q, EventPacket))
    assert len(first) >= 3 and sum(len(c[0]) for c in first) == n
    for q, *cols in first + second:
        assert all(np.array_equal(a, b) for a, b in zip((q.t, q.x, q.y, q.p), cols))
    assert np.array_equal(np.concatenate([c[1] for c in first]), t.astype(np.int64))


@pytest.mark.parametrize("fmt", sorted(EXT))
def test_packets_are_what_the_checked_constructor_builds(fmt: str, files) -> None:
    """Packets built without the constructor's checks hold what it would
    have built: the columns' types and shapes, the sensor and the interval
    as Python ints, no extra columns; and rebuilt through it, they pass."""
    pkts = [q for q in open_file(str(files[fmt])).packets() if isinstance(q, EventPacket)]
    assert pkts and sum(len(q) for q in pkts) == 3000
    for q in pkts:
        again = EventPacket(q.t, q.x, q.y, q.p, sensor=q.sensor, t_start=q.t_start, t_end=q.t_end)
        assert [type(v) for v in (q.t_start, q.t_end, *q.sensor)] == [int] * 4
        assert (q.t_start, q.t_end, q.sensor, dict(q.columns)) == (again.t_start, again.t_end, again.sensor, {})
        assert [(a.dtype, a.ndim, a.flags.c_contiguous) for a in (q.t, q.x, q.y, q.p)] == \
            [(a.dtype, 1, True) for a in (again.t, again.x, again.y, again.p)]
        q.validate()


def test_a_consumer_letting_packets_go_gets_the_same_columns_back(tmp_path: Path) -> None:
    """Chunks of one size take column sets of one size whatever the run of
    equal times each holds back (1 to 40 events here), so a consumer that
    drops each packet before the next gets the same pooled set every packet
    (still in the cache), and one holding the last packet two sets in turn;
    the events are the file's either way."""
    rng = np.random.default_rng(3)
    n, per = 20_000, 500
    t = np.cumsum(rng.integers(1, 4, n)).astype(np.uint64)
    for c in range(per, n, per):  # a run across each chunk edge, of a different length each time
        r = int(rng.integers(1, 40))
        t[c - r:c + 1] = t[c - r]
    t = np.maximum.accumulate(t)
    data = rng.integers(0, 64, n).astype(np.uint64) | (rng.integers(0, 48, n).astype(np.uint64) << np.uint64(14))
    path = tmp_path / "runs.dat"
    path.write_bytes(b"% Width 64\n% Height 48\n\x0c\x08" + (t | (data << np.uint64(32))).astype("<u8").tobytes())
    dropped, seen = set(), []
    for q in open_file(str(path), chunk_bytes=8 * per).packets():
        if q.t.base is not None:  # not the last run, held back to the end (a copy)
            dropped.add(q.t.base.ctypes.data)
        seen.append(q.t.copy())
        del q  # gone before the decoder reserves the next chunk's columns
    assert len(seen) > 30 and np.array_equal(np.concatenate(seen), t.astype(np.int64))
    assert len(dropped) == 1
    held = {q.t.base.ctypes.data for q in open_file(str(path), chunk_bytes=8 * per).packets() if q.t.base is not None}
    assert len(held) == 2


def test_dat_packets_fit_in_the_cache_by_default(tmp_path: Path, files) -> None:
    """DAT packets are of DAT_CHUNK_BYTES of records unless chunk_bytes says
    otherwise."""
    n = 3 * (prophesee.DAT_CHUNK_BYTES // 8) + 5
    rec = np.arange(n, dtype=np.uint64) | (np.uint64(5) << np.uint64(32))
    path = tmp_path / "many.dat"
    path.write_bytes(b"% Width 64\n% Height 48\n\x0c\x08" + rec.astype("<u8").tobytes())
    assert open_file(str(path)).chunk_bytes == prophesee.DAT_CHUNK_BYTES
    sizes = [len(q) for q in open_file(str(path)).packets()]
    assert sum(sizes) == n and 4 <= len(sizes) <= 5 and max(sizes) <= prophesee.DAT_CHUNK_BYTES // 8
    assert [len(q) for q in open_file(str(path), chunk_bytes=n * 8).packets()] == [n - 1, 1]  # the last: held back


class _ShortReads:
    """A file whose reads return at most ``most`` bytes (a pipe, a network
    file system): readers must ask again."""

    def __init__(self, f, most: int) -> None:
        self.f, self.most = f, most

    def readinto(self, view) -> int:
        return self.f.readinto(memoryview(view).cast("B")[:self.most])

    def __getattr__(self, name: str):
        return getattr(self.f, name)


@pytest.mark.parametrize("most", [1, 1001, 4096 + 3])
def test_dat_short_reads_give_the_same_events(tmp_path: Path, files, most: int, monkeypatch) -> None:
    """Reads returning fewer bytes than asked (not whole records) are
    completed before decoding: the same events as whole reads."""
    want = concat([q for q in open_file(str(files["dat"])).packets() if isinstance(q, EventPacket)])
    src = open_file(str(files["dat"]), chunk_bytes=8 * 500)
    plain = src._open
    monkeypatch.setattr(src, "_open", lambda **kw: _ShortReads(plain(**kw), most))
    got = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    assert got.t.tolist() == want.t.tolist() and got.x.tolist() == want.x.tolist()
    assert got.y.tolist() == want.y.tolist() and got.p.tolist() == want.p.tolist()


@pytest.mark.parametrize("fmt", ["evt2", "evt3"])
@pytest.mark.parametrize("most", [1, 1001, 4096 + 3])
def test_raw_short_reads_give_the_same_events(tmp_path: Path, files, fmt: str, most: int, monkeypatch) -> None:
    """RAW files are read unbuffered in pieces: a read returning fewer bytes
    than asked (not whole words) is completed, not taken for a truncated
    word; the same events as whole reads."""
    want = concat([q for q in open_file(str(files[fmt])).packets() if isinstance(q, EventPacket)])
    src = open_file(str(files[fmt]), chunk_bytes=2000)
    plain = src._open
    monkeypatch.setattr(src, "_open", lambda **kw: _ShortReads(plain(**kw), most))
    got = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    assert got.t.tolist() == want.t.tolist() and got.x.tolist() == want.x.tolist()
    assert got.y.tolist() == want.y.tolist() and got.p.tolist() == want.p.tolist()


def test_a_sensor_past_the_packet_limit_is_still_refused(tmp_path: Path) -> None:
    """A header's geometry beyond what a packet allows (65536 px a side) is
    refused as the checked constructor refuses it, not passed on."""
    rec = np.zeros(4, "<u8")
    rec[:] = np.arange(4, dtype=np.uint64) * 10 | (np.uint64(5) << np.uint64(32))
    path = tmp_path / "wide.dat"
    path.write_bytes(b"% Data file containing CD events.\n% Width 70000\n% Height 10\n\x0c\x08" + rec.tobytes())
    with pytest.raises(Exception, match="65536"):
        list(open_file(str(path)).packets())


@pytest.mark.parametrize("fmt", ["evt2", "evt3", "dat"])
def test_time_range_on_the_fast_path(fmt: str, files) -> None:
    ref = _events()
    lo, hi = int(ref.t[500]), int(ref.t[2500])
    got = concat([q for q in open_file(str(files[fmt]), chunk_bytes=512, t_start_us=lo, t_end_us=hi).packets()
                  if isinstance(q, EventPacket)])
    want = ref.slice_time(lo, hi)
    assert np.array_equal(got.t, want.t) and np.array_equal(got.x, want.x)


def test_error_offset_from_a_later_chunk(tmp_path: Path, files) -> None:
    data = bytearray(files["dat"].read_bytes())
    rec = len(data) - 1000 * 8
    data[rec + 4:rec + 8] = (63 | (47 << 14) | (1 << 28)).to_bytes(4, "little")  # in geometry
    data[rec:rec + 4] = (0).to_bytes(4, "little")  # time goes back
    f = tmp_path / "late.dat"
    f.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="decreases") as e:
        list(open_file(str(f), chunk_bytes=1024).packets())
    assert e.value.offset == rec
    src = open_file(str(f), chunk_bytes=1024, skip_bad=True)
    assert len(concat([q for q in src.packets() if isinstance(q, EventPacket)])) == 2999
    assert src.skipped_events == 1


@pytest.mark.parametrize(("what", "at"), [(w, a) for w in ("time", "x", "y") for a in (0, 1, 127, 128, 129, 2999)
                                           if (w, a) != ("time", 0)])  # the first time has nothing before it
def test_dat_bad_record_at_any_chunk_boundary(tmp_path: Path, files, what: str, at: int, monkeypatch) -> None:
    """A DAT record whose time goes back or whose x or y lies outside the
    sensor is found (offset, skip_bad count) wherever it falls against the
    chunks the records are read and decoded in (128, 129, 256 records or
    all; in one chunk, reads of 128 or 129 records): the decoder's bounds
    that spare the check pass never hide it."""
    data = bytearray(files["dat"].read_bytes())
    start = len(data) - 3000 * 8
    rec = start + 8 * at
    word = int.from_bytes(data[rec + 4:rec + 8], "little")
    if what == "time":
        data[rec:rec + 4] = (0).to_bytes(4, "little")
    else:
        word = (word & ~(0x3FFF << 14)) | (48 << 14) if what == "y" else (word & ~0x3FFF) | 64
        data[rec + 4:rec + 8] = word.to_bytes(4, "little")
    f = tmp_path / "bad.dat"
    f.write_bytes(bytes(data))
    for chunk, read in ((1 << 20, 1 << 19), (256 * 8, 1 << 19), (129 * 8, 1 << 19), (128 * 8, 1 << 19),
                        (1 << 20, 128 * 8), (1 << 20, 129 * 8)):
        monkeypatch.setattr(prophesee, "_DAT_READ", read)
        with pytest.raises(FormatError, match="decreases" if what == "time" else "outside") as e:
            list(open_file(str(f), chunk_bytes=chunk).packets())
        assert e.value.offset == rec
        src = open_file(str(f), chunk_bytes=chunk, skip_bad=True)
        assert len(concat([q for q in src.packets() if isinstance(q, EventPacket)])) == 2999
        assert src.skipped_events == 1


@pytest.mark.parametrize(("fmt", "at"), [(f, a) for f in ("evt2", "evt3") for a in (0.0, 0.3, 0.5, 0.999)])
def test_raw_event_outside_the_sensor_at_any_chunk_boundary(tmp_path: Path, files, fmt: str, at: float) -> None:
    """An EVT 2.0/3.0 event with x past the sensor is found (offset,
    skip_bad count) whatever chunks the words are decoded in: the kernels'
    bounds that spare the check pass never hide it."""
    data = bytearray(files[fmt].read_bytes())
    start = 0
    while data[start] == ord("%"):  # the header's lines
        start = data.index(b"\n", start) + 1
    size = 4 if fmt == "evt2" else 2
    words = np.frombuffer(bytes(data[start:]), "<u4" if fmt == "evt2" else "<u2")
    is_x = (words >> 28) <= 1 if fmt == "evt2" else (words >> 12) == 2
    k = int(np.flatnonzero(is_x)[int(at * (int(is_x.sum()) - 1))])
    word = int(words[k])
    word = (word & ~(0x7FF << 11)) | (64 << 11) if fmt == "evt2" else (word & ~0x7FF) | 64
    rec = start + size * k
    data[rec:rec + size] = word.to_bytes(size, "little")
    f = tmp_path / ("bad" + EXT[fmt])
    f.write_bytes(bytes(data))
    for chunk in (1 << 20, 256 * size, 129 * size, 128 * size):
        with pytest.raises(FormatError, match="outside") as e:
            list(open_file(str(f), chunk_bytes=chunk).packets())
        assert e.value.offset == rec
        src = open_file(str(f), chunk_bytes=chunk, skip_bad=True)
        assert len(concat([q for q in src.packets() if isinstance(q, EventPacket)])) == 2999
        assert src.skipped_events == 1


def test_evt3_kernel_resumes_when_the_output_is_full() -> None:
    rng = np.random.default_rng(3)
    words = [(8 << 12) | 1, (6 << 12) | 2]
    for _ in range(300):
        words += [int(rng.integers(0, 480)), (3 << 12) | int(rng.integers(0, 600)),
                  (4 << 12) | int(rng.integers(0, 4096)), (5 << 12) | int(rng.integers(0, 256)),
                  (2 << 12) | int(rng.integers(0, 4096)), (6 << 12) | int(rng.integers(0, 4096))]
    w = np.array(words, np.uint16)

    def decode(cap: int) -> list:
        st_, out, i = np.zeros(K.EVT3_STATE, np.int64), [], 0
        cols = [np.empty(cap, d) for d in (np.int64, np.uint16, np.uint16, np.int8, np.int64)]
        while i < w.shape[0]:
            n, _, bad, _, used = K.decode_evt3(w[i:], st_, True, *cols, np.empty((w.shape[0], 3), np.int64))
            assert bad < 0 and (used > 0 or cap < 13)
            out += list(zip(*(c[:n].tolist() for c in cols[:4]), (cols[4][:n] + i).tolist()))
            i += used
        return out

    whole = decode(12 * w.shape[0])
    assert len(whole) > 3000 and decode(13) == decode(40) == whole


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 50), st.integers(0, 70), st.integers(0, 50)), max_size=40),
       st.integers(-5, 5), st.integers(-3, 30))
def test_check_events_matches_reference(ev, offset, prev) -> None:
    t = np.array([e[0] for e in ev], np.int64)
    x = np.array([e[1] for e in ev], np.uint16)
    y = np.array([e[2] for e in ev], np.uint16)
    want = _check_ref(t, x, y, 0, len(ev), offset, prev, 64, 48)
    before = t.copy()
    got = K.check_events(t, x, y, 0, len(ev), offset, prev, 64, 48)
    assert got == want
    assert np.array_equal(t, before + offset if want < 0 else before)



def _check_ref(t: np.ndarray, x: np.ndarray, y: np.ndarray, lo: int, hi: int, offset: int, prev: int, w: int,
               h: int) -> int:
    run = prev
    for i in range(lo, hi):
        v = int(t[i]) + offset
        if v < run or x[i] >= w or y[i] >= h:
            return i
        run = v
    return -1


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 20_000), st.integers(0, 300), st.floats(0, 1), st.sampled_from(["t", "x", "y", "none"]),
       st.sampled_from([(640, 480), (70_000, 480), (640, 70_000)]))
def test_check_events_finds_one_bad_event_across_blocks(n, lo, frac, what, sensor) -> None:
    """The blocked (vectorised) check finds the same first bad event as the
    plain loop, wherever it lies, also past the 4096-event blocks."""
    rng = np.random.default_rng(n)
    w, h = sensor
    t = np.cumsum(rng.integers(0, 3, n)).astype(np.int64)
    x = rng.integers(0, min(w, 65535), n).astype(np.uint16)
    y = rng.integers(0, min(h, 65535), n).astype(np.uint16)
    lo = min(lo, n - 1)
    k = lo + int(frac * (n - 1 - lo))
    if what == "t" and k > lo:
        t[k] = t[k - 1] - 1
    elif what == "x" and w < 65535:
        x[k] = w
    elif what == "y" and h < 65535:
        y[k] = h + 3
    want = _check_ref(t, x, y, lo, n, 7, -1, w, h)
    before = t.copy()
    assert K.check_events(t, x, y, lo, n, 7, -1, w, h) == want
    assert np.array_equal(t[lo:], before[lo:] + 7 if want < 0 else before[lo:])


def test_check_events_on_garbage_times() -> None:
    """Times near the int64 limits (garbage read as times): a fall whose
    difference would overflow is still a fall."""
    t = np.array([0, 1, 2**62, -(2**62) - 5, 3] + [4] * 5000, np.int64)
    x = np.zeros(t.shape[0], np.uint16)
    assert K.check_events(t, x, x, 0, t.shape[0], 0, -1, 64, 48) == 3

def test_lz4_fast_path_equals_the_frame_decoder() -> None:
    lz4f = pytest.importorskip("lz4.frame")
    from tectum.sources.files import aedat4_codec as codec

    data = np.random.default_rng(0).integers(0, 8, 50_000).astype(np.uint8).tobytes()
    simple = lz4f.compress(data, content_checksum=False, block_size=lz4f.BLOCKSIZE_MAX64KB)
    assert codec._lz4_simple_frame(simple) == data == codec.decompress(simple, "lz4")
    checked = lz4f.compress(data, content_checksum=True)
    assert codec._lz4_simple_frame(checked) is None and codec.decompress(checked, "lz4") == data
    bad = bytearray(simple)
    bad[-10] ^= 0xFF
    bad[20] ^= 0xFF
    with pytest.raises(ValueError):
        codec.decompress(bytes(bad), "lz4")


def test_raw_columns_full_inside_a_piece(tmp_path: Path) -> None:
    """EVT 3.0 vector words give up to 12 events a word: a chunk's words can
    fill its columns before they are all decoded, inside a read piece. The
    words left are read again for the next packet: the same events as one
    big chunk."""
    words = [0x8000 | 7, 0x0000 | 5]  # TIME_HIGH, ADDR_Y
    for k in range(40):
        words += [0x6000 | k, 0x3000 | (k % 2) << 11]  # TIME_LOW, VECT_BASE_X at 0 (polarity alternating)
        words += [0x4FFF] * 150  # VECT_12, all set: x 0 .. 1799
    path = tmp_path / "v.raw"
    path.write_bytes(b"% evt 3.0\n% geometry 2048x720\n% end\n" + np.array(words, "<u2").tobytes())
    want = concat([q for q in open_file(str(path)).packets() if isinstance(q, EventPacket)])
    assert len(want) == 40 * 1800
    small = [q for q in open_file(str(path), chunk_bytes=1000).packets()
             if isinstance(q, EventPacket)]
    got = concat(small)
    assert len(small) > 1
    assert got.t.tolist() == want.t.tolist() and got.x.tolist() == want.x.tolist()
    assert got.y.tolist() == want.y.tolist() and got.p.tolist() == want.p.tolist()
