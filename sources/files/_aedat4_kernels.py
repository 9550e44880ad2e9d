"""Numba FlatBuffer walkers for AEDAT 4.0 packets, many packets per call.

A file holds thousands of small packets: looking up each packet's fields in
Python cost more than decoding the events. :func:`scan_packets` finds the
packets (and their LZ4 block) in a read buffer, many per call;
:func:`fill_events` decodes one
packet straight into a batch's preallocated columns (no per-packet arrays,
no joined copy); :func:`table_fields` takes one buffer holding many
decompressed, size-prefixed FlatBuffers (``offs[k]`` to ``ends[k]``). The
table/vtable/vector look-ups are bounds-checked in compiled code and never
raise: a malformed packet is reported.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic, overload

from . import _lz4 as LZ4

__all__ = ["fill_events", "inflate_events", "inflate_packets", "lz4_frame", "pack_events", "plan_run", "scan_packets",
           "table_fields"]


@njit(cache=True, nogil=True, inline="always")
def _u32(buf, i):  # pragma: no cover - numba
    return (np.int64(buf[i]) | (np.int64(buf[i + 1]) << 8) | (np.int64(buf[i + 2]) << 16)
            | (np.int64(buf[i + 3]) << 24))


@njit(cache=True, nogil=True, inline="always")
def _u16(buf, i):  # pragma: no cover - numba
    return np.int64(buf[i]) | (np.int64(buf[i + 1]) << 8)


@njit(cache=True, nogil=True)
def _root_field(buf, lo, hi, field):  # pragma: no cover - numba
    """(table position, field position or 0 when absent); -1 table when the
    buffer ``[lo, hi)`` is not a well-formed size-prefixed FlatBuffer."""
    if hi - lo < 12 or _u32(buf, lo) + 4 > hi - lo:
        return -1, 0
    tab = lo + 4 + _u32(buf, lo + 4)
    if tab + 4 > hi:
        return -1, 0
    so = _u32(buf, tab)
    if so >= np.int64(1) << 31:
        so -= np.int64(1) << 32
    vt = tab - so
    if vt < lo or vt + 4 > hi:
        return -1, 0
    vsize = _u16(buf, vt)
    if vsize < 4 or vsize & 1 or vt + vsize > hi:
        return -1, 0
    if 4 + 2 * field + 2 > vsize:
        return tab, 0
    off = _u16(buf, vt + 4 + 2 * field)
    if off == 0:
        return tab, 0
    return tab, tab + off


@njit(cache=True, nogil=True)
def _vector(buf, lo, hi, field, elem):  # pragma: no cover - numba
    """(first element position, length) of root vector ``field``; length -1
    when malformed."""
    tab, at = _root_field(buf, lo, hi, field)
    if tab < 0:
        return 0, -1
    if at == 0:
        return 0, 0
    if at + 4 > hi:
        return 0, -1
    vec = at + _u32(buf, at)
    if vec + 4 > hi:
        return 0, -1
    n = _u32(buf, vec)
    if vec + 4 + n * elem > hi:
        return 0, -1
    return vec + 4, n


#: Events :func:`_split_blocks` splits at once (16 x 16 bytes: 4 cache lines)
_LANES = 16


def _split_blocks(q, nb, t, x, y, p, last):  # pragma: no cover - numba
    """The ``Event`` structs ``0 .. 16 * nb - 1`` of ``q`` (their bytes as
    int64 words, two each) into ``t``, ``x``, ``y``, ``p`` from index 0,
    checked on the way: returns (times below the time before them, the
    first compared with ``last``; largest x; largest y). Compiled, one
    loop of vector code (see :func:`_split_blocks_ir`); this is the plain
    form (``NUMBA_DISABLE_JIT``)."""
    dec = mx = my = 0
    for k in range(_LANES * nb):
        w = int(q[2 * k + 1])  # little-endian: x, y, polarity, padding
        v = int(q[2 * k])
        t[k] = v
        x[k] = w & 0xFFFF
        y[k] = (w >> 16) & 0xFFFF
        p[k] = 1 if (w >> 32) & 0xFF else -1
        dec += v < last
        last = v
        mx = max(mx, w & 0xFFFF)
        my = max(my, (w >> 16) & 0xFFFF)
    return dec, mx, my


@intrinsic
def _split_blocks_ir(typingctx, q, nb, t, x, y, p, last):
    """:func:`_split_blocks` as one loop of LLVM vector code, per 16 events:
    a ``<32 x i64>`` load; the times (even words) and the rest (odd words:
    x | y << 16 | polarity << 32) taken apart by two shuffles; x and y
    picked from the rest's 16-bit lanes by one shuffle, the polarity bytes
    by another; whole-vector stores; the checks on the registers (x and y
    maxima, times below the lane before them counted by a mask's
    popcount). No truncating stores: LLVM lowered the narrowing of the
    earlier version to ``vpmovqw`` to memory, slow on AMD Zen 4; with the
    checks in a second pass over the columns, 0.55 against 0.38 ns an
    event here (columns in cache; 1.08 against 0.96 written to cold
    memory). Any target lowers the same IR. Tried, no gain: the times'
    stores non-temporal (``!nontemporal``, a fence after the loop): this
    loop alone 0.97 -> 0.87 ns an event into cold columns, but the whole
    decode 1.0015x the CPU (dvxplorer_2, 151 interleaved rounds in one
    process, 1 and 2 threads, loaded)."""
    sig = types.UniTuple(types.int64, 3)(q, types.intp, t, x, y, p, types.int64)

    def codegen(context, builder, signature, args):
        qa, ta, xa, ya, pa = (context.make_array(ty)(context, builder, v)
                              for ty, v in zip(signature.args, args) if isinstance(ty, types.Array))
        i64, i32, i16, i8 = (ir.IntType(b) for b in (64, 32, 16, 8))

        def lanes(picks):
            return ir.Constant(ir.VectorType(i32, len(picks)), list(picks))

        def pick(vec, picks):
            return builder.shuffle_vector(vec, ir.Constant(vec.type, None), lanes(picks))

        v16, v8, v64 = (ir.VectorType(e, _LANES) for e in (i16, i8, i64))
        mod = builder.module
        umax = cgutils.get_or_insert_function(mod, ir.FunctionType(v16, [v16, v16]), f"llvm.umax.v{_LANES}i16")
        popcount = cgutils.get_or_insert_function(mod, ir.FunctionType(i16, [i16]), "llvm.ctpop.i16")
        reduce = cgutils.get_or_insert_function(mod, ir.FunctionType(i16, [v16]),
                                                f"llvm.vector.reduce.umax.v{_LANES}i16")
        max_x = cgutils.alloca_once_value(builder, ir.Constant(v16, None))
        max_y = cgutils.alloca_once_value(builder, ir.Constant(v16, None))
        falls = cgutils.alloca_once_value(builder, ir.Constant(i64, 0))
        before = cgutils.alloca_once_value(  # the times of the block before (the last lane: ``last``)
            builder, builder.insert_element(ir.Constant(v64, None), args[6], ir.Constant(i32, _LANES - 1)))
        with cgutils.for_range(builder, args[1]) as loop:
            j = loop.index
            at = builder.gep(qa.data, [builder.mul(j, ir.Constant(j.type, 2 * _LANES))])
            words = builder.load(builder.bitcast(at, ir.VectorType(i64, 2 * _LANES).as_pointer()), align=8)
            times = pick(words, range(0, 2 * _LANES, 2))
            rest = pick(words, range(1, 2 * _LANES, 2))
            xy = pick(builder.bitcast(rest, ir.VectorType(i16, 4 * _LANES)),
                      [*range(0, 4 * _LANES, 4), *range(1, 4 * _LANES, 4)])
            xs = pick(xy, range(_LANES))
            ys = pick(xy, range(_LANES, 2 * _LANES))
            on = pick(builder.bitcast(rest, ir.VectorType(i8, 8 * _LANES)), range(4, 8 * _LANES, 8))
            ps = builder.select(builder.icmp_unsigned("!=", on, ir.Constant(v8, None)),
                                ir.Constant(v8, [1] * _LANES), ir.Constant(v8, [0xFF] * _LANES))
            o = builder.mul(j, ir.Constant(j.type, _LANES))
            for arr, val in ((ta, times), (xa, xs), (ya, ys), (pa, ps)):
                builder.store(val, builder.bitcast(builder.gep(arr.data, [o]), val.type.as_pointer()), align=1)
            builder.store(builder.call(umax, [builder.load(max_x), xs]), max_x)
            builder.store(builder.call(umax, [builder.load(max_y), ys]), max_y)
            prev = builder.shuffle_vector(builder.load(before), times, lanes(range(_LANES - 1, 2 * _LANES - 1)))
            fell = builder.bitcast(builder.icmp_signed("<", times, prev), i16)
            builder.store(builder.add(builder.load(falls), builder.zext(builder.call(popcount, [fell]), i64)), falls)
            builder.store(times, before)
        mx, my = (builder.zext(builder.call(reduce, [builder.load(m)]), i64) for m in (max_x, max_y))
        return context.make_tuple(builder, signature.return_type, [builder.load(falls), mx, my])

    return sig, codegen


@overload(_split_blocks)
def _split_blocks_compiled(q, nb, t, x, y, p, last):
    if any(a.layout != "C" for a in (q, t, x, y, p)):  # the vector loads and stores need contiguous arrays
        return _split_blocks
    return lambda q, nb, t, x, y, p, last: _split_blocks_ir(q, nb, t, x, y, p, last)


@njit(cache=True, nogil=True)
def _split(b, o, t, x, y, p, last):  # pragma: no cover - numba
    """The ``Event`` structs ``b`` (16 bytes each) into the columns from
    ``o``, checked on the way: returns (times below the time before them,
    the first compared with ``last``; largest x; largest y; last time), or
    (0, 0, 0, last) when ``b`` holds no event."""
    n = b.shape[0] // 16
    to = t[o:o + n]
    xo = x[o:o + n]
    yo = y[o:o + n]
    po = p[o:o + n]
    dec = np.int64(0)  # a count, not a difference: garbage times would overflow one
    if n == 0:
        return dec, np.int64(0), np.int64(0), last
    mx = np.int64(0)
    my = np.int64(0)
    if b.ctypes.data % 8 == 0:  # aligned, as FlatBuffers write it: whole-word loads
        q = b.view(np.int64)
        i = n // _LANES * _LANES  # 16 at a time, then the rest one by one
        if i:
            dec, mx, my = _split_blocks(q, i // _LANES, to, xo, yo, po, last)
            last = to[i - 1]
        for k in range(i, n):
            w = q[2 * k + 1]  # little-endian: x, y, polarity, padding
            v = q[2 * k]
            to[k] = v
            xo[k] = np.uint16(w & 0xFFFF)
            yo[k] = np.uint16((w >> 16) & 0xFFFF)
            po[k] = np.int8((w >> 32) & 0xFF != 0) * np.int8(2) - np.int8(1)  # no branch on a random bit
            dec += np.int64(v < last)
            last = v
            mx = max(mx, np.int64(w & 0xFFFF))
            my = max(my, np.int64((w >> 16) & 0xFFFF))
        return dec, mx, my, last
    for i in range(n):
        v = np.int64(0)
        for j in range(8):
            v |= np.int64(b[16 * i + j]) << (8 * j)
        xi = _u16(b, 16 * i + 8)
        yi = _u16(b, 16 * i + 10)
        to[i] = v
        xo[i] = xi
        yo[i] = yi
        po[i] = np.int8(1) if b[16 * i + 12] != 0 else np.int8(-1)
        dec += np.int64(v < last)
        last = v
        mx = max(mx, xi)
        my = max(my, yi)
    return dec, mx, my, last


@njit(cache=True, nogil=True)
def pack_events(t, x, y, p, out):  # pragma: no cover - numba
    """The columns as ``Event`` structs (int64 t, int16 x, int16 y, bool
    polarity, 3 zero bytes) in ``out`` (16 bytes each, 8-aligned)."""
    q = out.view(np.int64)
    for i in range(t.shape[0]):  # little-endian: the second word is x, y, polarity, padding
        q[2 * i] = t[i]
        q[2 * i + 1] = np.int64(x[i]) | (np.int64(y[i]) << 16) | (np.int64(1 if p[i] > 0 else 0) << 32)


@njit(cache=True, nogil=True)
def fill_events(buf, o, t, x, y, p):  # pragma: no cover - numba
    """Split the ``Event`` structs (int64 t, int16 x, int16 y, bool polarity)
    of one EventPacket FlatBuffer into the columns from index ``o``; returns
    the number of events, or -1 when the buffer is malformed or the columns
    are too short."""
    s, n = _vector(buf, 0, buf.shape[0], 0, 16)
    if n < 0 or o + n > t.shape[0]:
        return -1
    _split(buf[s:s + 16 * n], o, t, x, y, p, np.int64(0))
    return n


@njit(cache=True, nogil=True)
def _inflate(buf, lo, hi, linked, scratch, size):  # pragma: no cover - numba
    """The blocks ``buf[lo:hi]`` of an LZ4 frame (see :func:`lz4_frame`)
    into ``scratch[:size]``: the bytes written, -1 when a block is corrupt."""
    o = 0
    j = lo
    while j < hi:
        w = _u32(buf, j)
        n = w & 0x7FFFFFFF
        j += 4
        if w >> 31:  # stored uncompressed
            if o + n > size:
                return -1
            scratch[o:o + n] = buf[j:j + n]
            r = n
        elif linked and o > 0:  # refers back to the blocks before it, up to 64 KiB
            d = max(0, o - 65536)
            r = LZ4.decompress_safe_dict(buf, j, n, scratch, o, size - o, d, o - d)
        else:
            r = LZ4.decompress_safe(buf, j, n, scratch, o, size - o)
        if r < 0:
            return -1
        o += r
        j += n
    return o


@njit(cache=True, nogil=True)
def inflate_events(buf, rows, k, scratch, t, x, y, p, counts):  # pragma: no cover - numba
    """Decompress and split the event packets ``rows[k:]`` (rows of
    :func:`scan_packets` in ``buf``) into the columns, each packet through
    ``scratch`` (so it stays in cache). ``counts[k]`` gets each packet's
    number of events, -1 when its FlatBuffer is malformed, -2 when it does
    not decompress. Stops before a packet that is not a plain LZ4 frame or
    whose events may not fit in the columns. Returns (events written, next
    packet, whether no time written is below the one before it, largest x,
    largest y): what :meth:`EventAssembler.commit` would otherwise check
    in a second pass. Call only when
    :data:`tectum.sources.files._lz4.AVAILABLE`."""
    o = 0
    dec = np.int64(0)
    mx = np.int64(0)
    my = np.int64(0)
    last = np.int64(-(1 << 62))
    while k < rows.shape[0]:
        size = rows[k, 5]
        if rows[k, 3] < 0 or size > scratch.shape[0] or o + size // 16 > t.shape[0]:
            break
        n = _inflate(buf, rows[k, 3], rows[k, 4], rows[k, 6], scratch, size)
        if n < 0 or (rows[k, 7] >= 0 and n != rows[k, 7]):
            counts[k] = -2
        else:
            s, m = _vector(scratch, 0, n, 0, 16)
            counts[k] = m
            if m > 0:
                d, a, b, last = _split(scratch[s:s + 16 * m], o, t, x, y, p, last)
                dec += d
                mx = max(mx, a)
                my = max(my, b)
                o += m
        k += 1
    return o, k, dec == 0, mx, my


@njit(cache=True, nogil=True)
def plan_run(rows, threads, run_events, part_bytes):  # pragma: no cover - numba
    """How to decode the event packets ``rows`` (of :func:`scan_packets`)
    as one run of :func:`inflate_events` calls: returns (whether they are
    all plain LZ4 frames whose events fit in ``run_events``, the cuts of
    the run into parts, the columns' room before each cut, the largest
    packet's room in bytes). Parts: up to ``threads``, at least one packet
    and ``part_bytes`` of room each, of about equal compressed bytes
    (decoding time follows them: cut in equal numbers of packets, the two
    halves of a recording held 175 k and 149 k events and the thread with
    the first waited 0.25 ms for nothing). One call in place of a dozen
    NumPy calls on the rows (~20 us less a read)."""
    n = rows.shape[0]
    room = np.int64(0)
    size = np.int64(0)
    scratch = np.int64(0)
    total = np.int64(0)
    ok = n > 0
    for k in range(n):
        ok = ok and rows[k, 3] >= 0
        room += rows[k, 5] // 16
        total += rows[k, 5]
        size += rows[k, 1] - rows[k, 0]
        scratch = max(scratch, rows[k, 5])
    w = max(1, min(threads, n, total // part_bytes))
    cuts = np.zeros(w + 1, np.int64)
    at = np.zeros(w + 1, np.int64)
    cuts[w] = n
    i = 1
    done = np.int64(0)  # compressed bytes of the packets before k
    held = np.int64(0)  # their room
    for k in range(n):
        if i < w and (done * w >= size * i or n - k <= w - i) and k > cuts[i - 1]:
            cuts[i] = k
            at[i] = held
            i += 1
        done += rows[k, 1] - rows[k, 0]
        held += rows[k, 5] // 16
    at[w] = room
    return ok and room <= run_events, cuts, at, scratch


@njit(cache=True, nogil=True)
def inflate_packets(buf, rows, out, starts, ends):  # pragma: no cover - numba
    """Decompress the packets ``rows`` (of :func:`scan_packets` in ``buf``)
    one after the other into ``out`` (room: the sum of their room):
    ``out[starts[k]:ends[k]]`` is packet k; ``ends[k]`` is -1 when it does
    not decompress, -2 when it is not a plain LZ4 frame (the caller
    decompresses those). Call only when
    :data:`tectum.sources.files._lz4.AVAILABLE`."""
    o = 0
    for k in range(rows.shape[0]):
        size = rows[k, 5]
        starts[k] = o
        if rows[k, 3] < 0 or o + size > out.shape[0]:
            ends[k] = -2
            continue
        n = _inflate(buf, rows[k, 3], rows[k, 4], rows[k, 6], out[o:o + size], size)
        if n < 0 or (rows[k, 7] >= 0 and n != rows[k, 7]):
            ends[k] = -1
            continue
        o += n
        ends[k] = o
    return o


@njit(cache=True, nogil=True)
def lz4_frame(buf, lo, hi):  # pragma: no cover - numba
    """The blocks of the LZ4 frame ``buf[lo:hi]``, when it is one the
    kernels decode: version 01, no checksums, no dictionary, blocks then the
    end mark then nothing. Returns (first block header, end mark position,
    room the data needs, 1 when blocks are linked, content size or -1 when
    the frame does not say, number of blocks); first block -1 for any other
    frame (or a malformed one: the frame decoder then says why)."""
    if hi - lo < 11 or _u32(buf, lo) != 0x184D2204:
        return -1, 0, 0, 0, -1, 0
    flg = np.int64(buf[lo + 4])
    bd = np.int64(buf[lo + 5])
    bm = (bd >> 4) & 7
    if flg & 0xC0 != 0x40 or flg & 0x17 or bd & 0x8F or bm < 4:
        return -1, 0, 0, 0, -1, 0  # other version, block/content checksums, dictionary id or reserved bits
    block_max = np.int64(1) << (8 + 2 * bm)
    j = lo + 6
    content = np.int64(-1)
    if flg & 0x08:
        if j + 8 > hi:
            return -1, 0, 0, 0, -1, 0
        content = _u32(buf, j) | (_u32(buf, j + 4) << 32)
        if content < 0 or content >= np.int64(1) << 31:
            return -1, 0, 0, 0, -1, 0
        j += 8
    j += 1  # header checksum
    first = j
    nb = 0
    while True:
        if j + 4 > hi:
            return -1, 0, 0, 0, -1, 0
        n = _u32(buf, j) & 0x7FFFFFFF
        if n == 0:
            break
        if n > block_max or j + 4 + n > hi:
            return -1, 0, 0, 0, -1, 0
        nb += 1
        j += 4 + n
    if j + 4 != hi or _u32(buf, j) != 0 or nb == 0:
        return -1, 0, 0, 0, -1, 0
    room = nb * block_max if content < 0 else min(content, nb * block_max)
    return first, j, room, 0 if flg & 0x20 else 1, content, nb


@njit(cache=True, nogil=True)
def scan_packets(buf, start, have, max_size, lz4, rows, base=0):  # pragma: no cover - numba
    """Walk the packet headers (int32 stream id, int32 size) in
    ``buf[start:have]``: one row per complete packet, ``(payload start,
    payload end, stream id, first block, end mark, room, linked, content
    size, file offset of the header)`` (first block to content size from
    :func:`lz4_frame` when ``lz4``, else first block -1; the buffer starts
    at file offset ``base``). Returns (rows filled, end of the last complete packet,
    status): status 0 when what follows is an incomplete packet or ``rows``
    is full, 1 when the header there has a size below 0 or above
    ``max_size``."""
    i = start
    k = 0
    while k < rows.shape[0] and i + 8 <= have:
        sid = _u32(buf, i)
        size = _u32(buf, i + 4)
        if sid >= np.int64(1) << 31:
            sid -= np.int64(1) << 32
        if size >= np.int64(1) << 31 or size > max_size:
            return k, i, 1
        lo = i + 8
        hi = lo + size
        if hi > have:
            break
        rows[k, 0] = lo
        rows[k, 1] = hi
        rows[k, 2] = sid
        rows[k, 8] = base + i
        if lz4:
            rows[k, 3], rows[k, 4], rows[k, 5], rows[k, 6], rows[k, 7], _ = lz4_frame(buf, lo, hi)
        else:
            rows[k, 3], rows[k, 4], rows[k, 5], rows[k, 6], rows[k, 7] = -1, 0, 0, 0, -1
        k += 1
        i = hi
    return k, i, 0


@njit(cache=True, nogil=True)
def _tables(buf, lo, hi, fields, sizes, pos, row):  # pragma: no cover - numba
    """Fill ``pos`` from ``row`` with the field positions of the root's
    vector of tables in ``[lo, hi)``; returns the next row, -1 if malformed."""
    s, n = _vector(buf, lo, hi, 0, 4)
    if n < 0:
        return -1
    for i in range(n):
        if pos.shape[0] > 0:
            tab = s + 4 * i + _u32(buf, s + 4 * i)
            if tab + 4 > hi:
                return -1
            so = _u32(buf, tab)
            if so >= np.int64(1) << 31:
                so -= np.int64(1) << 32
            vt = tab - so
            if vt < lo or vt + 4 > hi:
                return -1
            vsize = _u16(buf, vt)
            if vsize < 4 or vsize & 1 or vt + vsize > hi:
                return -1
            for j in range(fields.shape[0]):
                pos[row, j] = -1
                if 4 + 2 * fields[j] + 2 <= vsize:
                    off = _u16(buf, vt + 4 + 2 * fields[j])
                    if off != 0:
                        if tab + off + sizes[j] > hi:
                            return -1
                        pos[row, j] = tab + off
        row += 1
    return row


@njit(cache=True, nogil=True)
def table_fields(buf, offs, ends, fields, sizes):  # pragma: no cover - numba
    """For packets whose root field 0 is a vector of tables (IMU, triggers):
    the byte position of each table's ``fields[j]`` (``sizes[j]`` bytes; -1
    when absent), all packets' tables in one array. Returns (positions
    (n, len(fields)), rows per packet, first malformed packet or -1)."""
    rows = np.zeros(offs.shape[0], np.int64)
    probe = np.zeros((0, fields.shape[0]), np.int64)
    total = 0
    for k in range(offs.shape[0]):
        r = _tables(buf, offs[k], ends[k], fields, sizes, probe, 0)
        if r < 0:
            return probe, rows, k
        rows[k] = r
        total += r
    pos = np.empty((total, fields.shape[0]), np.int64)
    row = 0
    for k in range(offs.shape[0]):
        row = _tables(buf, offs[k], ends[k], fields, sizes, pos, row)
        if row < 0:
            return probe, rows, k
    return pos, rows, -1
