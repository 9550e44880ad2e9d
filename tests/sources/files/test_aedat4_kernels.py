"""AEDAT 4.0 kernels against slow obvious references: the split of
``Event`` structs into columns (16 at a time in vector code, the rest one
by one) gives what NumPy's structured view of the same bytes gives, for any
bytes; the threads' parts of a run hold about equal compressed bytes; a
part no worker has started is decoded by the reading thread; no worker
thread is left decoding after an error, a Ctrl-C or a consumer that stops
early."""

from __future__ import annotations

import signal as signals
import threading
import time
from concurrent.futures import wait

import numpy as np
import pytest

from tectum import EventPacket
from tectum.sinks.files import SINKS
from tectum.sinks.files._common import write_all
from tectum.sources.files import _aedat4_kernels as AK
from tectum.sources.files import _lz4, aedat4
from tectum.sources.files._common import workers
from tectum.sources.files.aedat4 import Aedat4Source

#: The ``Event`` struct of the AEDAT 4.0 EventPacket, as NumPy reads it
EVENT = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "u1"), ("pad", "V3")])


def _reference(b: np.ndarray, last: int) -> tuple[tuple[int, int, int, int], list[np.ndarray]]:
    ev = np.frombuffer(b.tobytes(), EVENT)
    t = ev["t"].astype(np.int64)
    p = np.where(ev["p"] != 0, 1, -1).astype(np.int8)
    if not len(ev):
        return (0, 0, 0, last), [t, ev["x"], ev["y"], p]
    dec = int(t[0] < last) + int(np.sum(t[1:] < t[:-1]))
    return (dec, int(ev["x"].max()), int(ev["y"].max()), int(t[-1])), [t, ev["x"], ev["y"], p]


@pytest.mark.parametrize("shift", [0, 3], ids=["aligned", "unaligned"])
def test_split_is_the_struct_layout(shift: int) -> None:
    """Random bytes (times out of order, any polarity byte, garbage padding,
    x and y over the whole uint16 range), every length around the 16-event
    step, into columns from an offset: the same columns and checks as the
    structured view; nothing written outside the events' stretch."""
    rng = np.random.default_rng(7)
    for n in [*range(0, 50), 255, 2219]:
        raw = np.zeros(16 * n + 8, np.uint8)
        b = raw[shift:shift + 16 * n]
        b[:] = rng.integers(0, 256, 16 * n, dtype=np.uint8)
        q = np.frombuffer(b.tobytes(), EVENT)
        if n > 3:  # mostly rising times, as recordings have them, with a few falls
            t = np.cumsum(rng.integers(-2, 50, n))
            q = q.copy()
            q["t"] = t
            b[:] = np.frombuffer(q.tobytes(), np.uint8)
        o = 5
        cols = [np.full(n + 10, 77, d) for d in (np.int64, np.uint16, np.uint16, np.int8)]
        got = AK._split(b, o, *cols, np.int64(10))
        want, want_cols = _reference(b, 10)
        assert tuple(int(v) for v in got) == want, n
        for c, w in zip(cols, want_cols):
            assert np.array_equal(c[o:o + n], w), n
            assert (c[:o] == 77).all() and (c[o + n:] == 77).all(), n


def test_plain_blocks_are_the_struct_layout() -> None:
    """The plain form of the 16-event step (``NUMBA_DISABLE_JIT``) too,
    with its checks."""
    rng = np.random.default_rng(1)
    b = rng.integers(0, 256, 16 * 40, dtype=np.uint8)
    q = np.frombuffer(b.tobytes(), EVENT).copy()
    q["t"] = np.cumsum(rng.integers(-2, 50, 40))
    b = np.frombuffer(q.tobytes(), np.uint8)[16 * 3:16 * 35]
    cols = [np.zeros(32, d) for d in (np.int64, np.uint16, np.uint16, np.int8)]
    got = AK._split_blocks(b.view(np.int64), 2, *cols, 10)
    (dec, mx, my, _), want = _reference(b, 10)
    assert got == (dec, mx, my)
    for c, w in zip(cols, want):
        assert np.array_equal(c, w)


def _rows(sizes: list[int], room: int = 4096) -> np.ndarray:
    rows = np.zeros((len(sizes), 9), np.int64)
    ends = np.cumsum(sizes)
    rows[:, 0], rows[:, 1] = ends - sizes, ends
    rows[:, 5] = 16 * room
    return rows


def test_parts_hold_equal_compressed_bytes() -> None:
    """Packets of uneven size: each part's bytes within one packet of an
    equal share (cutting in equal numbers of packets would give the first
    part 3x the second's here), every part at least one packet, the room
    before each cut that of the packets before it."""
    sizes = [3000] * 50 + [1000] * 50
    for w in (1, 2, 3, 4):
        ok, cuts, at, scratch = AK.plan_run(_rows(sizes), w, 1 << 22, 1)
        assert ok and scratch == 16 * 4096
        assert cuts[0] == 0 and cuts[-1] == len(sizes) and (np.diff(cuts) > 0).all()
        assert at.tolist() == [4096 * c for c in cuts.tolist()]
        share = sum(sizes) / w
        for a, b in zip(cuts, cuts[1:]):
            assert abs(sum(sizes[a:b]) - share) <= max(sizes), (w, cuts)
    # one packet each, whatever their sizes
    assert AK.plan_run(_rows([10, 10**6, 10]), 3, 1 << 22, 1)[1].tolist() == [0, 1, 2, 3]
    assert AK.plan_run(_rows([10**6, 10, 10]), 3, 1 << 22, 1)[1].tolist() == [0, 1, 2, 3]
    assert AK.plan_run(_rows([5, 5]), 2, 1 << 22, 1)[1].tolist() == [0, 1, 2]


