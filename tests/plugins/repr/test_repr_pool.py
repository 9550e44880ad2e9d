"""Frames recycled from the repr operators' pools: equal to fresh ones, and
never written while anyone can still read them."""

import gc
import weakref

import numpy as np
import pytest

from tectum import concat
from tectum.plugins import repr as R
from tectum.plugins.repr import _pool
from tectum.testing import assert_stream_contract

from helpers import bars

MAKES = {
    "event_frame": lambda window_us=700, **w: R.EventFrame(window_us=window_us, **w),
    "count_uint8": lambda window_us=700, **w: R.CountImage(window_us=window_us, dtype="uint8", **w),
    "accumulate_int8": lambda window_us=700, **w: R.Accumulate(window_us=window_us, dtype="int8", **w),
    "time_surface": lambda window_us=700, **w: R.TimeSurface(window_us=window_us, tau_us=2000.0, **w),
}
REFERENCE = {"event_frame": R.event_frame, "count_uint8": lambda s: np.minimum(R.count_image(s), 255),
             "accumulate_int8": R.accumulate}


@pytest.fixture
def ev():
    # 16x10 px: an int32 event frame is 1280 bytes and records 20 indices, so windows
    # of 700 µs are zeroed where they were written (few events) or whole (many)
    return bars(duration_us=40_000, sensor="16x10", noise_hz=100.0, speed=300.0)


@pytest.mark.parametrize("name", list(MAKES))
def test_recycled_frames_equal_fresh_ones(ev, name):
    """Fed in pieces whose frames are copied and dropped (so each next piece
    gets recycled blocks), every frame equals the plain reference of its
    window (time surface: the frames of a run that keeps every frame)."""
    op = MAKES[name]()
    got, stamps, bases = [], [], set()
    for piece in ev.batches(53):
        for pkt in op.process(piece):
            if len(pkt):
                bases.add(id(pkt.images.base if pkt.images.base is not None else pkt.images))
                got.append(pkt.images.copy())
                stamps.append(pkt.t.copy())
        pkt = None
    got_all, ts = np.concatenate(got), np.concatenate(stamps)
    assert len(ts) > 40 and len(bases) < len(got) / 4  # the blocks went round
    if name in REFERENCE:
        per_window = [REFERENCE[name](ev.slice_time(t - 699, t + 1)) for t in ts]
        assert np.array_equal(got_all, np.stack(per_window).astype(got_all.dtype))
        if name == "event_frame":
            n = np.array([len(ev.slice_time(t - 699, t + 1)) for t in ts])
            assert (n <= 20).sum() > 5 and (n > 20).sum() > 5  # both ways of zeroing ran
    else:
        kept = concat(op_out for op_out in _feed_keeping(MAKES[name](), ev))
        assert np.array_equal(kept.t[:len(ts)], ts) and np.array_equal(kept.images[:len(ts)], got_all)


def _feed_keeping(op, ev):
    out = []
    for piece in ev.batches(53):
        out += op.process(piece)
    return out + op.finish()


