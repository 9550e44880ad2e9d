"""The numba decode kernels against slow, obvious reference decoders."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum.sources.files import _kernels as K


def ref_evt2(words):
    out, th = [], None
    for w in (int(v) for v in words):
        typ = w >> 28
        if typ == 8:
            th = w & 0x0FFFFFFF
        elif typ in (0, 1) and th is not None:
            out.append(((th << 6) | ((w >> 22) & 63), (w >> 11) & 0x7FF, w & 0x7FF, 1 if typ else -1))
    return out


def ref_evt3(words):
    out, high, low, y, bx, vp, have = [], 0, 0, 0, 0, 1, False
    for w in (int(v) for v in words):
        typ, v = w >> 12, w & 0xFFF
        t = (high << 12) | low
        if typ == 0:
            y = v & 0x7FF
        elif typ == 2 and have:
            out.append((t, v & 0x7FF, y, 1 if v >> 11 else -1))
        elif typ == 3:
            bx, vp = v & 0x7FF, 1 if v >> 11 else -1
        elif typ in (4, 5):
            nb = 12 if typ == 4 else 8
            if have:
                out.extend((t, bx + b, y, vp) for b in range(nb) if (v >> b) & 1)
            bx += nb
        elif typ == 6:
            low = v
        elif typ == 8:
            high, have = v, True
    return out


def run(kernel, words, state_size, fan):
    n = len(words) * fan
    t, x, y = np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16)
    p, where, trig = np.empty(n, np.int8), np.empty(n, np.int64), np.empty((len(words), 3), np.int64)
    k, _, _, _, _ = kernel(words, np.zeros(state_size, np.int64), False, t, x, y, p, where, trig)
    return list(zip(t[:k].tolist(), x[:k].tolist(), y[:k].tolist(), p[:k].tolist()))


evt2_word = st.one_of(st.integers(0, 2**28 - 1).map(lambda v: (8 << 28) | v),
                      st.tuples(st.sampled_from([0, 1]), st.integers(0, 2**28 - 1)).map(lambda a: (a[0] << 28) | a[1]),
                      st.integers(0, 2**32 - 1))
evt3_word = st.tuples(st.sampled_from([0, 2, 3, 4, 5, 6, 7, 10, 14, 15]), st.integers(0, 4095)).map(
    lambda a: (a[0] << 12) | a[1])


@settings(max_examples=40, deadline=None)
@given(st.lists(evt2_word, max_size=200))
def test_evt2_kernel_matches_reference(words):
    w = np.array(words, np.uint32)
    # the reference has no wrap logic: keep time highs increasing
    assert run(K.decode_evt2, w, K.EVT2_STATE, 1) == ref_evt2(w) or _has_wrap(w)


def test_evt2_long_runs_end_at_any_offset():
    """A run of CD words ends (at a TIME_HIGH, a trigger, an OTHERS word or
    an undefined type) at any offset from the words the run scan takes 8 at a
    time, and the words after it decode as the reference says."""
    rng = np.random.default_rng(5)
    for enders in ((8 << 28) | 7, (0xA << 28) | (3 << 22) | (2 << 8) | 1, 0xE << 28, 0x5 << 28):
        for length in range(26):
            cd = [(int(rng.integers(0, 2)) << 28) | int(rng.integers(0, 1 << 28)) for _ in range(length + 30)]
            w = np.array([(8 << 28) | 5] + cd[:length] + [enders] + cd[length:], np.uint32)
            want = ref_evt2(w)
            assert run(K.decode_evt2, w, K.EVT2_STATE, 1) == want, (hex(enders), length)
            assert len(want) == length + 30


def _has_wrap(w):
    highs = [int(v) & 0x0FFFFFFF for v in w if int(v) >> 28 == 8]
    return any(b < a and a - b > (1 << 27) for a, b in zip(highs, highs[1:]))


@settings(max_examples=40, deadline=None)
@given(st.lists(evt3_word, max_size=200))
def test_evt3_kernel_matches_reference(words):
    w = np.array(words, np.uint16)
    highs = [int(v) & 0xFFF for v in w if int(v) >> 12 == 8]
    wraps = any(b < a and a - b > 2048 for a, b in zip(highs, highs[1:]))
    if not wraps:
        assert run(K.decode_evt3, w, K.EVT3_STATE, 12) == ref_evt3(w)


def decode_evt3_calls(words, strict, cap, fast, state=None):
    """decode_evt3 over all of ``words`` in calls of at most ``cap`` output
    events (resuming after each), on the fast path (empty ``where``) or the
    tracked one: every call's return values and the state after it, the
    events, the triggers."""
    st_ = np.zeros(K.EVT3_STATE, np.int64) if state is None else state.copy()
    calls, events, trig, i = [], [], [], 0
    while i < len(words):
        t, x, y = np.empty(cap, np.int64), np.empty(cap, np.uint16), np.empty(cap, np.uint16)
        p, tr = np.empty(cap, np.int8), np.empty((len(words), 3), np.int64)
        where = np.empty(0 if fast else cap, np.int64)
        n, nt, bad, nbad, used = K.decode_evt3(words[i:], st_, strict, t, x, y, p, where, tr)
        calls.append((n, nt, bad, nbad, used, st_.tolist()))
        events += zip(t[:n].tolist(), x[:n].tolist(), y[:n].tolist(), p[:n].tolist())
        trig += tr[:nt].tolist()
        if used == 0 or (strict and bad >= 0):
            break
        i += used
    return calls, events, trig


#: EVT 3.0 words of every type, the common ones more often, TIME_HIGH
#: values near the ends of their range (wraps) and vector bases anywhere
evt3_any_word = st.one_of(
    st.tuples(st.sampled_from([0, 2, 6, 7, 14, 15]), st.integers(0, 4095)).map(lambda a: (a[0] << 12) | a[1]),
    st.sampled_from([0, 1, 2, 4093, 4094, 4095, 2047, 2048, 2049]).map(lambda v: (8 << 12) | v),
    st.integers(0, 0xFFFF))


@settings(max_examples=200, deadline=None)
@given(st.lists(evt3_any_word, max_size=300), st.booleans(), st.integers(0, 80),
       st.lists(st.integers(-(1 << 20), 1 << 20), min_size=8, max_size=8))
def test_evt3_fast_path_equals_tracked_path(words, strict, cap, state):
    """The packed fast path (no ``where``) gives what the tracked path gives
    (events, triggers, return values, state after each call) on any words:
    undefined types, wraps, vectors past x 2047 or 4095, output full after
    any word, any state to start from."""
    w = np.array(words, np.uint16)
    st0 = np.array(state + [0], np.int64)
    st0[3] = st0[3] & 1  # have: 0 or 1
    st0[6] = 1 if st0[6] > 0 else (-1 if st0[6] < 0 else 0)
    st0[0], st0[1], st0[4] = st0[0] & 0xFFF, st0[1] & 0xFFF, st0[4] & 0x7FF
    st0[2] = abs(int(st0[2])) >> 8
    assert decode_evt3_calls(w, strict, cap, True, st0) == decode_evt3_calls(w, strict, cap, False, st0)


def _bounds_ref(t, x, y):
    """(times never fell from one event to the next, largest x, largest y)."""
    return (bool(np.all(t[1:] >= t[:-1])), int(x.max()) if x.shape[0] else 0, int(y.max()) if y.shape[0] else 0)


def _bounded_calls(kernel, words, state_size, cap, strict):
    """The bounded kernel over ``words`` in calls of at most ``cap`` events:
    per call its bounds and the reference's on the events it wrote."""
    st_, i, out = np.zeros(state_size, np.int64), 0, []
    while i < len(words):
        t, x, y = np.empty(cap, np.int64), np.empty(cap, np.uint16), np.empty(cap, np.uint16)
        p, tr = np.empty(cap, np.int8), np.empty((len(words), 3), np.int64)
        n, _, bad, _, used, ordered, mx, my = kernel(words[i:], st_, strict, t, x, y, p, tr)
        out.append(((bool(ordered), int(mx), int(my)), _bounds_ref(t[:n], x[:n], y[:n])))
        if used == 0 or (strict and bad >= 0):
            break
        i += used
    return out


