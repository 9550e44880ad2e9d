"""The DAT reader's fast kernel: :func:`decode_dat_within`.

:func:`._kernels.decode_dat` written as LLVM vector code, 16 records at a
time (:func:`dat_lanes`): one 128-byte load, the times, x, y and polarity
picked out of it with shuffles instead of LLVM's narrowing stores, and, in
place of the largest x and y, whether any event lies outside the sensor.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic, overload

from ._kernels import dat_unroll
from ._lanes import LANES, splat

__all__ = ["dat_lanes", "decode_dat_within"]

#: Records per block of :func:`decode_dat_within` (a block holding a wrap
#: has its times unrolled again).
_BLOCK = 4096


def dat_lanes(records, i, t, x, y, p, hi, prev, w, h):  # type: ignore[no-untyped-def]
    """Decode records ``i .. i + 15`` into ``t, x, y, p`` at the same
    indices: t = ``hi`` + the 32-bit time, x bits 0-13 and y bits 14-27 of
    the data word, p +1 when any of its bits 28-31 is set, else -1. Returns
    a bit mask: bit ``k`` set when record ``i + k``'s raw time is below the
    one before it (``prev`` before the first), bit ``16 + k`` when its x is
    ``w`` or more or its y ``h`` or more (``w``, ``h`` below 65536).
    Compiled, vector code (:func:`_dat_lanes_ir`); this is the plain form
    (``NUMBA_DISABLE_JIT``)."""
    out = 0
    for k in range(LANES):
        rec = int(records[i + k])
        raw, d = rec & 0xFFFFFFFF, rec >> 32
        xk, yk = d & 0x3FFF, (d >> 14) & 0x3FFF
        t[i + k] = hi + raw
        x[i + k] = xk
        y[i + k] = yk
        p[i + k] = 1 if d >> 28 else -1
        out |= (int(raw < prev) << k) | (int(xk >= w or yk >= h) << (LANES + k))
        prev = raw
    return out


def _lanes(builder, vector, every, at):  # type: ignore[no-untyped-def]
    """Elements ``at``, ``at + every``, ``at + 2 every``... of ``vector``
    (:data:`LANES` of them)."""
    picks = ir.Constant(ir.VectorType(ir.IntType(32), LANES), [every * k + at for k in range(LANES)])
    return builder.shuffle_vector(vector, ir.Constant(vector.type, None), picks)


@intrinsic
def _dat_lanes_ir(typingctx, records, i, t, x, y, p, hi, prev, w, h):  # type: ignore[no-untyped-def]
    sig = types.int64(records, types.intp, t, x, y, p, types.int64, types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        i8, i16, i32, i64 = (ir.IntType(b) for b in (8, 16, 32, 64))
        arrays = [context.make_array(ty)(context, builder, v)
                  for ty, v in zip(signature.args[:1] + signature.args[2:6], args[:1] + args[2:6])]
        rec, to, xo, yo, po = (builder.gep(a.data, [args[1]]) for a in arrays)

        def store(value, ptr):  # type: ignore[no-untyped-def]
            builder.store(value, builder.bitcast(ptr, value.type.as_pointer()), align=1)

        v = builder.load(builder.bitcast(rec, ir.VectorType(i64, LANES).as_pointer()), align=1)
        times = _lanes(builder, builder.bitcast(v, ir.VectorType(i32, 2 * LANES)), 2, 0)
        words = builder.bitcast(v, ir.VectorType(i16, 4 * LANES))
        low, high = _lanes(builder, words, 4, 2), _lanes(builder, words, 4, 3)  # the data word's halves
        store(builder.or_(builder.zext(times, ir.VectorType(i64, LANES)), splat(builder, i64, args[6])), to)
        bits14 = splat(builder, i16, ir.Constant(i16, 0x3FFF))
        xs = builder.and_(low, bits14)
        ys = builder.and_(builder.or_(builder.lshr(low, splat(builder, i16, ir.Constant(i16, 14))),
                                      builder.shl(high, splat(builder, i16, ir.Constant(i16, 2)))), bits14)
        store(xs, xo)
        store(ys, yo)
        on = builder.icmp_unsigned(">=", high, splat(builder, i16, ir.Constant(i16, 0x1000)))
        store(builder.select(on, splat(builder, i8, ir.Constant(i8, 1)),
                             splat(builder, i8, ir.Constant(i8, -1))), po)
        first = builder.insert_element(ir.Constant(ir.VectorType(i32, LANES), None), builder.trunc(args[7], i32),
                                       ir.Constant(i32, 0))
        before = builder.shuffle_vector(first, times, ir.Constant(ir.VectorType(i32, LANES),
                                                                  [0] + [LANES + k for k in range(LANES - 1)]))
        fell = builder.icmp_unsigned("<", times, before)
        out = builder.or_(builder.icmp_unsigned(">=", xs, splat(builder, i16, builder.trunc(args[8], i16))),
                          builder.icmp_unsigned(">=", ys, splat(builder, i16, builder.trunc(args[9], i16))))
        mask = ir.IntType(LANES)
        fell, out = (builder.zext(builder.bitcast(b, mask), i64) for b in (fell, out))
        return builder.or_(fell, builder.shl(out, ir.Constant(i64, LANES)))

    return sig, codegen


@overload(dat_lanes)
def _dat_lanes_compiled(records, i, t, x, y, p, hi, prev, w, h):  # type: ignore[no-untyped-def]
    if any(a.layout != "C" for a in (records, t, x, y, p)):  # the vector loads and stores need them
        return dat_lanes
    return lambda records, i, t, x, y, p, hi, prev, w, h: _dat_lanes_ir(records, i, t, x, y, p, hi, prev, w, h)


@njit(cache=True, nogil=True, inline="always")
def _dat_few(r, a, b, to, xo, yo, po, hi, prev, wl, hl):  # type: ignore[no-untyped-def]
    """Records ``a .. b - 1`` of ``r`` one by one, as :func:`dat_lanes`
    decodes 16: returns its mask (the falls in bit 0, any outside in bit
    16) and the last raw time."""
    flags = np.int64(0)
    for e in range(a, b):
        raw = np.int64(r[e] & np.uint64(0xFFFFFFFF))
        d = np.uint32(r[e] >> np.uint64(32))
        xq = np.uint16(d & np.uint32(0x3FFF))
        yq = np.uint16((d >> np.uint32(14)) & np.uint32(0x3FFF))
        to[e] = hi + raw
        xo[e] = xq
        yo[e] = yq
        po[e] = np.int8((d >> np.uint32(28)) != 0) * np.int8(2) - np.int8(1)
        flags |= np.int64(raw < prev) | (np.int64(xq >= wl or yq >= hl) << LANES)
        prev = raw
    return flags, prev


@njit(cache=True, nogil=True)
def decode_dat_within(records, k, state, t, x, y, p, at, w, h):  # type: ignore[no-untyped-def]
    """:func:`._kernels.decode_dat` of ``records[:k]`` into the columns
    from index ``at`` (the same events and state), returning ``(k, ok)``:
    ``ok`` when no time fell (the first compared with the previous call's
    last) and every x is below ``w`` and y below ``h``
    (:meth:`EventAssembler.commit`'s bounds, as ``(ok, 0, 0)``; ``w`` and
    ``h`` at most 65536).

    ``records`` may be ``t[at:at + k]`` itself (viewed as uint64): each
    record is read before its time is written, and where a block's times
    are unrolled again only their low 32 bits, the raw time, are read back
    (the DAT reader decodes in place, see ``DatSource._events``).

    Per block of 4096 records, :func:`dat_lanes` 16 at a time as if no
    time wrapped, then, when a time fell or they rose by more than half
    the 32-bit range, the times unrolled again one by one
    (:func:`._kernels.dat_unroll`)."""
    wraps = state[0]
    last = state[1]
    have = state[2]
    wl = min(w, 65535)  # 14-bit coordinates: 65535 refuses none
    hl = min(h, 65535)
    half = np.int64(1) << 31
    ok = True
    i = 0
    while i < k:
        j = min(i + _BLOCK, k)
        r = records[i:j]
        to = t[at + i:at + j]
        xo = x[at + i:at + j]
        yo = y[at + i:at + j]
        po = p[at + i:at + j]
        first = last if have == 1 else np.int64(r[0] & np.uint64(0xFFFFFFFF))
        prev = first
        hi = wraps << 32
        # one by one until the times' column is aligned to 128 bytes (whole cache lines for the lanes' stores)
        q = min(j - i, -np.int64(to.ctypes.data >> 3) & (LANES - 1))
        flags, prev = _dat_few(r, 0, q, to, xo, yo, po, hi, prev, wl, hl)
        while q + LANES <= j - i:
            flags |= dat_lanes(r, q, to, xo, yo, po, hi, prev, wl, hl)
            prev = np.int64(r[q + LANES - 1] & np.uint64(0xFFFFFFFF))
            q += LANES
        few, prev = _dat_few(r, q, j - i, to, xo, yo, po, hi, prev, wl, hl)  # the last few
        flags |= few
        ok = ok and flags >> LANES == 0
        if flags & ((1 << LANES) - 1) or prev - first > half:  # perhaps a wrap: unrolled one by one
            wraps, last, fell = dat_unroll(r, to, wraps, last, have, first)
            ok = ok and fell == 0
        else:
            last = prev
        have = 1
        i = j
    state[0] = wraps
    state[1] = last
    state[2] = have
    return k, ok
