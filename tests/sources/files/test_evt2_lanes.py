"""EVT 2.0's vector lanes (runs of CD words 16 at a time) against a slow
reference, in calls cut anywhere, their plain form against the compiled
one, and a bad word where lanes and read pieces end."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from tectum import EventPacket, FormatError
from tectum.sources.files import _kernels as K
from tectum.sources.files._lanes import LANES, evt2_group
from tectum.sources.files.prophesee import Evt2Source


def reference(words: np.ndarray) -> list[tuple[int, int, int, int]]:
    """The events (t, x, y, p) of EVT 2.0 words without a wrap, the slow way."""
    out, high = [], None
    for w in (int(v) for v in words):
        if w >> 28 == 8:
            high = w & 0x0FFFFFFF
        elif w >> 28 in (0, 1) and high is not None:
            out.append(((high << 6) | ((w >> 22) & 63), (w >> 11) & 0x7FF, w & 0x7FF, 1 if w >> 28 else -1))
    return out


def stream(seed: int, runs: int) -> np.ndarray:
    """TIME_HIGH words, each followed by a run of 0 to 70 CD words whose
    6-bit times mostly rise, sometimes fall, sometimes stay; rising time highs."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(runs):
        out.append((8 << 28) | (1000 + k * int(rng.integers(0, 3))))
        n = int(rng.integers(0, 71))
        low = np.sort(rng.integers(0, 64, n))
        if rng.random() < 0.3 and n > 1:  # a time falling somewhere in the run
            j = int(rng.integers(1, n))
            low[j] = max(0, int(low[j - 1]) - 1 - int(rng.integers(0, 5)))
        cd = ((rng.integers(0, 2, n) << 28) | (low << 22) | (rng.integers(0, 2048, n) << 11)
              | rng.integers(0, 2048, n))
        out.extend(int(v) for v in cd)
    return np.array(out, np.uint32)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 40), st.integers(1, 300))
def test_runs_decode_as_the_reference_in_any_calls(seed, runs, cap):
    """Runs of any length (lanes and the last few), in calls of at most
    ``cap`` events (a call can end inside a run): the reference's events,
    and per call the bounds of the events it wrote: their order, largest x
    and y (the assembler compares a call's first time with the last before)."""
    words = stream(seed, runs)
    state, i, got = np.zeros(K.EVT2_STATE, np.int64), 0, []
    while i < words.shape[0]:
        t, x, y = np.empty(cap, np.int64), np.empty(cap, np.uint16), np.empty(cap, np.uint16)
        p, trig = np.empty(cap, np.int8), np.empty((words.shape[0], 3), np.int64)
        n, _, bad, _, used, ordered, mx, my = K.decode_evt2_bounded(words[i:], state, True, t, x, y, p, trig)
        assert bad < 0 and used > 0
        times = t[:n].tolist()
        assert bool(ordered) == all(a <= b for a, b in zip(times, times[1:]))
        assert (int(mx), int(my)) == ((int(x[:n].max()), int(y[:n].max())) if n else (0, 0))
        got += list(zip(t[:n].tolist(), x[:n].tolist(), y[:n].tolist(), p[:n].tolist()))
        i += used
    assert got == reference(words)


@pytest.mark.parametrize("seed", range(6))
def test_plain_group_equals_the_compiled_one(seed):
    """evt2_group's plain form gives the compiled vector code's columns
    (every lane, the garbage past the leading CD words too) and packed
    count, falls and largest x and y, with another word at each lane or
    none, a first comparison that falls (64) or never does (0)."""
    rng = np.random.default_rng(seed)
    words = ((rng.integers(0, 2, 40) << 28) | (rng.integers(0, 64, 40) << 22) | (rng.integers(0, 2048, 40) << 11)
             | rng.integers(0, 2048, 40)).astype(np.uint32)
    compiled = njit(lambda w, i, t, x, y, p, n, base, prev: evt2_group(w, i, t, x, y, p, n, base, prev))
    for other in range(-1, LANES):
        ws = words.copy()
        if other >= 0:
            ws[3 + other] = int(rng.choice([0x8, 0xA, 0xE, 0x5])) << 28 | int(rng.integers(0, 1 << 28))
        for prev in (0, 64, 17):
            a = (np.zeros(40, np.int64), np.zeros(40, np.uint16), np.zeros(40, np.uint16), np.zeros(40, np.int8))
            b = tuple(c.copy() for c in a)
            got = compiled(ws, 3, *a, 5, seed << 6, prev)
            assert got == evt2_group(ws, 3, *b, 5, seed << 6, prev)
            assert all(np.array_equal(u, v) for u, v in zip(a, b))
            assert got & 0xFF == (LANES if other < 0 else other)
            lead = ws[3:3 + (got & 0xFF)].astype(np.int64)
            low = np.concatenate([[prev], lead >> 22 & 63])
            assert got >> 8 & 0xFF == int((low[1:] < low[:-1]).sum())
            assert (got >> 16 & 0xFFFF, got >> 32) == ((int((lead >> 11 & 0x7FF).max()), int((lead & 0x7FF).max()))
                                                       if lead.size else (0, 0))


HEAD = b"% evt 2.0\n% geometry 640x480\n% end\n"