@settings(max_examples=150, deadline=None)
@given(st.lists(evt3_any_word, max_size=300), st.booleans(), st.integers(0, 80))
def test_evt3_bounds_are_those_of_the_events(words, strict, cap):
    """The bounds the fast path returns (which spare the source its check
    pass) are the events': time falls (TIME_HIGH/TIME_LOW going back,
    wraps), vectors past x 2047 and 4095, every call of a resumed decode."""
    for got, want in _bounded_calls(K.decode_evt3_bounded, np.array(words, np.uint16), K.EVT3_STATE, cap, strict):
        assert got == want


@settings(max_examples=100, deadline=None)
@given(st.lists(evt2_word, max_size=200), st.booleans(), st.integers(1, 60))
def test_evt2_bounds_are_those_of_the_events(words, strict, cap):
    for got, want in _bounded_calls(K.decode_evt2_bounded, np.array(words, np.uint32), K.EVT2_STATE, cap, strict):
        assert got == want


def test_evt3_fast_path_long_streams_and_blocks():
    """Blocks of the fast path: 100k words of every type (triggers, many
    wraps, wide vectors) decode as on the tracked path, with output room for
    all or for a few events per call."""
    rng = np.random.default_rng(7)
    typ = rng.choice([0, 2, 2, 3, 4, 5, 6, 6, 7, 8, 10, 14, 15], 100_000)
    val = rng.integers(0, 4096, typ.shape[0])
    val[typ == 8] = np.cumsum(rng.integers(0, 2, int((typ == 8).sum()))) * 1500 % 4096  # wraps
    w = ((typ << 12) | val).astype(np.uint16)
    for cap in (12 * w.shape[0], 500):
        fast = decode_evt3_calls(w, False, cap, True)
        assert fast == decode_evt3_calls(w, False, cap, False)
        assert len(fast[1]) > 50_000 and len(fast[2]) > 1000
        assert max(e[0] for e in fast[1]) >> 24 > 100  # wrapped many times


