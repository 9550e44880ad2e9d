"""LZ4 block decompression callable from numba kernels.

The ``lz4`` package (the ``aedat4`` extra) compiles liblz4 into its
``lz4.block._block`` extension, which exports ``LZ4_decompress_safe`` and
``LZ4_decompress_safe_usingDict``. Their addresses are registered with LLVM
under :data:`SYMBOL` and :data:`SYMBOL_DICT`, and :func:`decompress_safe`
and :func:`decompress_safe_dict` call them by those names, so kernels using
them can be cached (the cached code names the symbols, not addresses).
Without the package, or without the exports, or with numba's JIT disabled
(``NUMBA_DISABLE_JIT=1``: an intrinsic has no Python form), :data:`AVAILABLE`
is False and callers decompress from Python instead; a kernel calling these
must then never run.

The functions never read or write outside the given ranges, whatever the
input: they return the bytes written, or a negative number for a malformed
block (or one that does not fit).
"""

from __future__ import annotations

import ctypes

import llvmlite.binding as llvm
from llvmlite import ir
from numba import config, types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["AVAILABLE", "SYMBOL", "SYMBOL_DICT", "decompress_safe", "decompress_safe_dict"]

#: The names the liblz4 functions are registered under.
SYMBOL = "tectum_LZ4_decompress_safe"
SYMBOL_DICT = "tectum_LZ4_decompress_safe_usingDict"


def _addresses() -> tuple[int, int] | None:
    try:
        from lz4.block import _block
        lib = ctypes.CDLL(_block.__file__)
        return tuple(ctypes.cast(getattr(lib, f), ctypes.c_void_p).value  # type: ignore[return-value]
                     for f in ("LZ4_decompress_safe", "LZ4_decompress_safe_usingDict"))
    except (ImportError, OSError, AttributeError):
        return None


_ADDRESSES = _addresses()
if _ADDRESSES and all(_ADDRESSES):
    llvm.add_symbol(SYMBOL, _ADDRESSES[0])
    llvm.add_symbol(SYMBOL_DICT, _ADDRESSES[1])

#: True when :func:`decompress_safe` and :func:`decompress_safe_dict` may be called.
AVAILABLE = bool(_ADDRESSES and all(_ADDRESSES)) and not config.DISABLE_JIT


def _call(context, builder, signature, args, symbol, extra):  # type: ignore[no-untyped-def]
    """Call ``symbol(src + src_start, dst + dst_start, src_len, dst_cap,
    [dst + dict_start, dict_len])`` (int32 lengths), as int64."""
    i8p = ir.IntType(8).as_pointer()
    i32 = ir.IntType(32)
    s = context.make_array(signature.args[0])(context, builder, args[0])
    d = context.make_array(signature.args[3])(context, builder, args[3])
    sp = builder.gep(builder.bitcast(s.data, i8p), [args[1]])
    dp = builder.gep(builder.bitcast(d.data, i8p), [args[4]])
    argv = [sp, dp, builder.trunc(args[2], i32), builder.trunc(args[5], i32)]
    types_ = [i8p, i8p, i32, i32]
    if extra:
        argv += [builder.gep(builder.bitcast(d.data, i8p), [args[6]]), builder.trunc(args[7], i32)]
        types_ += [i8p, i32]
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i32, types_), symbol)
    return builder.sext(builder.call(fn, argv), ir.IntType(64))


@intrinsic
def decompress_safe(typingctx, src, src_start, src_len, dst, dst_start, dst_cap):  # type: ignore[no-untyped-def]
    """``LZ4_decompress_safe(src + src_start, dst + dst_start, src_len,
    dst_cap)`` on uint8 arrays (the caller checks the ranges lie inside
    them; lengths below 2**31)."""
    sig = types.int64(src, types.int64, types.int64, dst, types.int64, types.int64)
    return sig, lambda c, b, sg, a: _call(c, b, sg, a, SYMBOL, False)


@intrinsic
def decompress_safe_dict(typingctx, src, src_start, src_len, dst, dst_start, dst_cap,  # type: ignore[no-untyped-def]
                         dict_start, dict_len):
    """``LZ4_decompress_safe_usingDict``: as :func:`decompress_safe`, the
    block referring back to ``dst[dict_start:dict_start + dict_len]`` (the
    output of the blocks before it in a linked LZ4 frame)."""
    sig = types.int64(src, types.int64, types.int64, dst, types.int64, types.int64, types.int64, types.int64)
    return sig, lambda c, b, sg, a: _call(c, b, sg, a, SYMBOL_DICT, True)