@pytest.mark.parametrize("bad", [LANES - 1, LANES, 2 * LANES + 3, 255, 256, 257])
def test_a_bad_word_where_lanes_and_pieces_end(tmp_path: Path, bad: int) -> None:
    """An undefined word type inside a long run of CD words is refused at
    its byte offset, and dropped alone with skip_bad, whether it ends a
    lane, starts one, sits among the last few or at a read piece's edge
    (chunk_bytes 1 KiB: 256 words)."""
    words = stream(3, 1)[:1]  # a TIME_HIGH
    cd = ((np.arange(600) % 2 << 28) | ((np.arange(600) // 10 % 64) << 22) | (5 << 11) | 7).astype(np.uint32)
    words = np.concatenate([words, cd])
    words[1 + bad] = 0x5 << 28
    path = tmp_path / "f.raw"
    path.write_bytes(HEAD + words.astype("<u4").tobytes())
    for chunk in (1 << 10, 1 << 22):
        with pytest.raises(FormatError) as e:
            list(Evt2Source(str(path), chunk_bytes=chunk).packets())
        assert e.value.offset == len(HEAD) + 4 * (1 + bad)
        src = Evt2Source(str(path), chunk_bytes=chunk, skip_bad=True)
        assert sum(len(q) for q in src.packets() if isinstance(q, EventPacket)) == 599
        assert src.skipped_events == 1


def test_a_fall_at_each_place_of_a_run():
    """A time one below the time before it (and equal to the one before
    that) is a fall wherever it lies in a run: inside a lane, first of a
    lane (against the last of the one before), among the last few."""
    for j in range(1, 45):
        low = np.arange(45, dtype=np.uint32) + 5
        low[j] = low[j - 1] - 1
        words = np.concatenate([[(8 << 28) | 3], (low << 22) | (9 << 11) | 4]).astype(np.uint32)
        t, x, y = np.empty(64, np.int64), np.empty(64, np.uint16), np.empty(64, np.uint16)
        p, trig = np.empty(64, np.int8), np.empty((64, 3), np.int64)
        n, *_, ordered, mx, my = K.decode_evt2_bounded(words, np.zeros(K.EVT2_STATE, np.int64), True, t, x, y, p,
                                                        trig)
        assert n == 45 and not ordered and (mx, my) == (9, 4), j
        assert t[:n].tolist() == [(3 << 6) | int(v) for v in low]


@pytest.mark.parametrize("before", [5, 16, 21, 405])
@pytest.mark.parametrize("after", [0, 3, 10, 40])
@pytest.mark.parametrize("step", [-1, 0, 1])
def test_order_across_a_time_base_after_a_partial_group(before, after, step):
    """A run of CD words ending inside a group of 16, a TIME_HIGH (the same
    time base again, one lower or one higher), more CD words: times in order
    are reported in order, and a lower base is a fall (as gen31_evt2.raw's
    first 417 words, a repeated time base after 405 events, where the
    compiled decoder once read the last time back stale and said 'fell')."""
    low = np.minimum(np.arange(before) * 16 // max(before, 1), 15).astype(np.uint32)
    cd = (low << 22) | (np.arange(before, dtype=np.uint32) % 640 << 11) | 7
    tail = (np.full(after, 16, np.uint32) << 22) | (3 << 11) | 2
    words = np.concatenate([[(8 << 28) | 1000], cd, [(8 << 28) | (1000 + step)], tail]).astype(np.uint32)
    m = words.shape[0] + 64
    t, x, y = np.zeros(m, np.int64), np.zeros(m, np.uint16), np.zeros(m, np.uint16)
    p, trig = np.zeros(m, np.int8), np.empty((m, 3), np.int64)
    n, *_, ordered, mx, my = K.decode_evt2_bounded(words, np.zeros(K.EVT2_STATE, np.int64), True, t, x, y, p, trig)
    assert n == before + after
    times = t[:n].tolist()
    assert bool(ordered) == all(a <= b for a, b in zip(times, times[1:]))
    assert bool(ordered) == (step >= 0 or after == 0)


@pytest.mark.parametrize("fault", ["fall", "outside"])
@pytest.mark.parametrize("at", [0, 1, 7])
def test_a_fault_just_past_a_read_piece(tmp_path: Path, fault: str, at: int) -> None:
    """The reader decodes a chunk's words in pieces of 512 KiB into one set
    of columns: a time falling at the first events of the second piece
    (against the last of the first) or an x outside the sensor there is
    refused at its word's offset (the offsets found by reading the words
    again), not trusted as in order or in bounds."""
    n = (1 << 19) // 4 + 64  # the second piece's words start at index 131072 (the TIME_HIGH is word 0)
    low = np.where(np.arange(n) < (1 << 17) - 1 + at, 10, 10 if fault == "outside" else 5).astype(np.uint32)
    xs = np.full(n, 5, np.uint32)
    if fault == "outside":
        xs[(1 << 17) - 1 + at] = 700
    cd = (low << 22) | (xs << 11) | 7
    words = np.concatenate([[(8 << 28) | 1000], cd]).astype("<u4")
    path = tmp_path / "f.raw"
    path.write_bytes(HEAD + words.tobytes())
    with pytest.raises(FormatError) as e:
        list(Evt2Source(str(path)).packets())
    assert e.value.offset == len(HEAD) + 4 * ((1 << 17) + at)
