"""Numba decode kernels for the binary event formats.

Each kernel is a pure function on arrays: it decodes a chunk of raw words
into preallocated output arrays, keeps the decoder state (time base, wrap
count, vector base...) in a small int64 ``state`` array so a chunk boundary
can fall anywhere, and never raises. The RAW kernels return ``(n_events,
n_triggers, bad, n_bad, n_used)``: ``bad`` is the index of the first invalid
word (-1 when none) and, when ``strict`` is true, decoding stops there;
decoding also stops before a word whose events might not fit in the output
columns, and ``n_used`` says how many words were decoded (call again with
the rest).

``where`` receives, for each event, the index of the word it came from (for
error messages with a byte offset); an empty ``where`` records nothing (the
fast path: offsets are rebuilt by decoding again, only when something is
wrong). ``trig`` (int64, shape (n_words, 3)) receives the external triggers
as rows ``(t µs, channel id, value 1 rising / 0 falling)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._lanes import CD_END, LANES, evt2_group


@njit(cache=True, nogil=True)
def _falls(t, lo, hi, last):  # pragma: no cover - numba
    """How many of ``t[lo:hi]`` lie below the time before them (``last``
    before ``t[lo]``): a vectorised count, two reads of the same cached
    column."""
    a = t[lo:hi - 1]
    b = t[lo + 1:hi]
    c = np.int64(t[lo] < last)
    for k in range(b.shape[0]):
        c += np.int64(b[k] < a[k])
    return c


# --- Prophesee EVT 2.0 ------------------------------------------------------------
# state: 0 time_high (28 bits, unrolled with wraps), 1 have time_high, 2 last raw high,
#        3 wraps, 4 events dropped before the first time_high
EVT2_STATE = 5


@njit(cache=True, nogil=True)
def decode_evt2(words, state, strict, t, x, y, p, where, trig):  # pragma: no cover - numba
    """EVT 2.0 words to events (the module's RAW kernel contract)."""
    n, nt, bad, nbad, i, _, _, _ = _evt2(words, state, strict, t, x, y, p, where, trig)
    return n, nt, bad, nbad, i


@njit(cache=True, nogil=True)
def decode_evt2_bounded(words, state, strict, t, x, y, p, trig):  # pragma: no cover - numba
    """:func:`decode_evt2` without ``where``, returning also the bounds of
    the events written (:meth:`EventAssembler.commit`'s): (..., times never
    fell from one event to the next, largest x, largest y)."""
    return _evt2(words, state, strict, t, x, y, p, np.empty(0, np.int64), trig)


@njit(cache=True, nogil=True)
def _evt2(words, state, strict, t, x, y, p, where, trig):  # pragma: no cover - numba
    """The EVT 2.0 kernel of :func:`decode_evt2` (``where``: each event's
    word index, unless empty) and :func:`decode_evt2_bounded`.

    The words go 16 at a time through :func:`._lanes.evt2_group`, which
    decodes them all as CD words and says how many lead before another
    type: the column index moves on by that many, the other word is
    decoded on its own, and the next 16 start just after it. No scan for
    the end of a run of CD words, no slice per run, no last few one by one
    but at the chunk's end."""
    n = 0
    nt = 0
    bad = -1
    nbad = 0
    th = state[0]
    have = state[1]
    last_raw = state[2]
    wraps = state[3]
    dropped = state[4]
    track = where.shape[0] > 0
    m = min(words.shape[0], t.shape[0])  # one event per word at most
    fell = np.int64(0)  # events whose time is below the one before
    mx = np.int64(0)
    my = np.int64(0)
    # the 6-bit time the next event's is compared with: the last event's in this call under the same
    # time base, 0 when there is none or the base rose past its time, 64 when the base fell below it;
    # lth: the time base of that last event (none yet: below any)
    none = np.int64(-1) << 62
    low = np.int64(0)
    lth = none
    i = 0
    while i < m:
        if have == 1:
            base = th << 6
            while i + LANES <= m:
                got = evt2_group(words, i, t, x, y, p, n, base, low)
                fell += (got >> 8) & 0xFF
                mx = max(mx, (got >> 16) & 0xFFFF)
                my = max(my, (got >> 32) & 0xFFFF)
                j = got & 0xFF
                if track:
                    for q in range(j):
                        where[np.uint64(n + q)] = i + q
                if j == LANES:  # the usual case, by constants: the next load's address waits for no result
                    low = np.int64((words[np.uint64(i + LANES - 1)] >> np.uint32(22)) & np.uint32(0x3F))
                    lth = th
                    n += LANES
                    i += LANES
                    continue
                if j:
                    low = np.int64((words[np.uint64(i + j - 1)] >> np.uint32(22)) & np.uint32(0x3F))
                    lth = th
                n += j
                i += j
                break
            if i >= m:
                break
        w = np.int64(words[np.uint64(i)])
        i += 1
        if w < CD_END:  # one by one: the last few words, or before the first time base
            if have == 0:
                dropped += 1
                continue
            lq = (w >> 22) & 0x3F
            xq = (w >> 11) & 0x7FF
            yq = w & 0x7FF
            k = np.uint64(n)
            t[k] = (th << 6) | lq
            x[k] = xq
            y[k] = yq
            p[k] = np.int8((w >> 27) & 2) - np.int8(1)
            if track:
                where[k] = i - 1
            fell += np.int64(lq < low)
            low = lq
            lth = th
            mx = max(mx, xq)
            my = max(my, yq)
            n += 1
            continue
        typ = w >> 28
        if typ == 8:
            raw = w & 0x0FFFFFFF
            if have == 1 and raw < last_raw and last_raw - raw > (1 << 27):
                wraps += 1
            elif have == 1 and raw > last_raw and raw - last_raw > (1 << 27):
                wraps -= 1  # a step back across a wrap (a corrupt word): unrolled to the nearest time
            last_raw = raw
            th = (wraps << 28) + raw
            have = 1
            if lth != none and th != lth:  # the next event against the last one, by 6-bit times under the new base
                low = np.int64(0) if th > lth else np.int64(64)
        elif typ == 0xA:
            if have == 1:
                trig[nt, 0] = (th << 6) | ((w >> 22) & 0x3F)
                trig[nt, 1] = (w >> 8) & 0x1F
                trig[nt, 2] = w & 1
                nt += 1
        elif typ == 0xE or typ == 0xF:
            pass
        else:
            if bad < 0:
                bad = i - 1
            nbad += 1
            if strict:
                i -= 1
                break
    state[0] = th
    state[1] = have
    state[2] = last_raw
    state[3] = wraps
    state[4] = dropped
    return n, nt, bad, nbad, i, fell == 0, mx, my




# --- Prophesee EVT 3.0 ------------------------------------------------------------
# state: 0 time_high raw (12 bits), 1 time_low, 2 wraps, 3 have_high, 4 y, 5 base_x,
#        6 polarity of vector, 7 dropped before time base, 8 have_low
EVT3_STATE = 9


#: EVT 3.0 word types that take the branch (vectors, their base, triggers and
#: the types the format does not define); the rest are decoded without one
_EVT3_RARE = sum(1 << k for k in (0x1, 0x3, 0x4, 0x5, 0x9, 0xA, 0xB, 0xC, 0xD))


@njit(cache=True, nogil=True)
def _evt3_registers(state):  # pragma: no cover - numba
    """The EVT 3.0 decoder registers in ``state``: (time high, time low,
    wraps, have a time high, y, vector base x, vector polarity (no
    VECT_BASE_X seen yet: OFF, as a zeroed register would say), events
    dropped before the first time high)."""
    return state[0], state[1], state[2], state[3], state[4], state[5], state[6] if state[6] != 0 else -1, state[7]


@njit(cache=True, nogil=True)
def _evt3_keep(state, high, low, wraps, have, cy, bx, vp, dropped):  # pragma: no cover - numba
    """Store the registers of :func:`_evt3_registers` back into ``state``."""
    state[0] = high
    state[1] = low
    state[2] = wraps
    state[3] = have
    state[4] = cy
    state[5] = bx
    state[6] = vp
    state[7] = dropped


@njit(cache=True, nogil=True)
def decode_evt3(words, state, strict, t, x, y, p, where, trig):  # pragma: no cover - numba
    """EVT 3.0 words to events: :func:`_evt3_packed` when ``where`` is empty
    (the fast path), else :func:`_evt3_tracked`; both give the same events,
    state and return values."""
    if where.shape[0] > 0:
        return _evt3_tracked(words, state, strict, t, x, y, p, where, trig)
    n, nt, bad, nbad, i, _, _, _ = _evt3_packed(words, state, strict, t, x, y, p, trig)
    return n, nt, bad, nbad, i


@njit(cache=True, nogil=True)
def decode_evt3_bounded(words, state, strict, t, x, y, p, trig):  # pragma: no cover - numba
    """:func:`decode_evt3`'s fast path, returning also the bounds of the
    events written (:meth:`EventAssembler.commit`'s): (..., times never fell
    from one event to the next, largest x, largest y)."""
    return _evt3_packed(words, state, strict, t, x, y, p, trig)


@njit(cache=True, nogil=True)
def _evt3_tracked(words, state, strict, t, x, y, p, where, trig):  # pragma: no cover - numba
    """The reference decoder, recording each event's word in ``where``.
    The common words (ADDR_Y, ADDR_X, TIME_LOW, TIME_HIGH and the
    ignored ones) update the registers with arithmetic instead of a branch
    per type, whose mispredictions cost more than the decoding on a mixed
    stream; an ADDR_X event is written every time and counted when valid.
    Vector words write all their bits' slots and count the set ones."""
    n = 0
    nt = 0
    bad = -1
    nbad = 0
    high, low, wraps, have, cy, bx, vp, dropped = _evt3_registers(state)
    track = where.shape[0] > 0
    cap = t.shape[0] - 12  # room for a vector word's events
    i = 0
    m = words.shape[0]
    while i < m:
        if n > cap:
            break
        w = np.int64(words[np.uint64(i)])
        i += 1
        typ = w >> 12
        if (_EVT3_RARE >> typ) & 1:
            if typ == 0x3:
                bx = w & 0x7FF
                vp = 1 if (w >> 11) & 1 else -1
            elif typ == 0x4 or typ == 0x5:
                nb = 12 if typ == 0x4 else 8
                if have == 0:
                    bx += nb
                    dropped += 1
                    continue
                tb = (wraps << 24) | (high << 12) | low
                bits = w & 0xFFF
                for b in range(nb):
                    k = np.uint64(n)
                    t[k] = tb
                    x[k] = bx + b
                    y[k] = cy
                    p[k] = vp
                    if track:
                        where[k] = i - 1
                    n += int((bits >> b) & 1)
                bx += nb
            elif typ == 0xA:
                if have == 1:
                    trig[nt, 0] = (wraps << 24) | (high << 12) | low
                    trig[nt, 1] = (w >> 8) & 0xF
                    trig[nt, 2] = w & 1
                    nt += 1
            else:
                if bad < 0:
                    bad = i - 1
                nbad += 1
                if strict:
                    i -= 1
                    break
            continue
        is_y = np.int64(typ == 0x0)
        is_x = np.int64(typ == 0x2)
        is_low = np.int64(typ == 0x6)
        is_high = np.int64(typ == 0x8)
        v = w & 0xFFF
        cy = (w & 0x7FF) if is_y else cy  # selects (cmov): a multiply would lengthen the loop's chain
        low = v if is_low else low
        wraps += is_high & have & np.int64(v < high) & np.int64(high - v > 2048)
        high = v if is_high else high
        have |= is_high
        k = np.uint64(n)
        t[k] = (wraps << 24) | (high << 12) | low
        x[k] = w & 0x7FF
        y[k] = cy
        p[k] = ((w >> 10) & 2) - 1
        if track:
            where[k] = i - 1
        n += is_x * have
        dropped += is_x * (1 - have)
    _evt3_keep(state, high, low, wraps, have, cy, bx, vp, dropped)
    return n, nt, bad, nbad, i


#: Words per block of :func:`_evt3_packed` (its wrap count fits 15 bits).
_EVT3_BLOCK = 1 << 14
#: Per word type: the bits of the packed record of :func:`_evt3_packed` it
#: sets (ADDR_Y 12-22, TIME_LOW 24-35, TIME_HIGH 36-47; none for the others),
#: -1 for TIME_HIGH, and the shift taking the word's 12 bits to its field
#: plus 256 for an event (ADDR_X): the shift and the count in one look-up
_EVT3_FIELD = np.array([0x7FF << 12, 0, 0, 0, 0, 0, 0xFFF << 24, 0, 0xFFF << 36, 0, 0, 0, 0, 0, 0, 0], np.int64)
_EVT3_HIGH = np.array([0, 0, 0, 0, 0, 0, 0, 0, -1, 0, 0, 0, 0, 0, 0, 0], np.int64)
_EVT3_MOVE = np.array([12, 0, 256, 0, 0, 0, 24, 0, 36, 0, 0, 0, 0, 0, 0, 0], np.int64)


@njit(cache=True, nogil=True)
def _evt3_high_spread(words, i, e, high):  # pragma: no cover - numba
    """The largest TIME_HIGH fall words ``[i, e)`` can hold, at most: the
    range of their TIME_HIGH values and ``high`` (the one before). Compares
    the raw 16-bit words (TIME_HIGH is 0x8000-0x8FFF): a vectorised loop."""
    lo = np.uint16(0x8000)
    top = np.uint16(0x8FFF)
    hmax = np.uint16(0x8000 | high)
    hmin = hmax
    ws = words[i:e]
    for k in range(ws.shape[0]):
        w = ws[k]
        h = (w >= lo) & (w <= top)
        hmax = max(hmax, w if h else lo)
        hmin = min(hmin, w if h else top)
    return np.int64(hmax) - np.int64(hmin)


@njit(cache=True, nogil=True)
def _evt3_block(words, i, e, exact, cur, base, n, nt, bad, nbad, bx, vp, strict, t, trig):  # pragma: no cover
    """Words ``[i, e)`` of :func:`_evt3_packed` as packed records into
    ``t[n:]``; ``cur`` holds the latest ADDR_Y, TIME_LOW and TIME_HIGH in
    their fields. Wraps are counted only with ``exact`` (the caller asks
    for it when :func:`_evt3_high_spread` says a fall past 2048 is
    possible). Returns (i, n, nt, bad, nbad, bx, vp, cur, wraps << 48,
    stopped at a bad word, stopped at a wide vector)."""
    wq = np.int64(0)
    while i < e:
        w = np.int64(words[np.uint64(i)])
        typ = w >> 12
        if (_EVT3_RARE >> typ) & 1:
            if typ == 0x4 or typ == 0x5:
                nb = 12 if typ == 0x4 else 8
                if bx < 0 or bx + nb > 4096:
                    return i, n, nt, bad, nbad, bx, vp, cur, wq, False, True
                head = wq | cur | (np.int64(vp > 0) << 11)
                for b in range(nb):
                    xb = bx + b
                    t[np.uint64(n)] = head | (xb & 0x7FF) | ((xb & 0x800) << 12)
                    n += (w >> b) & 1
                bx += nb
            elif typ == 0x3:
                bx = w & 0x7FF
                vp = 1 if (w >> 11) & 1 else -1
            elif typ == 0xA:
                trig[nt, 0] = base + ((wq | cur) >> 24)
                trig[nt, 1] = (w >> 8) & 0xF
                trig[nt, 2] = w & 1
                nt += 1
            else:
                if bad < 0:
                    bad = i
                nbad += 1
                if strict:
                    return i, n, nt, bad, nbad, bx, vp, cur, wq, True, False
            i += 1
            continue
        i += 1
        v = w & 0xFFF
        if exact:  # loop-invariant: compiled as two loops
            wq += np.int64((((cur >> 36) - v) & _EVT3_HIGH[typ]) > 2048) << 48  # a TIME_HIGH falling past half
        move = _EVT3_MOVE[typ]
        cur ^= (cur ^ (v << (move & 63))) & _EVT3_FIELD[typ]  # the word's field replaced, the others kept
        t[np.uint64(n)] = wq | cur | v
        n += move >> 8
    return i, n, nt, bad, nbad, bx, vp, cur, wq, False, False


@njit(cache=True, nogil=True)
def _evt3_packed(words, state, strict, t, x, y, p, trig):  # pragma: no cover - numba
    """:func:`decode_evt3` without ``where``, in blocks of words
    (:func:`_evt3_block`): one pass writes each word as a packed 64-bit
    record into ``t`` (bits 0-10 x, 11 polarity, 12-22 y, 23 x's bit 11,
    24-35 TIME_LOW, 36-47 TIME_HIGH, 48-62 wraps since the block began),
    at the slot of the next event and counted only for ADDR_X: no branch
    but the one for rare types (vectors, triggers, undefined), the
    registers merged into one record through masks looked up by type, one
    store per word. Wraps (one per 16.8 s of recording) are counted only in
    a block whose TIME_HIGH values span more than half their range. A
    second pass unpacks the block's events into the columns while they are
    in cache, noting their bounds (the check pass they spare the caller).
    A vector reaching x past 12 bits (only in a corrupt stream) ends the
    block and is decoded unpacked. Returns :func:`decode_evt3`'s values, then whether no event's
    time fell below the one before, the largest x and the largest y."""
    n = 0
    nt = 0
    bad = -1
    nbad = 0
    high, low, wraps, have, cy, bx, vp, dropped = _evt3_registers(state)
    cap = t.shape[0] - 12
    m = words.shape[0]
    i = 0
    while have == 0 and i < m and n <= cap:  # no time base yet: events dropped, counted
        w = np.int64(words[i])
        typ = w >> 12
        if typ == 0x8:
            high = w & 0xFFF
            have = 1
        elif typ == 0x0:
            cy = w & 0x7FF
        elif typ == 0x6:
            low = w & 0xFFF
        elif typ == 0x2:
            dropped += 1
        elif typ == 0x3:
            bx = w & 0x7FF
            vp = 1 if (w >> 11) & 1 else -1
        elif typ == 0x4 or typ == 0x5:
            bx += 12 if typ == 0x4 else 8
            dropped += 1
        elif (_EVT3_RARE >> typ) & 1 and typ != 0xA:
            if bad < 0:
                bad = i
            nbad += 1
            if strict:
                m = i
                break
        i += 1
    cur = (cy << 12) | (low << 24) | (high << 36)
    last = np.int64(-1) << 62  # the time of the event before (bounds)
    fell = np.int64(0)  # events whose time is below the one before
    mx = np.int64(0)
    my = np.int64(0)
    while have == 1 and i < m and n <= cap:
        n0 = n
        base = wraps << 24
        e = min(m, i + _EVT3_BLOCK, i + (cap - n) // 12 + 1)  # each word starts with n <= cap
        exact = _evt3_high_spread(words, i, e, cur >> 36) > 2048  # a wrap is possible
        i, n, nt, bad, nbad, bx, vp, cur, wq, stop, wide = _evt3_block(words, i, e, exact, cur, base, n, nt, bad,
                                                                       nbad, bx, vp, strict, t, trig)
        bmx = np.uint16(0)
        bmy = np.uint16(0)
        tb = t[n0:n]  # indices from 0 on: no wraparound test per event, a vectorised loop
        xb = x[n0:n]
        yb = y[n0:n]
        pb = p[n0:n]
        for k in range(n - n0):  # unpack, and the largest x and y
            q = tb[k]
            xk = np.uint16((q & 0x7FF) | ((q >> 12) & 0x800))
            yk = np.uint16((q >> 12) & 0x7FF)
            bmx = max(bmx, xk)
            bmy = max(bmy, yk)
            xb[k] = xk
            yb[k] = yk
            pb[k] = np.int8(((q >> 10) & 2) - 1)
            tb[k] = base + (q >> 24)
        mx = max(mx, np.int64(bmx))
        my = max(my, np.int64(bmy))
        if n > n0:
            fell += _falls(t, n0, n, last)
            last = t[n - 1]
        wraps += wq >> 48
        if stop:
            break
        if wide:  # the vector word at i, decoded unpacked
            w = np.int64(words[i])
            i += 1
            nb = 12 if (w >> 12) == 0x4 else 8
            tb = (wraps << 24) | (cur >> 24)
            for b in range(nb):
                at = np.uint64(n)
                t[at] = tb
                x[at] = bx + b
                y[at] = (cur >> 12) & 0x7FF
                p[at] = vp
                if (w >> b) & 1:
                    fell += np.int64(tb < last)
                    last = tb
                    mx = max(mx, np.int64(x[at]))
                    my = max(my, (cur >> 12) & 0x7FF)
                n += (w >> b) & 1
            bx += nb
    if have == 1:
        high = cur >> 36
        low = (cur >> 24) & 0xFFF
        cy = (cur >> 12) & 0x7FF
    _evt3_keep(state, high, low, wraps, have, cy, bx, vp, dropped)
    return n, nt, bad, nbad, i, fell == 0, mx, my


# --- checks shared by the decoders ------------------------------------------------
@njit(cache=True, nogil=True)
def check_events(t, x, y, lo, hi, offset, prev, w, h):  # pragma: no cover - numba
    """Index of the first event in ``[lo, hi)`` whose time (plus ``offset``)
    is below the running maximum (starting at ``prev``) or whose ``x >= w``
    or ``y >= h``; -1 when all are good, and then ``offset`` is added to
    ``t[lo:hi]`` in place (on failure nothing is changed)."""
    if hi <= lo:
        return -1
    if t[lo] + offset < prev or x[lo] >= w or y[lo] >= h:
        return lo
    # blocks of reductions (vectorised; a bad block is then searched event by
    # event): while no time decreased, the running maximum is the previous time
    wu = np.uint16(min(w, 65535))
    hu = np.uint16(min(h, 65535))
    i = lo + 1
    while i < hi:
        j = min(i + 4096, hi)
        a = t[i - 1:j - 1]
        b = t[i:j]
        xs = x[i:j]
        ys = y[i:j]
        dec = np.int64(0)  # a count, not a difference: garbage times would overflow one
        mx = np.uint16(0)
        my = np.uint16(0)
        for k in range(j - i):
            dec += np.int64(b[k] < a[k])
            mx = max(mx, xs[k])
            my = max(my, ys[k])
        if dec or (w <= 65535 and mx >= wu) or (h <= 65535 and my >= hu):
            for k in range(i, j):
                if t[k] < t[k - 1] or x[k] >= w or y[k] >= h:
                    return k
        i = j
    if offset != 0:
        tt = t[lo:hi]
        for k in range(hi - lo):
            tt[k] += offset
    return -1


@njit(cache=True, nogil=True, inline="always")
def _wrap_step(have, last, raw, half):  # pragma: no cover - numba
    """+1 when ``raw`` falls from ``last`` by more than ``half`` (a wrap),
    -1 when it rises by more than ``half`` (a step back across a wrap: a
    corrupt value), else 0: times unroll to the nearest, so a single bad
    value costs that value alone."""
    if have == 0:
        return 0
    if raw < last and last - raw > half:
        return 1
    if raw > last and raw - last > half:
        return -1
    return 0


# --- resynchronisation after bad times (skip_bad) ---------------------------------
@njit(cache=True, nogil=True)
def longest_rise(t, ok, floor, keep):  # pragma: no cover - numba
    """Mark in ``keep`` a longest non-decreasing run of ``t`` (a subsequence)
    among the events with ``ok`` set and ``t >= floor``; returns its length.

    Dropping the fewest events that break time order removes a corrupt time
    (too high or too low) alone and keeps everything after it. Among runs of
    equal length, the one ending lowest is kept (a too-high time is dropped
    before the good ones after it). Patience sorting: O(n log n)."""
    n = t.shape[0]
    tails = np.empty(n, np.int64)  # smallest last time of a run of each length
    tail_i = np.empty(n, np.int64)
    back = np.empty(n, np.int64)
    runs = 0
    for i in range(n):
        keep[i] = False
        v = t[i]
        if not ok[i] or v < floor:
            continue
        lo = 0
        hi = runs
        while lo < hi:  # first run whose last time is above v
            mid = (lo + hi) >> 1
            if tails[mid] > v:
                hi = mid
            else:
                lo = mid + 1
        tails[lo] = v
        tail_i[lo] = i
        back[i] = tail_i[lo - 1] if lo > 0 else -1
        if lo == runs:
            runs += 1
    k = tail_i[runs - 1] if runs > 0 else -1
    while k >= 0:
        keep[k] = True
        k = back[k]
    return runs


# --- Prophesee DAT (EventCD / Event2d: 32-bit time, 14-bit x, 14-bit y, 4-bit p) -----
# state: 0 wraps, 1 last raw time, 2 have last
DAT_STATE = 3


@njit(cache=True, nogil=True)
def dat_unroll(r, to, wraps, last, have, first):  # pragma: no cover - numba
    """The times of the DAT records ``r`` (at least one) unrolled one by one
    into ``to``: a fall of more than half the 32-bit range is a wrap, a rise
    of more than half a step back across one (a corrupt record), each time
    unrolled to the one nearest the previous, so one bad record cannot
    shift every later time by 2^32 µs. ``wraps``, ``last`` (raw) and
    ``have`` are the decoder's state before ``r``; ``first`` is ``r[0]``'s
    raw time. Returns the new ``wraps`` and ``last`` and how many times
    fell (the first compared with the time before it, if any)."""
    half = np.int64(1) << 31
    before = (wraps << 32) + (last if have == 1 else np.int64(first))  # the time before the first
    fell = np.int64(0)
    for k in range(r.shape[0]):
        raw = np.int64(r[k] & np.uint64(0xFFFFFFFF))
        wraps += _wrap_step(have, last, raw, half)
        last = raw
        have = 1
        to[k] = (wraps << 32) + raw
        fell += np.int64(to[k] < before)
        before = to[k]
    return wraps, last, fell


@njit(cache=True, nogil=True)
def decode_dat(records, state, t, x, y, p):  # pragma: no cover - numba
    """``records`` are little-endian uint64 (low word time, high word data);
    returns (n_events, times never decrease, largest x, largest y) (the
    bounds of :meth:`EventAssembler.commit`; the first time is compared
    with the previous call's last).

    A block whose raw times never fall and rise by at most half the 32-bit
    range in all holds no wrap: it is decoded in one vectorised pass on
    32-bit times. Any other block (a wrap, a time out of order, a corrupt
    record) has its times unrolled again one by one (:func:`dat_unroll`)."""
    wraps = state[0]
    last = state[1]
    have = state[2]
    m = records.shape[0]
    half = np.int64(1) << 31
    dec = np.int64(0)  # times that fell
    mx = np.uint16(0)
    my = np.uint16(0)
    i = 0
    while i < m:
        j = min(i + 4096, m)
        r = records[i:j]
        to = t[i:j]
        xo = x[i:j]
        yo = y[i:j]
        po = p[i:j]
        first = np.uint32(last) if have == 1 else np.uint32(r[0] & np.uint64(0xFFFFFFFF))
        prev = first
        fell = np.int64(0)
        hi = wraps << 32
        for k in range(j - i):  # one pass: times as if no wrap, the falls, the data word, the bounds
            rec = r[k]
            r32 = np.uint32(rec & np.uint64(0xFFFFFFFF))
            fell += np.int64(r32 < prev)
            prev = r32
            to[k] = hi + np.int64(r32)
            d = np.uint32(rec >> np.uint64(32))
            xk = np.uint16(d & np.uint32(0x3FFF))
            yk = np.uint16((d >> np.uint32(14)) & np.uint32(0x3FFF))
            mx = max(mx, xk)
            my = max(my, yk)
            xo[k] = xk
            yo[k] = yk
            po[k] = np.int8((d >> np.uint32(28)) != 0) * np.int8(2) - np.int8(1)
        if fell or np.int64(prev) - np.int64(first) > half:  # perhaps a wrap: unrolled one by one
            wraps, last, fell = dat_unroll(r, to, wraps, last, have, first)
            have = 1
        else:
            last = np.int64(prev)
            have = 1
        dec += fell
        i = j
    state[0] = wraps
    state[1] = last
    state[2] = have
    return m, dec == 0, mx, my


# --- jAER AEDAT 2.0 (big-endian int32 address, int32 timestamp) -----------------------
# state: 0 wraps, 1 last raw time, 2 have last
AEDAT2_STATE = 3


@njit(cache=True, nogil=True)
def decode_aedat2(words, state, davis, w, h, t, x, y, p, where, imu_t, imu_v):  # pragma: no cover
    """``words`` are byte-swapped uint32 pairs (address, time).

    DVS128: bit 0 polarity (0 = ON, as jAER reads it), bits 1-7 x (mirrored),
    bits 8-14 y (bottom-left origin), bit 15 external event. DAVIS: bit 31
    APS/IMU, bits 22-30 y (bottom-left), bits 12-21 x (mirrored), bit 11
    polarity (1 = ON), bit 10 external event; IMU
    words are APS-type with bits 10-11 = 3, bits 28-30 the sample's component
    and bits 12-27 its value (7 words per sample). A DVS128 address with any
    of bits 16-31 set is no address (a corrupt record): not decoded, counted.
    Returns (n_events, n_imu_words, first bad record or -1, n_bad)."""
    wraps = state[0]
    last = state[1]
    have = state[2]
    n = 0
    ni = 0
    bad = -1
    nbad = 0
    m = words.shape[0] // 2
    for i in range(m):
        a = np.int64(words[2 * i])
        raw = np.int64(words[2 * i + 1])
        wraps += _wrap_step(have, last, raw, np.int64(1) << 31)
        last = raw
        have = 1
        ts = (wraps << 32) + raw
        if davis:
            if (a >> 31) & 1:
                if (a >> 10) & 3 == 3:
                    imu_t[ni] = ts
                    imu_v[ni, 0] = (a >> 28) & 7
                    imu_v[ni, 1] = (a >> 12) & 0xFFFF
                    ni += 1
                continue
            if (a >> 10) & 1:
                continue
            t[n] = ts
            x[n] = w - 1 - ((a >> 12) & 0x3FF)
            y[n] = h - 1 - ((a >> 22) & 0x1FF)
            p[n] = 1 if (a >> 11) & 1 else -1
        else:
            if a >> 16:
                if bad < 0:
                    bad = i
                nbad += 1
                continue
            if (a >> 15) & 1:
                continue
            t[n] = ts
            x[n] = w - 1 - ((a >> 1) & 0x7F)
            y[n] = h - 1 - ((a >> 8) & 0x7F)
            p[n] = -1 if a & 1 else 1
        where[n] = i
        n += 1
    state[0] = wraps
    state[1] = last
    state[2] = have
    return n, ni, bad, nbad
