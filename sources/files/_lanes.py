"""LLVM vector code for the decoders' hot loops, 16 records at a time:
one load, the fields picked out with shuffles and masks, one store per
column (LLVM's own vectorisation of the scalar loops narrows each column
with slower stores). Each compiled form has a plain-Python twin for
``NUMBA_DISABLE_JIT``; :mod:`._dat_kernels` holds the DAT one,
:func:`evt2_group` is EVT 2.0's.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

__all__ = ["LANES", "evt2_group", "splat"]

#: Records (words) decoded at once.
LANES = 16


def splat(builder, kind, value):  # type: ignore[no-untyped-def]
    """``value`` (an LLVM scalar of type ``kind``) in all :data:`LANES` lanes."""
    vec = ir.VectorType(kind, LANES)
    one = builder.insert_element(ir.Constant(vec, None), value, ir.Constant(ir.IntType(32), 0))
    return builder.shuffle_vector(one, ir.Constant(vec, None), ir.Constant(ir.VectorType(ir.IntType(32), LANES),
                                                                            [0] * LANES))


def _cd_words(builder, src, base, to, xo, yo, po):  # type: ignore[no-untyped-def]
    """:func:`evt2_group`'s codegen of the columns: load the 16 words at ``src``,
    write each as a CD word to the columns at ``to, xo, yo, po`` (t =
    ``base`` | bits 22-27, x bits 11-21, y bits 0-10, p +1 where bit 28 is
    set, else -1); returns the words and their 6-bit times, x and y."""
    i8, i16, i32, i64 = (ir.IntType(b) for b in (8, 16, 32, 64))

    def const(kind, v):  # type: ignore[no-untyped-def]
        return splat(builder, kind, ir.Constant(kind, v))

    def store(value, ptr):  # type: ignore[no-untyped-def]
        builder.store(value, builder.bitcast(ptr, value.type.as_pointer()), align=1)

    w = builder.load(builder.bitcast(src, ir.VectorType(i32, LANES).as_pointer()), align=1)
    low = builder.and_(builder.lshr(w, const(i32, 22)), const(i32, 0x3F))
    store(builder.or_(builder.zext(low, ir.VectorType(i64, LANES)), splat(builder, i64, base)), to)
    xs = builder.trunc(builder.and_(builder.lshr(w, const(i32, 11)), const(i32, 0x7FF)), ir.VectorType(i16, LANES))
    ys = builder.trunc(builder.and_(w, const(i32, 0x7FF)), ir.VectorType(i16, LANES))
    store(xs, xo)
    store(ys, yo)
    on = builder.icmp_unsigned("!=", builder.and_(w, const(i32, 1 << 28)), const(i32, 0))
    store(builder.select(on, const(i8, 1), const(i8, -1)), po)
    return w, low, xs, ys


#: EVT 2.0 words below this are CD_OFF / CD_ON (types 0x0 and 0x1).
CD_END = 0x20000000


def evt2_group(words, i, t, x, y, p, n, base, prev):  # type: ignore[no-untyped-def]
    """Decode the EVT 2.0 words ``i .. i + 15`` as CD words into ``t, x,
    y, p`` at ``n .. n + 15`` (t = ``base`` | the 6-bit time, bits 22-27; x bits
    11-21, y bits 0-10; p +1 for CD_ON, bit 28, else -1; every lane written),
    of which the first ``j`` are events: ``j`` is the number of CD words
    (CD_OFF, CD_ON) before the first other word, 16 when all are CD.
    Returns, packed in one int: bits 0-7 ``j``; bits 8-15 how many of
    those ``j`` have a 6-bit time below the one before them (``prev``
    before the first: 64 makes the first fall, 0 never); bits 16-31 their
    largest x, bits 32-47 their largest y (0 when ``j`` is 0). The lanes
    past ``j`` hold garbage for the caller to overwrite: it goes on at word
    ``i + j`` and column index ``n + j``. Compiled, vector code
    (:func:`_evt2_group_ir`); this is the plain form."""
    j = 0
    while j < LANES and int(words[i + j]) < CD_END:
        j += 1
    falls = mx = my = 0
    for k in range(LANES):
        w = int(words[i + k])
        low, xk, yk = (w >> 22) & 0x3F, (w >> 11) & 0x7FF, w & 0x7FF
        t[n + k] = base | low
        x[n + k] = xk
        y[n + k] = yk
        p[n + k] = 1 if (w >> 28) & 1 else -1
        if k < j:
            falls += int(low < prev)
            mx, my = max(mx, xk), max(my, yk)
        prev = low
    return j | (falls << 8) | (mx << 16) | (my << 32)


@intrinsic
def _evt2_group_ir(typingctx, words, i, t, x, y, p, n, base, prev):  # type: ignore[no-untyped-def]
    sig = types.int64(words, types.intp, t, x, y, p, types.intp, types.int64, types.int64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        i16, i32, i64 = (ir.IntType(b) for b in (16, 32, 64))
        mask = ir.IntType(LANES)
        arrays = [context.make_array(ty)(context, builder, v)
                  for ty, v in zip(signature.args[:1] + signature.args[2:6], args[:1] + args[2:6])]
        src = builder.gep(arrays[0].data, [args[1]])
        to, xo, yo, po = (builder.gep(a.data, [args[6]]) for a in arrays[1:])

        def const(kind, v):  # type: ignore[no-untyped-def]
            return splat(builder, kind, ir.Constant(kind, v))

        def call(name, ret, *vals):  # type: ignore[no-untyped-def]
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ret, [v.type for v in vals]), name)
            return builder.call(fn, list(vals))

        w, low, xs, ys = _cd_words(builder, src, args[7], to, xo, yo, po)
        # j: the CD words before the first other one (bit 16 set: 16 when all are CD)
        cd = builder.zext(builder.bitcast(builder.icmp_unsigned("<", w, const(i32, CD_END)), mask), i32)
        j = call("llvm.cttz.i32", i32, builder.or_(builder.xor(cd, ir.Constant(i32, 0xFFFF)),
                                                     ir.Constant(i32, 1 << LANES)), ir.Constant(ir.IntType(1), 0))
        valid = builder.bitcast(builder.trunc(builder.sub(builder.shl(ir.Constant(i32, 1), j), ir.Constant(i32, 1)),
                                              mask), ir.VectorType(ir.IntType(1), LANES))
        first = builder.insert_element(ir.Constant(ir.VectorType(i32, LANES), None), builder.trunc(args[8], i32),
                                       ir.Constant(i32, 0))
        before = builder.shuffle_vector(first, low, ir.Constant(ir.VectorType(i32, LANES),
                                                                [0] + [LANES + k for k in range(LANES - 1)]))
        fell = builder.and_(builder.icmp_unsigned("<", low, before), valid)
        falls = call("llvm.ctpop.i32", i32, builder.zext(builder.bitcast(fell, mask), i32))
        zero = const(i16, 0)

        def largest(vec):  # type: ignore[no-untyped-def]
            kept = builder.select(valid, vec, zero)
            return builder.zext(call(f"llvm.vector.reduce.umax.v{LANES}i16", i16, kept), i64)

        out = builder.or_(builder.zext(j, i64), builder.shl(builder.zext(falls, i64), ir.Constant(i64, 8)))
        return builder.or_(out, builder.or_(builder.shl(largest(xs), ir.Constant(i64, 16)),
                                            builder.shl(largest(ys), ir.Constant(i64, 32))))

    return sig, codegen


@overload(evt2_group)
def _evt2_group_compiled(words, i, t, x, y, p, n, base, prev):  # type: ignore[no-untyped-def]
    if any(a.layout != "C" for a in (words, t, x, y, p)):  # the vector loads and stores need them
        return evt2_group
    return lambda words, i, t, x, y, p, n, base, prev: _evt2_group_ir(words, i, t, x, y, p, n, base, prev)