def test_plan_says_when_a_run_is_not_one() -> None:
    """Not one run: a packet that is not a plain LZ4 frame, more room than
    a run holds, no packets. Parts: at most one per ``part_bytes`` of room
    and per packet."""
    rows = _rows([100] * 8)
    assert AK.plan_run(rows, 2, 8 * 4096, 1)[0]
    assert not AK.plan_run(rows, 2, 8 * 4096 - 1, 1)[0]
    rows[3, 3] = -1
    assert not AK.plan_run(rows, 2, 1 << 22, 1)[0]
    assert not AK.plan_run(rows[:0], 2, 1 << 22, 1)[0]
    assert AK.plan_run(_rows([100] * 8), 4, 1 << 22, 3 * 16 * 4096)[1].tolist() == [0, 4, 8]  # 8 packets' room: 2
    assert AK.plan_run(_rows([100] * 2), 4, 1 << 22, 1)[1].tolist() == [0, 1, 2]


def _slow_worker(monkeypatch, fail_here: BaseException | None, signal: bool = False) -> dict[str, bool]:
    """``inflate_events`` made slow on the worker threads (0.2 s) and, with
    ``fail_here``, raising it on the reading thread: what a Ctrl-C or an
    error there looks like to the run; with ``signal``, the worker sends
    the reading thread a real SIGINT as it starts (it arrives while that
    thread decodes its own part or waits for the worker's). The flag says
    whether the workers' parts had ended."""
    state = {"ended": True}
    started = threading.Event()
    real = AK.inflate_events
    main = threading.get_ident()

    def inflate(*args):
        if threading.get_ident() == main:
            if fail_here is not None or signal:
                # the worker is decoding its part (else this thread would decode it, having ended its own)
                assert started.wait(5)
            if fail_here is not None:
                raise fail_here
            return real(*args)
        state["ended"] = False
        started.set()
        if signal:
            signals.pthread_kill(main, signals.SIGINT)
        time.sleep(0.2)
        out = real(*args)
        state["ended"] = True
        return out

    monkeypatch.setattr(AK, "inflate_events", inflate)
    monkeypatch.setattr(aedat4, "_PART_BYTES", 1 << 12)  # two parts even for a small file
    return state


def _file(tmp_path) -> str:
    pytest.importorskip("lz4")
    rng = np.random.default_rng(5)
    n = 20_000
    ev = EventPacket.from_arrays(np.cumsum(rng.integers(0, 5, n)), rng.integers(0, 64, n), rng.integers(0, 48, n),
                                 rng.choice([-1, 1], n), sensor=(64, 48))
    path = str(tmp_path / "w.aedat4")
    write_all(next(c for c in SINKS if c.name == "aedat4")(path, packet_events=700), [ev])
    return path


@pytest.mark.parametrize("fail, signal", [(KeyboardInterrupt(), False), (ValueError("broken"), False),
                                          (None, True)], ids=["ctrl-c", "error", "sigint"])
def test_no_worker_writes_after_an_interrupt(tmp_path, monkeypatch, fail: BaseException | None, signal: bool) -> None:
    """A Ctrl-C (or an error) on the reading thread while a worker decodes
    its part, raised in its own part or while it waits for the worker's:
    the worker's part has ended when the exception reaches the caller (no
    thread still writing into columns the caller gave up)."""
    if not _lz4.AVAILABLE:
        pytest.skip("no compiled LZ4 path")
    if signal and not hasattr(signals, "pthread_kill"):
        pytest.skip("no pthread_kill here")
    path = _file(tmp_path)
    state = _slow_worker(monkeypatch, fail, signal)
    with pytest.raises(KeyboardInterrupt if fail is None else type(fail)):
        list(Aedat4Source(path, threads=2).packets())
    assert state["ended"]


def test_a_part_no_worker_started_is_decoded_here(tmp_path, monkeypatch) -> None:
    """Every worker thread busy elsewhere (for 3 s): the reading thread
    decodes the worker's part itself once it has ended its own, instead of
    waiting for a worker; the events are those of one thread."""
    if not _lz4.AVAILABLE:
        pytest.skip("no compiled LZ4 path")
    path = _file(tmp_path)
    want = [q for q in Aedat4Source(path, threads=1).packets() if isinstance(q, EventPacket)]
    monkeypatch.setattr(aedat4, "_PART_BYTES", 1 << 12)  # two parts even for a small file
    release, busy = threading.Event(), threading.Semaphore(0)

    def block() -> None:
        busy.release()
        release.wait(3)

    pool = workers()
    blockers = [pool.submit(block) for _ in range(pool._max_workers)]
    try:
        for _ in blockers:
            assert busy.acquire(timeout=5)
        got = [q for q in Aedat4Source(path, threads=2).packets() if isinstance(q, EventPacket)]
        assert not any(b.done() for b in blockers)  # it did not wait for them
    finally:
        release.set()
        wait(blockers)
    assert len(got) > 1  # decoded in two parts
    for name in ("t", "x", "y", "p"):
        assert np.array_equal(np.concatenate([getattr(q, name) for q in got]),
                              np.concatenate([getattr(q, name) for q in want]))


def test_no_worker_writes_after_the_consumer_stops(tmp_path, monkeypatch) -> None:
    """A consumer that stops after the first packet (threads=2): no worker
    is left decoding, and the next read gives every event."""
    if not _lz4.AVAILABLE:
        pytest.skip("no compiled LZ4 path")
    path = _file(tmp_path)
    state = _slow_worker(monkeypatch, None)
    it = Aedat4Source(path, threads=2).packets()
    next(it)
    it.close()
    assert state["ended"]
    assert sum(len(q) for q in Aedat4Source(path, threads=2).packets() if isinstance(q, EventPacket)) == 20_000