def test_evt3_fast_path_at_the_edges():
    """Wraps at a TIME_HIGH fall of exactly 2048 (none) and 2049 (one);
    vectors from base 2040 running on past x 2047, 4095 and 65535 (a corrupt
    stream; x keeps its bits as on the tracked path)."""
    hi, lo, y = 8 << 12, 6 << 12, 5
    words = [hi | 4095, lo | 1, y, (2 << 12) | 9, hi | 2047, (2 << 12) | 9, hi | 4095, hi | 2046, (2 << 12) | 9]
    words += [(3 << 12) | (1 << 11) | 2040] + [(4 << 12) | 0xFFF] * 5500 + [(5 << 12) | 0x81, (2 << 12) | 3]
    w = np.array(words, np.uint16)
    fast = decode_evt3_calls(w, True, 12 * len(words), True)
    assert fast == decode_evt3_calls(w, True, 12 * len(words), False)
    ev = fast[1]
    assert [e[0] >> 24 for e in ev[:3]] == [0, 0, 1]
    xs = [e[1] for e in ev[3:-3]]
    assert xs[:2] == [2040, 2041] and 4096 in xs and 0 in xs[10:] and len(xs) == 66000
    for cap in (12 * len(words), 700):  # the wide vectors' bounds too (decoded outside the blocks)
        for got, want in _bounded_calls(K.decode_evt3_bounded, w, K.EVT3_STATE, cap, True):
            assert got == want


def test_evt3_wrap_is_unrolled():
    words = np.array([(8 << 12) | 4095, (6 << 12) | 10, 0x0005, (2 << 12) | 7,
                      (8 << 12) | 0, (6 << 12) | 3, (2 << 12) | 8], np.uint16)
    ev = run(K.decode_evt3, words, K.EVT3_STATE, 12)
    assert ev[0][0] == (4095 << 12) | 10 and ev[1][0] == (1 << 24) | 3


