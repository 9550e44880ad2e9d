"""LLVM vector code for the decoders' hot loops, 16 records at a time:
one load, the fields picked out with shuffles and masks, one store per
column (LLVM's own vectorisation of the scalar loops narrows each column
with slower stores). Each compiled form has a plain-Python twin for
``NUMBA_DISABLE_JIT``; :mod:`._dat_kernels` holds the DAT one,
:func:`evt2_lanes` is EVT 2.0's.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

__all__ = ["LANES", "evt2_lanes", "splat"]

#: Records (words) decoded at once.
LANES = 16


def splat(builder, kind, value):  # type: ignore[no-untyped-def]
    """``value`` (an LLVM scalar of type ``kind``) in all :data:`LANES` lanes."""
    vec = ir.VectorType(kind, LANES)
    one = builder.insert_element(ir.Constant(vec, None), value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(one, ir.Constant(vec, None), ir.Constant(ir.VectorType(ir.IntType(32), LANES),
                                                                            [0] * LANES))


def evt2_lanes(words, i, t, x, y, p, base, prev):  # type: ignore[no-untyped-def]
    """Decode the EVT 2.0 CD words ``i .. i + 15`` (all CD_OFF or CD_ON)
    into ``t, x, y, p`` at the same indices: t = ``base`` | the 6-bit time
    (bits 22-27), x bits 11-21, y bits 0-10, p +1 for CD_ON (bit 28), else
    -1. Returns, packed in one int: bits 0-15, bit ``k`` set when word
    ``i + k``'s 6-bit time is below the one before it (``prev`` before the
    first); bits 16-31 the largest x; bits 32-47 the largest y. Compiled,
    vector code (:func:`_evt2_lanes_ir`); this is the plain form."""
    falls = mx = my = 0
    for k in range(LANES):
        w = int(words[i + k])
        low, xk, yk = (w >> 22) & 0x3F, (w >> 11) & 0x7FF, w & 0x7FF
        t[i + k] = base | low
        x[i + k] = xk
        y[i + k] = yk
        p[i + k] = 1 if (w >> 28) & 1 else -1
        falls |= int(low < prev) << k
        mx, my, prev = max(mx, xk), max(my, yk), low
    return falls | (mx << 16) | (my << 32)


@intrinsic
def _evt2_lanes_ir(typingctx, words, i, t, x, y, p, base, prev):  # type: ignore[no-untyped-def]
    sig = types.int64(words, types.intp, t, x, y, p, types.int64, types.int64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        i8, i16, i32, i64 = (ir.IntType(b) for b in (8, 16, 32, 64))
        tys, vals = signature.args[:1] + signature.args[2:6], args[:1] + args[2:6]
        src, to, xo, yo, po = (builder.gep(context.make_array(ty)(context, builder, v).data, [args[1]])
                               for ty, v in zip(tys, vals))

        def const(kind, v):  # type: ignore[no-untyped-def]
            return splat(builder, kind, ir.Constant(kind, v))

        def store(value, ptr):  # type: ignore[no-untyped-def]
            builder.store(value, builder.bitcast(ptr, value.type.as_pointer()), align=1)

        def largest(vec):  # type: ignore[no-untyped-def]
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i16, [vec.type]),
                                                f"llvm.vector.reduce.umax.v{LANES}i16")
            return builder.zext(builder.call(fn, [vec]), i64)

        w = builder.load(builder.bitcast(src, ir.VectorType(i32, LANES).as_pointer()), align=1)
        low = builder.and_(builder.lshr(w, const(i32, 22)), const(i32, 0x3F))
        store(builder.or_(builder.zext(low, ir.VectorType(i64, LANES)), splat(builder, i64, args[6])), to)
        xs = builder.trunc(builder.and_(builder.lshr(w, const(i32, 11)), const(i32, 0x7FF)), ir.VectorType(i16, LANES))
        ys = builder.trunc(builder.and_(w, const(i32, 0x7FF)), ir.VectorType(i16, LANES))
        store(xs, xo)
        store(ys, yo)
        on = builder.icmp_unsigned("!=", builder.and_(w, const(i32, 1 << 28)), const(i32, 0))
        store(builder.select(on, const(i8, 1), const(i8, -1)), po)
        first = builder.insert_element(ir.Constant(ir.VectorType(i32, LANES), None), builder.trunc(args[7], i32),
                                       ir.Constant(i32, 0))
        before = builder.shuffle_vector(first, low, ir.Constant(ir.VectorType(i32, LANES),
                                                                [0] + [LANES + k for k in range(LANES - 1)]))
        falls = builder.zext(builder.bitcast(builder.icmp_unsigned("<", low, before), ir.IntType(LANES)), i64)
        return builder.or_(falls, builder.or_(builder.shl(largest(xs), ir.Constant(i64, 16)),
                                              builder.shl(largest(ys), ir.Constant(i64, 32))))

    return sig, codegen


@overload(evt2_lanes)
def _evt2_lanes_compiled(words, i, t, x, y, p, base, prev):  # type: ignore[no-untyped-def]
    if any(a.layout != "C" for a in (words, t, x, y, p)):  # the vector loads and stores need them
        return evt2_lanes
    return lambda words, i, t, x, y, p, base, prev: _evt2_lanes_ir(words, i, t, x, y, p, base, prev)
