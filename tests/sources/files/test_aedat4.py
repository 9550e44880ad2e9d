"""The AEDAT 4.0 reader: the compiled LZ4 path (threads, runs, reads cut
anywhere) gives what the Python path gives, for every compression and LZ4
frame layout; a packet that does not decompress or decode is named by its
byte offset, or skipped and counted, the same way on both paths."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError, concat
from tectum.sinks.files import SINKS
from tectum.sinks.files._common import write_all
from tectum.sources.files import _lz4, aedat4
from tectum.sources.files.aedat4 import Aedat4Source

from helpers import decodes_or_names, mutate

pytest.importorskip("lz4")
pytest.importorskip("zstandard")

SINK = next(c for c in SINKS if c.name == "aedat4")
PER_PACKET = 700


def _events(n: int = 60_000) -> EventPacket:
    rng = np.random.default_rng(3)
    return EventPacket.from_arrays(np.cumsum(rng.integers(0, 5, n)), rng.integers(0, 64, n), rng.integers(0, 48, n),
                                   rng.choice([-1, 1], n), sensor=(64, 48))


def _write(path: Path, pkt: EventPacket, **kw) -> Path:
    write_all(SINK(str(path), **kw), [pkt])
    return path


def _read(path: Path, **kw) -> tuple[EventPacket, Aedat4Source]:
    src = Aedat4Source(str(path), **kw)
    pkts = [q for q in src.packets() if isinstance(q, EventPacket)]
    return concat(pkts), src


def _same(a: EventPacket, b: EventPacket) -> bool:
    return all(np.array_equal(getattr(a, c), getattr(b, c)) for c in "txyp")


@pytest.fixture(params=[True, False], ids=["compiled", "python"])
def compiled(request, monkeypatch) -> bool:
    if request.param and not _lz4.AVAILABLE:
        pytest.skip("lz4 does not export LZ4_decompress_safe here")
    monkeypatch.setattr(_lz4, "AVAILABLE", request.param)
    return request.param


@pytest.mark.parametrize("compression", ["lz4", "lz4_high", "zstd", "none"])
@pytest.mark.parametrize("per_packet", [PER_PACKET, 6000], ids=["one-block", "linked-blocks"])
def test_every_path_reads_the_same_events(tmp_path: Path, compiled: bool, compression: str, per_packet: int,
                                          monkeypatch) -> None:
    """6000 events are 96 KB: two linked 64 KiB LZ4 blocks per packet."""
    ev = _events()
    f = _write(tmp_path / "e.aedat4", ev, compression=compression, packet_events=per_packet)
    for threads in (1, 2, 3):
        got, _ = _read(f, threads=threads)
        assert _same(got, ev), threads
    got, _ = _read(f, chunk_bytes=5000, threads=2)  # packets cut by reads, and larger than a read
    assert _same(got, ev)
    monkeypatch.setattr(aedat4, "_RUN_EVENTS", 3000)  # many runs, each on up to 2 threads
    got, _ = _read(f, threads=2)
    assert _same(got, ev)


def test_large_reads_go_into_huge_pages(tmp_path: Path, monkeypatch) -> None:
    """A read of at least _HUGE_READ bytes (lowered here) lands at the
    start of a 2 MiB-aligned block (huge pages: see _read_buffer), file
    order and events unchanged; a smaller read may land anywhere."""
    ev = _events()
    f = _write(tmp_path / "e.aedat4", ev, packet_events=PER_PACKET)
    seen: list[int] = []
    real = aedat4.AK.scan_packets

    def scan(buf, *args):
        seen.append(buf.ctypes.data)
        return real(buf, *args)

    monkeypatch.setattr(aedat4.AK, "scan_packets", scan)
    monkeypatch.setattr(aedat4, "_HUGE_READ", 1 << 12)
    got, _ = _read(f, threads=1)
    assert _same(got, ev)
    assert seen and all(a % (1 << 21) == 0 for a in seen)


def _packet_at(path: Path, k: int) -> tuple[int, int]:
    """(offset of the header, payload size) of event packet ``k``."""
    entries = [e for e in Aedat4Source(str(path)).packet_table() if e.stream == 0]
    return entries[k].offset - 8, entries[k].size


def _without(path: Path, ev: EventPacket, k: int) -> EventPacket:
    """``ev`` without the events of packet ``k`` (of the file's packet table)."""
    n = np.cumsum([0] + [e.elements for e in Aedat4Source(str(path)).packet_table() if e.stream == 0])
    keep = np.ones(len(ev), bool)
    keep[n[k]:n[k + 1]] = False
    return ev.select(keep)


def _corrupt_block(path: Path, k: int) -> int:
    """Fill the LZ4 data of packet ``k``'s first block with 0xFF (literal
    lengths running past the block): the frame still parses, the block does
    not decompress."""
    at, size = _packet_at(path, k)
    raw = bytearray(path.read_bytes())
    frame = at + 8
    first = frame + 7 + (8 if raw[frame + 4] & 0x08 else 0)  # after the header (and content size)
    n = int.from_bytes(raw[first:first + 4], "little") & 0x7FFFFFFF
    raw[first + 4:first + 4 + n] = b"\xff" * n
    path.write_bytes(bytes(raw))
    return at


def _garbage_payload(path: Path, k: int) -> int:
    """Replace packet ``k``'s payload by a valid LZ4 frame of the same size
    holding random bytes (stored raw): it decompresses, but is no FlatBuffer."""
    import lz4.frame

    at, size = _packet_at(path, k)
    junk = np.random.default_rng(1).integers(0, 256, size - 15, dtype=np.uint8).tobytes()
    frame = lz4.frame.compress(junk, store_size=False, content_checksum=False)
    assert len(frame) == size
    raw = bytearray(path.read_bytes())
    raw[at + 8:at + 8 + size] = frame
    path.write_bytes(bytes(raw))
    return at


@pytest.mark.parametrize("damage, why", [(_corrupt_block, "does not decompress"),
                                         (_garbage_payload, "malformed EventPacket")], ids=["lz4", "flatbuffer"])
@pytest.mark.parametrize("threads", [1, 2])
def test_bad_packet_is_named_or_skipped(tmp_path: Path, compiled: bool, threads: int, damage, why: str) -> None:
    ev = _events()
    f = _write(tmp_path / "c.aedat4", ev, packet_events=PER_PACKET)
    want = _without(f, ev, 40)
    at = damage(f, 40)
    with pytest.raises(FormatError, match=why) as e:
        _read(f, threads=threads)
    assert e.value.offset == at
    got, src = _read(f, threads=threads, skip_bad=True)
    # the packet's events, as the packet table lists them: kept + skipped = all
    assert _same(got, want) and src.skipped_events == PER_PACKET == len(ev) - len(got)


@pytest.mark.parametrize("inside", [0, 3])
@pytest.mark.parametrize("what", ["time", "x", "y"])
def test_bad_event_found_on_every_path(tmp_path: Path, compiled: bool, what: str, inside: int, monkeypatch) -> None:
    """An event whose time goes back or whose x or y lies outside the sensor
    is named by its packet's offset wherever it lies: inside a packet, first
    of a packet, of a run, of a thread's part (each part committed, and
    checked against the one before, in turn; the compiled path checks while
    it splits the packets)."""
    monkeypatch.setattr(aedat4, "_PART_BYTES", 1 << 12)  # parts of a few packets: many threads' parts meet
    ev = _events()
    for k in (1, 700, 1400, 3000, 30_000, len(ev) - 4):
        t, x, y = ev.t.copy(), ev.x.copy(), ev.y.copy()
        b = k + inside  # the bad event, ``inside`` events into the packet starting at k
        if what == "time":
            t[b:] -= t[b] - t[b - 1] + 1  # the time falls by 1 µs at b, in order after it
        elif what == "x":
            x[b] = 64
        else:
            y[b] = 48
        parts = [EventPacket(c[0], c[1], c[2], c[3], sensor=(64, 48))  # unchecked, as a corrupt file holds
                 for c in ((t[:k], x[:k], y[:k], ev.p[:k]), (t[k:], x[k:], y[k:], ev.p[k:]))]
        f = tmp_path / f"b{k}.aedat4"
        write_all(SINK(str(f), packet_events=PER_PACKET), parts)  # a packet starts at k
        starts = np.cumsum([0] + [e.elements for e in Aedat4Source(str(f)).packet_table() if e.stream == 0])
        at = _packet_at(f, int(np.flatnonzero(starts == k)[0]))[0]
        for threads, run in ((1, 1 << 22), (2, 1 << 22), (2, 3000)):
            monkeypatch.setattr(aedat4, "_RUN_EVENTS", run)
            with pytest.raises(FormatError, match="decreases" if what == "time" else "outside") as e:
                _read(f, threads=threads)
            assert e.value.offset == at, (k, threads, run)


def _tiled(pkts: list[EventPacket]) -> bool:
    """Packets one after the other: each starts where the one before ends,
    and no time is split between two packets."""
    full = [q for q in pkts if len(q)]
    return (all(a.t_end == b.t_start for a, b in zip(pkts, pkts[1:]))
            and all(a.t[-1] < b.t[0] for a, b in zip(full, full[1:])))


@pytest.mark.parametrize("in_place", [True, False], ids=["in-place", "moved"])
def test_thread_parts_committed_in_turn(tmp_path: Path, in_place: bool, monkeypatch) -> None:
    """Each thread's part of a run is committed where it was decoded, the
    run of equal times held back from the part before copied in front of
    it (or, when that does not fit, the part moved into new columns): the
    same events, in packets that tile time, long runs of equal times across
    the parts' boundaries included."""
    from tectum.sources.files._common import EventAssembler

    rng = np.random.default_rng(5)
    n = 60_000
    steps = rng.integers(0, 3, n)
    steps[20_000:24_000] = 0  # 4000 events at one time
    steps[41_000:41_200] = 0
    ev = EventPacket.from_arrays(np.cumsum(steps), rng.integers(0, 64, n), rng.integers(0, 48, n),
                                 rng.choice([-1, 1], n), sensor=(64, 48))
    f = _write(tmp_path / "runs.aedat4", ev, packet_events=PER_PACKET)
    resumed: list[bool] = []
    real = EventAssembler.resume_at

    def spy(self: EventAssembler, i: int) -> bool:
        resumed.append(real(self, i) if in_place else False)
        return resumed[-1]
    monkeypatch.setattr(EventAssembler, "resume_at", spy)
    for part_bytes, run in ((1 << 12, 1 << 22), (1 << 14, 20_000)):
        monkeypatch.setattr(aedat4, "_PART_BYTES", part_bytes)
        monkeypatch.setattr(aedat4, "_RUN_EVENTS", run)
        resumed.clear()
        pkts = [q for q in Aedat4Source(str(f), threads=2).packets() if isinstance(q, EventPacket)]
        assert _same(concat(pkts), ev) and _tiled(pkts)
        assert resumed and all(r == in_place for r in resumed)


def test_resume_at_places_the_held_back_run_or_refuses() -> None:
    """EventAssembler.resume_at: the run held back from a commit goes just
    before the next part's events when it fits after the committed ones
    (never over them), else nothing changes and False says so."""
    from tectum.sources.files._common import EventAssembler

    for gap, fits in ((3, True), (2, False)):
        asm = EventAssembler(Aedat4Source("unused.aedat4"), (64, 48))
        t, x, y, p = asm.reserve(20)
        t[:6] = [1, 2, 3, 7, 7, 7]  # part one: 7 held back
        start = 6 + gap
        t[6:start] = -5  # the gap
        t[start:start + 4] = [7, 8, 9, 9]  # part two, after the gap
        x[:] = np.arange(20)
        y[:], p[:] = 1, 1
        first = asm.commit(6)
        assert [q.t.tolist() for q in first] == [[1, 2, 3]]
        assert asm.resume_at(start) is fits
        if not fits:
            assert t[6:start].tolist() == [-5] * gap and asm.carry is not None and asm.carry[0].tolist() == [7] * 3
            continue
        second = asm.commit(4) + asm.finish()
        assert first[0].t.tolist() == [1, 2, 3] and first[0].x.tolist() == [0, 1, 2]
        assert [q.t.tolist() for q in second] == [[7, 7, 7, 7, 8], [9, 9]]
        assert second[0].x.tolist() == [3, 4, 5, start, start + 1]


def test_frame_kinds_found_by_the_scan(tmp_path: Path) -> None:
    """What the packet scan calls a plain LZ4 frame (decoded in compiled
    code): single and linked blocks, with or without the content size; not
    frames with checksums (the Python decoder checks those)."""
    import lz4.frame

    from tectum.sources.files import _aedat4_kernels as AK

    data = np.random.default_rng(0).integers(0, 4, 150_000).astype(np.uint8).tobytes()

    def scan(**kw) -> tuple[int, ...]:
        fr = np.frombuffer(lz4.frame.compress(data, **kw), np.uint8)
        return AK.lz4_frame(fr, 0, fr.shape[0])

    first, _, room, linked, content, blocks = scan(content_checksum=False)
    assert first > 0 and linked == 1 and content == len(data) == room and blocks == 3
    first, _, room, linked, content, blocks = scan(content_checksum=False, store_size=False, block_linked=False)
    assert first > 0 and linked == 0 and content == -1 and room == 3 << 16
    assert scan(content_checksum=True)[0] == -1
    assert scan(content_checksum=False, block_checksum=True)[0] == -1


def _mixed(path: Path, ev: EventPacket) -> Path:
    """Events with a frame and three IMU samples after every 2000."""
    from tectum import FramePacket, ImuPacket

    rng = np.random.default_rng(2)
    parts: list = []
    for chunk in ev.batches(2000):
        t = int(chunk.t[-1])
        parts += [chunk, FramePacket(np.array([t]), t_start=t, t_end=t + 1,
                                     images=rng.integers(0, 255, (1, 48, 64), np.uint8)),
                  ImuPacket(t + np.arange(3), t_start=t, t_end=t + 3, accel=rng.normal(size=(3, 3)),
                            gyro=rng.normal(size=(3, 3)))]
    write_all(SINK(str(path), packet_events=PER_PACKET), parts)
    return path


def test_every_stream_is_the_same_on_both_paths(tmp_path: Path, monkeypatch) -> None:
    """Frames and IMU samples (decompressed in compiled code, a read at a
    time) come out as the Python path gives them."""
    if not _lz4.AVAILABLE:
        pytest.skip("lz4 does not export LZ4_decompress_safe here")
    f = _mixed(tmp_path / "m.aedat4", _events(20_000))

    def kinds() -> dict:
        out: dict = {}
        for q in Aedat4Source(str(f), chunk_bytes=20_000).packets():
            out.setdefault(q.kind, []).append(q)
        return {k: concat(v) for k, v in out.items()}

    compiled = kinds()
    monkeypatch.setattr(_lz4, "AVAILABLE", False)
    python = kinds()
    assert sorted(compiled) == sorted(python) and len(compiled) == 3
    def columns(q) -> dict:
        return {c: getattr(q, c) for c in "txyp"} if isinstance(q, EventPacket) else {"t": q.t, **q.data}

    for k in compiled:
        a, b = columns(compiled[k]), columns(python[k])
        assert len(a["t"]) and a.keys() == b.keys() and all(np.array_equal(a[c], b[c]) for c in a), k


def test_events_only_skips_frames_through_the_table(tmp_path: Path, compiled: bool) -> None:
    """Asked for events only, a file with frames is read through its packet
    table (frames seeked over), with the same result as reading every packet;
    a table that does not cover the file is not trusted."""
    ev = _events(20_000)
    f = _mixed(tmp_path / "f.aedat4", ev)
    walked, _ = _read(f, streams="events", use_index=False)
    indexed, src = _read(f, streams="events")
    assert _same(walked, ev) and _same(indexed, ev)
    part, _ = _read(f, streams="events", t_start_us=int(ev.t[5000]), t_end_us=int(ev.t[15000]))
    assert _same(part, ev.slice_time(int(ev.t[5000]), int(ev.t[15000])))
    # the table's last entry says one byte less: not trusted, every packet is read
    tab = src.packet_table()
    assert tab is not None
    from tectum.sources.files import aedat4 as A

    table = np.array([[e.offset, e.stream, e.size, e.elements, e.t_first, e.t_last] for e in tab], np.int64)
    start = table[:, 0].min() - 8
    end = int((table[:, 0] + table[:, 2]).max())
    assert A._tiles(table, start, end)
    table[-1, 2] -= 1
    assert not A._tiles(table, start, end)


def test_writer_threads_write_the_same_file(tmp_path: Path) -> None:
    """Compression on threads keeps packets in order, frames included; an
    abort with packets still compressing leaves no file."""
    from tectum import FramePacket

    ev = _events(50_000)
    frame = FramePacket(np.array([int(ev.t[-1])]), t_start=int(ev.t[-1]), t_end=int(ev.t[-1]) + 1,
                        images=np.zeros((1, 48, 64), np.uint8))
    parts = [*ev.batches(20_000), frame]
    files = []
    for k in (1, 3):
        f = tmp_path / f"w{k}.aedat4"
        write_all(SINK(str(f), packet_events=PER_PACKET, threads=k), parts)
        files.append(f)
    assert files[0].read_bytes() == files[1].read_bytes()
    sink = SINK(str(tmp_path / "gone.aedat4"), packet_events=PER_PACKET, threads=3)
    sink.open()
    sink.write(ev)
    sink.abort()
    assert not (tmp_path / "gone.aedat4").exists() and list(tmp_path.glob(".tectum-*")) == []


@pytest.fixture(scope="module")
def many_packets(tmp_path_factory) -> bytes:
    """An LZ4 file of event packets (one and two linked blocks) between
    frames and IMU samples."""
    f = tmp_path_factory.mktemp("fz") / "m.aedat4"
    ev = _events(16_000)
    from tectum import FramePacket, ImuPacket

    parts: list = []
    for k, chunk in enumerate(ev.batches(4000)):  # 4000 events: 2 blocks; 1000: 1
        t = int(chunk.t[-1])
        parts += [*chunk.batches(1000 if k % 2 else 4000),
                  FramePacket(np.array([t]), t_start=t, t_end=t + 1, images=np.full((1, 48, 64), 7, np.uint8)),
                  ImuPacket(np.array([t]), t_start=t, t_end=t + 1, accel=np.ones((1, 3)), gyro=np.zeros((1, 3)))]
    write_all(SINK(str(f), packet_events=4000), parts)
    return f.read_bytes()


@pytest.mark.abuse
@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_compiled_path(many_packets: bytes, data, tmp_path_factory) -> None:
    """Flipped, cut or spliced bytes anywhere in a many-packet file: a
    FormatError naming the file, or packets that obey the contract; never
    a crash (the compiled path hands liblz4 only ranges it checked)."""
    if not _lz4.AVAILABLE:
        pytest.skip("lz4 does not export LZ4_decompress_safe here")
    f = tmp_path_factory.mktemp("fz") / "f.aedat4"
    f.write_bytes(mutate(many_packets, data))
    for kw in ({}, {"skip_bad": True, "threads": 2}):
        decodes_or_names(Aedat4Source(str(f), **kw), f)


def test_threads_work_in_a_forked_child(tmp_path: Path) -> None:
    """After the parent used the worker threads, a forked child (as a
    DataLoader worker is) reads with threads too instead of waiting forever
    on the parent's threads."""
    import multiprocessing as mp

    if "fork" not in mp.get_all_start_methods():
        pytest.skip("no fork on this platform")
    f = _write(tmp_path / "k.aedat4", _events(200_000))  # 3 MB: decoded on 2 threads
    n = len(_read(f, threads=2)[0])
    ctx = mp.get_context("fork")
    with ctx.Pool(1) as pool:
        got = pool.apply_async(_count, (str(f),)).get(timeout=60)
    assert got == n


def _count(path: str) -> int:
    return sum(len(q) for q in Aedat4Source(path, threads=2).packets()
               if isinstance(q, EventPacket))


def test_number_in_the_info_node_that_is_not_one(tmp_path: Path) -> None:
    """A sizeX that is no integer is a FormatError naming the file, as a
    malformed infoNode is (the network reader already said so)."""
    f = _write(tmp_path / "x.aedat4", _events(100))
    raw = f.read_bytes()
    assert raw.count(b'"sizeX" type="int">64<') == 1
    f.write_bytes(raw.replace(b'"sizeX" type="int">64<', b'"sizeX" type="int">!4<'))
    with pytest.raises(FormatError, match="infoNode"):
        _read(f)


def test_info_node_parsed_once_each_caller_its_own_streams(tmp_path: Path) -> None:
    """The infoNode document of a file opened again is parsed once: each
    reader still gets Stream objects of its own (changing one changes no
    other reader's), and the file rewritten with another sensor reads as the
    new one (the cache is keyed by the document)."""
    f = _write(tmp_path / "s.aedat4", _events(100))
    a, b = Aedat4Source(str(f)), Aedat4Source(str(f))
    a._open_header()
    b._open_header()
    a.close()
    b.close()
    assert a.streams == b.streams and a.streams[0].sensor == (64, 48)
    assert all(a.streams[k] is not b.streams[k] for k in a.streams)
    a.streams[0].sensor = (1, 1)
    with open(f, "rb") as fh:
        assert aedat4.parse_info_node(aedat4.read_io_header(fh, str(f))[2])[0].sensor == (64, 48)
    write_all(SINK(str(f)), [EventPacket.from_arrays([1, 2], [0, 1], [0, 1], [1, -1], sensor=(32, 16))])
    c = Aedat4Source(str(f))
    c._open_header()
    c.close()
    assert c.streams[0].sensor == (32, 16)