def test_evt3_chunk_boundary_keeps_state():
    words = np.array([(8 << 12) | 1, (6 << 12) | 2, 9, (3 << 12) | (1 << 11) | 100, (4 << 12) | 0b101,
                      (5 << 12) | 0b1], np.uint16)
    whole = run(K.decode_evt3, words, K.EVT3_STATE, 12)
    st_ = np.zeros(K.EVT3_STATE, np.int64)
    parts = []
    for chunk in (words[:4], words[4:]):
        n = len(chunk) * 12
        t, x, y = np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16)
        p, wh, tr = np.empty(n, np.int8), np.empty(n, np.int64), np.empty((len(chunk), 3), np.int64)
        k, *_ = K.decode_evt3(chunk, st_, False, t, x, y, p, wh, tr)
        parts += list(zip(t[:k].tolist(), x[:k].tolist(), y[:k].tolist(), p[:k].tolist()))
    assert parts == whole == [(4098, 100, 9, 1), (4098, 102, 9, 1), (4098, 112, 9, 1)]


def test_trigger_words_give_channel_and_value():
    # EVT 3.0: TIME_HIGH, TIME_LOW, EXT_TRIGGER id 5 rising, id 2 falling
    w3 = np.array([(8 << 12) | 1, (6 << 12) | 3, (0xA << 12) | (5 << 8) | 1, (0xA << 12) | (2 << 8)], np.uint16)
    tr = np.empty((4, 3), np.int64)
    out = [np.empty(48, d) for d in (np.int64, np.uint16, np.uint16, np.int8, np.int64)]
    _, nt, _, _, _ = K.decode_evt3(w3, np.zeros(K.EVT3_STATE, np.int64), True, *out, tr)
    assert tr[:nt].tolist() == [[4099, 5, 1], [4099, 2, 0]]
    # EVT 2.0: TIME_HIGH 2, EXT_TRIGGER with 6-bit time 7, id 17, rising
    w2 = np.array([(8 << 28) | 2, (0xA << 28) | (7 << 22) | (17 << 8) | 1], np.uint32)
    _, nt, _, _, _ = K.decode_evt2(w2, np.zeros(K.EVT2_STATE, np.int64), True, *out, tr)
    assert tr[:nt].tolist() == [[(2 << 6) | 7, 17, 1]]


def ref_dat(times, data):
    """Each 32-bit time unrolled to the value nearest the previous one (a fall
    of more than half the range is a wrap, a rise of more than half a step
    back across one)."""
    out, t = [], None
    for raw, d in zip(times, data):
        t = raw if t is None else t + ((raw - t + (1 << 31)) % (1 << 32)) - (1 << 31)
        out.append((t, d & 0x3FFF, (d >> 14) & 0x3FFF, 1 if d >> 28 else -1))
    return out


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 12_000), st.lists(st.integers(0, 12_000), max_size=3), st.integers(0, 2**32 - 1),
       st.integers(0, 6), st.integers(0, 2))
def test_dat_unrolls_wraps_in_any_chunking(n, cuts, t0, n_jumps, n_back):
    """32-bit times falling by more than half their range count one wrap, a
    time rising by more than half (a bad record) steps back across one,
    wherever the wraps and the chunk boundaries (vector blocks) fall."""
    rng = np.random.default_rng(n)
    steps = rng.integers(0, 1 << 20, n).astype(np.int64)
    steps[rng.integers(0, n, n_jumps)] += (1 << 31) - (1 << 20)  # large jumps: two make a wrap
    times = ((t0 + np.cumsum(steps)) & 0xFFFFFFFF).astype(np.uint64)
    times[rng.integers(0, n, n_back)] ^= np.uint64(1 << 31)  # corrupt records, half the range away
    data = rng.integers(0, 1 << 32, n, dtype=np.uint64)
    rec = times | (data << np.uint64(32))
    state = np.zeros(K.DAT_STATE, np.int64)
    got = []
    for part in np.split(rec, sorted(c % (n + 1) for c in cuts)):
        t, x, y = np.empty(len(part), np.int64), np.empty(len(part), np.uint16), np.empty(len(part), np.uint16)
        p = np.empty(len(part), np.int8)
        before = got[-1][0] if got else None
        _, ordered, mx, my = K.decode_dat(part, state, t, x, y, p)
        got += list(zip(t.tolist(), x.tolist(), y.tolist(), p.tolist()))
        # the bounds the assembler trusts: order (from the previous call's last time on) and largest x, y
        times_here = ([before] if before is not None else []) + t.tolist()
        assert ordered == all(a <= b for a, b in zip(times_here, times_here[1:]))
        assert (mx, my) == ((int(x.max()), int(y.max())) if len(part) else (0, 0))
    assert got == ref_dat(times.tolist(), data.tolist())


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 9000), st.integers(0, 2**30), st.integers(1, 8_999), st.integers(-3, 2**30).filter(lambda v: v != -1))
def test_dat_rise_past_half_the_range_within_ordered_times(n, t0, at, over):
    """Times that never fall but rise by about half the 32-bit range (``over``
    past it) from one record to the next (a corrupt record, or two records
    far apart): more than half is unrolled to the nearest time like any
    other, whatever the block and the calls' boundaries (a rise of exactly
    half, ``over == -1``, is none: :func:`ref_dat` would step back)."""
    times = t0 + np.arange(n, dtype=np.int64)
    times[at % n:] += (1 << 31) + over  # stays below 2^32: no time falls
    data = np.random.default_rng(n).integers(0, 1 << 32, n, dtype=np.uint64)
    check_dat_cuts_raw(times.astype(np.uint64), data, [[], [at % n], [4096]])