@pytest.mark.parametrize("name", list(MAKES))
@pytest.mark.parametrize("hold", ["packet", "view", "memoryview", "weakref"])
def test_frames_someone_holds_are_never_written(ev, name, hold):
    """A frame kept by a packet, a view, a buffer export or a weak reference
    keeps its values however many windows follow."""
    op = MAKES[name]()
    kept = []
    pieces = list(ev.batches(53))
    for piece in pieces[:len(pieces) // 2]:
        for pkt in op.process(piece):
            if not len(pkt):
                continue
            images = pkt.images
            keep = {"packet": pkt, "view": images[-1:], "memoryview": memoryview(images)}.get(hold)
            if hold == "weakref":
                base = images.base if images.base is not None else images
                keep = weakref.ref(base)
            kept.append((keep, images[-1].copy()))
        pkt = images = keep = base = None  # only what `kept` holds stays
    gc.collect()
    out = [q for piece in pieces[len(pieces) // 2:] for q in op.process(piece)] + op.finish()
    assert_stream_contract(out)
    assert sum(len(q) for q in out) > 20 and len(kept) > 5
    for keep, copy in kept:
        if hold == "weakref":
            base = keep()
            assert base is not None  # the pool keeps it alive: so it must not reuse it
            now = base[-1] if base.shape[0] else None
            # the last frame the packet held: find it among the block's frames by the copy
            assert now is not None and any(np.array_equal(f, copy) for f in base)
        else:
            now = {"packet": lambda k: k.images[-1], "view": lambda k: k[-1],
                   "memoryview": lambda k: np.asarray(k)[-1]}[hold](keep)
            assert np.array_equal(now, copy)


def test_a_pool_reuses_only_unshared_blocks():
    p = _pool.FramePool((2, 3), np.dtype(np.int32), 2, 0, max_blocks=2)
    a, view = p.take()
    b, held_b = p.take()
    assert b is not a  # a's images are held by the reference take() gave
    del view
    c, _ = p.take()
    assert c is a  # free again; b is still held
    held = [a.images, b.images]
    e, _ = p.take()  # none free and no room: a new block, not kept
    assert e is not a and e is not b and len(p._blocks) == 2
    del held, held_b


def test_a_caller_taking_several_blocks_looks_at_each_once(monkeypatch):
    """take(skip) passes the caller's own last blocks by unlooked (a packet
    of k blocks costs k looks, not k squared); a skip that is wrong still
    never hands out a held block."""
    p = _pool.FramePool((2, 3), np.dtype(np.int32), 1, 0, max_blocks=8)
    first = [p.take() for _ in range(3)]
    free = first[0][0]
    del first  # all three free now
    looks = []
    real = _pool._unshared
    monkeypatch.setattr(_pool, "_unshared", lambda b: looks.append(b) or real(b))
    got = []
    for k in range(3):
        got.append(p.take(k))
    assert [len(looks)] == [3] and {id(b) for b, _ in got} == {id(b) for b in p._blocks}
    assert got[-1][0] is free
    held = p.take(0)  # none free (all held in got): a new one, after looking at the three
    assert all(held[0] is not b for b, _ in got)
    wrong = p.take(7)  # more than there are: nothing looked at, a new block
    assert all(wrong[0] is not b for b, _ in [*got, held])


def test_a_block_is_not_taken_twice_across_threads():
    """Threads taking blocks of one shared pool at once never get the same
    block while the first still holds what take() returned."""
    import sys
    import threading
    import time

    p = _pool.FramePool((4,), np.dtype(np.int32), 1, 0, max_blocks=8)
    clashes = []

    def work(k):
        for _ in range(300):
            _, images = p.take()  # the block itself holds no reference to its images for us
            images[0, 0] = k  # ours alone: nobody else may write it before we read it back
            time.sleep(0)
            if images[0, 0] != k:
                clashes.append(k)
            images = None

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        threads = [threading.Thread(target=work, args=(k,)) for k in range(1, 5)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        sys.setswitchinterval(interval)
    assert not clashes


def test_pools_are_shared_by_shape_but_small_frames_keep_their_own():
    """A pipeline built again finds the blocks the last one freed; a tiny
    frame (an operator's warm-up) does not push a shared pool out."""
    big = ((130, 173, 2), np.dtype(np.int32), 11, 8)
    assert _pool.pool(*big) is _pool.pool(*big)
    small = ((8, 8), np.dtype(np.uint8), 4096, 1)
    assert _pool.pool(*small) is not _pool.pool(*small)
    kept = _pool.pool(*big)
    for k in range(_pool.POOLS + 3):
        _pool.pool((8, 8 + k), np.dtype(np.int32), 10, 0)
    assert _pool.pool(*big) is kept


@pytest.mark.parametrize("name", list(MAKES))
@pytest.mark.parametrize("window", [{"window_us": 300}, {"window_us": None, "count": 20}])
def test_frame_packets_built_on_the_trusted_path_pass_the_plain_checks(ev, name, window, monkeypatch):
    """The operators build their frame packets without FramePacket()'s
    checks: each passes them (the plain constructor and validate()), in
    blocks of 1 or 2 frames (packets back to back)."""
    from tectum import FramePacket
    from tectum.plugins.repr import operators
    from tectum.testing import feed

    monkeypatch.setattr(operators, "BLOCK_BYTES", 2 * 16 * 10)  # 2 frames of 8 bits, 1 of 32 or 2 x 32
    monkeypatch.setattr(operators, "MIN_FRAMES", 1)
    out = feed(MAKES[name](**window), list(ev.batches(97)))
    assert sum(len(q) for q in out) > 10 and max(len(q) for q in out) <= 2
    for q in out:
        q.validate()
        FramePacket(q.t, images=q.images, t_start=q.t_start, t_end=q.t_end)
    assert_stream_contract(out)