def test_dat_wrap_exactly_at_a_chunk_or_block_boundary():
    """A wrap between the last record of one call (or of one 4096-record
    vector block) and the first of the next counts as one too, after a block
    without a wrap (the vector loop) and after one with a wrap (record by
    record)."""
    n = 4096 + 10
    k = np.arange(n, dtype=np.int64)
    data = np.random.default_rng(1).integers(0, 1 << 32, n, dtype=np.uint64)
    plain = (1 << 32) - 4096 + k  # 2^32 at record 4096
    wrapped = np.where(k == 0, (1 << 32) - 1, (1 << 33) - (4096 - k) * (1 << 20))  # 2^32 at 1, 2^33 at 4096
    for unrolled in (plain, wrapped):
        check_dat_cuts(unrolled, data, [[], [4096], [4095, 4096]])


def check_dat_cuts_raw(times, data, cuts_list):
    """decode_dat over the 32-bit ``times`` in calls cut at each of
    ``cuts_list`` equals :func:`ref_dat`."""
    rec = times | (data << np.uint64(32))
    want = ref_dat(times.tolist(), data.tolist())
    for cuts in cuts_list:
        state = np.zeros(K.DAT_STATE, np.int64)
        got = []
        for part in np.split(rec, [c for c in cuts if c <= len(rec)]):
            t, x, y = np.empty(len(part), np.int64), np.empty(len(part), np.uint16), np.empty(len(part), np.uint16)
            p = np.empty(len(part), np.int8)
            K.decode_dat(part, state, t, x, y, p)
            got += list(zip(t.tolist(), x.tolist(), y.tolist(), p.tolist()))
        assert got == want, cuts


def check_dat_cuts(unrolled, data, cuts_list):
    """decode_dat over the 32-bit times of ``unrolled``, in calls cut at each
    of ``cuts_list``, gives the unrolled times."""
    times = (unrolled & 0xFFFFFFFF).astype(np.uint64)
    assert [w[0] for w in ref_dat(times.tolist(), data.tolist())] == unrolled.tolist()
    check_dat_cuts_raw(times, data, cuts_list)


def test_wrap_step_at_exactly_half_the_range():
    """The 32-bit clocks (DAT, AEDAT 2.0) unroll to the nearest time: a fall
    by more than half the range is one wrap forward, a rise by more than half
    one back (a corrupt value); exactly half either way is no wrap; nothing
    before the first time."""
    half = 1 << 31
    for have, last, raw, step in [(1, half + 10, 10, 0), (1, half + 10, 9, 1), (1, 10, half + 10, 0),
                                  (1, 10, half + 11, -1), (1, 7, 7, 0), (0, half + 10, 9, 0), (0, 10, half + 11, 0)]:
        assert K._wrap_step(np.int64(have), np.int64(last), np.int64(raw), np.int64(half)) == step, (last, raw)
