"""The common event text lines parsed from the places of their non-digits.

Most event text files hold one layout line after line: ``t x y p`` with the
time a decimal (``0.003811000 96 133 0``, the RPG ``events.txt``) or an
integer (µs CSV). In such a line every byte is a digit except a few at known
places: the time's ``.``, three separators, the polarity's ``-``, a ``\r``
and the newline. :func:`fast_lines` reads 64 bytes at a time from the start
of the next line: one vector load and three compares give the masks of its
non-digits, its newlines and its separators (:func:`masks64`), and each line
ending in those 64 bytes is parsed from its start and its newline, the
non-digits between them read off the mask (``tzcnt``), its separators
checked against theirs. The fields lie between those,
all digits by construction, so each number is converted from one 64-bit word
by a few multiplications (:func:`digits_value`: three for eight digits, two
for a coordinate's four; a short time's whole part, places and rounding place
together, rounded by one division by 10): no loop over its digits, no branch
on its length, and no line waits on the one before but for its start, one
``tzcnt`` away, so the processor overlaps consecutive lines. The line's end
after its last separator (polarity, CR, newline) is one word looked up in a
table of the six it may be.

A line of any other form (a sign on the time, a coordinate of five or more
digits, blanks around a field, a comment, a header, a bad polarity) ends the
run, and the caller parses it the careful way: the fast path decides nothing
the careful one would decide differently (tests/sources/files/test_text_fast.py
compares the two on drawn and on edge inputs).

Words are read little-endian (byte ``i`` lowest), each by one unaligned
load (:func:`word`). Each time unit has its own compiled :func:`fast_lines`
(``digits`` a literal), its masks and shifts constants. All word arithmetic is
on uint64 (numba turns uint64 mixed with int64 into float64, so every
constant is a ``np.uint64``).

Numba's cache of :func:`tectum.sources.files.text.parse_lines` holds this
module's code and is keyed on text.py alone: after editing only this file,
delete ``sources/files/__pycache__/text.*.nb?`` (or the tests run the old code).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import config, literally, njit, types
from numba.extending import intrinsic

__all__ = ["REACH", "ctlz", "cttz", "digits_value", "fast_lines", "masks64", "run_value", "word"]

#: Bytes past ``end`` :func:`fast_lines` may read (``buf`` must extend that
#: far): the 64 bytes of the masks from a line's start before ``end``, and
#: a word from its 65th byte.
REACH = 80

_U = np.uint64
_ZEROS = _U(0x3030303030303030)  # "00000000"
_PAIRS = _U(0x00FF00FF00FF00FF)
_QUADS = _U(0x0000FFFF0000FFFF)
_POW10 = np.array([10 ** k for k in range(9)], np.uint64)
#: ``_LOW_BYTES[k]``: a mask of the k lowest bytes of a word (all for 8 to 15)
_LOW_BYTES = np.array([(1 << (8 * k)) - 1 for k in range(8)] + [(1 << 64) - 1] * 8, np.uint64)

if config.DISABLE_JIT:  # plain Python (the coverage run): an intrinsic has no Python form

    def cttz(v):  # type: ignore[no-untyped-def]
        """The number of trailing zero bits of the uint64 ``v`` (64 for 0)."""
        v = int(v)
        return _U((v & -v).bit_length() - 1 if v else 64)

    def ctlz(v):  # type: ignore[no-untyped-def]
        """The number of leading zero bits of the uint64 ``v`` (64 for 0)."""
        return _U(64 - int(v).bit_length())

    def masks64(buf, i, sep):  # type: ignore[no-untyped-def]
        """(mask of the bytes of ``buf[i:i + 64]`` that are no ASCII digit,
        mask of its newlines, mask of its bytes ``sep``): bit j for byte
        ``i + j``."""
        nd = nl = se = 0
        for j, c in enumerate(bytes(buf[i:i + 64])):
            nd |= (not 48 <= c <= 57) << j
            nl |= (c == 10) << j
            se |= (c == sep) << j
        return _U(nd), _U(nl), _U(se)

    def word(buf, i):  # type: ignore[no-untyped-def]
        """``buf[i:i + 8]`` (uint8, ``i >= 0``) as a little-endian uint64."""
        return _U(int.from_bytes(bytes(buf[i:i + 8]), "little"))

else:

    def _zero_bits(which: str):  # type: ignore[no-untyped-def]
        """An intrinsic: the number of ``which`` ("trailing" or "leading")
        zero bits of the uint64 ``v`` (64 for 0), one ``tzcnt`` / ``lzcnt``
        instruction (LLVM's ``cttz`` / ``ctlz``)."""
        emit = "cttz" if which == "trailing" else "ctlz"

        def count(typingctx, v):  # type: ignore[no-untyped-def]
            if not isinstance(v, types.Integer) or v.bitwidth != 64:
                return None

            def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
                return getattr(builder, emit)(args[0], ir.Constant(ir.IntType(1), 0))

            return types.uint64(v), codegen

        count.__doc__ = f"The number of {which} zero bits of the uint64 ``v`` (64 for 0): one instruction."
        return intrinsic(count)

    cttz = _zero_bits("trailing")
    ctlz = _zero_bits("leading")

    @intrinsic
    def masks64(typingctx, buf, i, sep):  # type: ignore[no-untyped-def]
        """(mask of the bytes of ``buf[i:i + 64]`` (uint8, ``i >= 0``) that
        are no ASCII digit, mask of its newlines, mask of its bytes ``sep``
        (an integer 0 to 255)): bit j for byte ``i + j``. One unaligned
        64-byte load, three compares and their bit masks: a few vector
        instructions (LLVM's, for whatever vector width the CPU has)."""
        if (not isinstance(buf, types.Array) or buf.dtype != types.uint8 or not isinstance(i, types.Integer)
                or not isinstance(sep, types.Integer)):
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            data = context.make_array(signature.args[0])(context, builder, value=args[0]).data
            vec = ir.VectorType(ir.IntType(8), 64)
            v = builder.load(builder.bitcast(builder.gep(data, [args[1]]), vec.as_pointer()), align=1)
            digit = builder.sub(v, ir.Constant(vec, [48] * 64))
            other = builder.icmp_unsigned(">", digit, ir.Constant(vec, [9] * 64))
            newline = builder.icmp_unsigned("==", v, ir.Constant(vec, [10] * 64))
            c = builder.trunc(args[2], ir.IntType(8))
            splat = builder.insert_element(ir.Constant(vec, [0] * 64), c, ir.Constant(ir.IntType(32), 0))
            splat = builder.shuffle_vector(splat, splat, ir.Constant(ir.VectorType(ir.IntType(32), 64), [0] * 64))
            seps = builder.icmp_unsigned("==", v, splat)
            bits = [builder.bitcast(m, ir.IntType(64)) for m in (other, newline, seps)]
            return context.make_tuple(builder, signature.return_type, bits)

        return types.UniTuple(types.uint64, 3)(buf, i, sep), codegen

    @intrinsic
    def word(typingctx, buf, i):  # type: ignore[no-untyped-def]
        """``buf[i:i + 8]`` (uint8, ``i >= 0``) as a little-endian uint64:
        one unaligned load, whichever of its bytes the caller uses (eight
        byte loads merged by LLVM come apart again once a constant mask
        leaves some of them unused)."""
        if not isinstance(buf, types.Array) or buf.dtype != types.uint8 or not isinstance(i, types.Integer):
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            data = context.make_array(signature.args[0])(context, builder, value=args[0]).data
            ptr = builder.bitcast(builder.gep(data, [args[1]]), ir.IntType(64).as_pointer())
            return builder.load(ptr, align=1)

        return types.uint64(buf, i), codegen


@njit(cache=True, nogil=True, inline="always")
def run_value(w, k):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The value of the ``k`` (0 to 8) decimal digits in the lowest bytes of
    ``w`` (0 for ``k == 0``; ASCII digits): moved to the word's top (the last
    digit in the highest byte), then pairs, quads and the eight digits
    combined by three multiplications. Any other ``k`` gives a meaningless
    value, never a read past the tables."""
    return digits_value((w - _ZEROS) & _low(k), k)


@njit(cache=True, nogil=True, inline="always")
def _low(k):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The mask of the ``k`` (0 to 8) lowest bytes of a word; one of the
    table's for any other ``k``, a negative one too (one ``and``, no branch)."""
    return _LOW_BYTES[_U(k) & _U(15)]


@njit(cache=True, nogil=True, inline="always")
def _short_value(w, k):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The value of the ``k`` (1 to 4) decimal digits in the lowest bytes of
    ``w`` (ASCII digits, any bytes above them): :func:`run_value` without
    its mask (the shift to the top drops the bytes above, and ``- _ZEROS``
    borrows only upwards) nor its last step (the digits lie in the word's
    upper half, whose value the second step gives)."""
    v = (w - _ZEROS) << ((_U(64) - (_U(k) << _U(3))) & _U(63))
    v = (v * _U(10) + (v >> _U(8))) & _PAIRS
    return (v * _U(1 + (100 << 16))) >> _U(48)


@njit(cache=True, nogil=True, inline="always")
def digits_value(v, k):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The value of the ``k`` (0 to 8) decimal digits in the lowest bytes of
    ``v``, one digit (0 to 9) a byte, the bytes above them 0."""
    v <<= (_U(64) - (_U(k) << _U(3))) & _U(63)
    v = (v * _U(10) + (v >> _U(8))) & _PAIRS
    v = ((v * _U(1 + (100 << 16))) >> _U(16)) & _QUADS
    return (v * _U(1 + (10000 << 32))) >> _U(32)




#: The ends of a plain line after its last separator (the polarity, an
#: optional CR, the newline), each with the polarity convention it needs
#: (0 any, 1 0/1, 2 -1/+1) and whether it is +1
_ENDS = {b"1\n": (0, 1), b"1\r\n": (0, 1), b"0\n": (1, 0), b"0\r\n": (1, 0), b"-1\n": (2, 0), b"-1\r\n": (2, 0)}
#: A multiplier whose top 3 bits of the product tell the six ends apart
_END_HASH = 0x7C65C1E582E2E663


def _end_table() -> np.ndarray:
    """Slot ``(end * _END_HASH mod 2**64) >> 61`` of each end read as a word:
    the word, with its convention at bit 40 and its polarity as an int8 in
    the top byte; 0 in the slots no end takes. The bytes after a line's last
    separator, 1 to 15 of them taken (a tail of 16, 32 or 48 bytes: none), are
    never such a 0 but for none, which falls in slot 0: an end takes it."""
    table = np.zeros(8, np.uint64)
    for e, (need, one) in _ENDS.items():
        v = int.from_bytes(e, "little")
        slot = (v * _END_HASH % (1 << 64)) >> 61
        assert table[slot] == 0, "the multiplier must tell the ends apart"
        table[slot] = v | need << 40 | (1 if one else 255) << 56
    assert table[0], "an end must take the slot of no bytes"
    return table


_END_TABLE = _end_table()


@njit(cache=True, nogil=True)
def fast_lines(buf, i, end, digits, big, state, t, x, y, p, n):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Parse lines of the plain form ``t x y p`` from ``buf[i]`` (a line's
    start) while they come, up to a line ending before ``end`` (``buf``
    readable :data:`REACH` bytes past it), into the columns from index
    ``n`` (one event a line, each ending in a newline). The plain
    form: a time of 1 to 16 whole digits below ``big`` (the largest whole
    part) with an optional ``.`` and places (the first ``digits``, 0 to 6,
    are the µs, the next rounds half up), the run's separator three times
    (the first line's: space, tab or comma), coordinates of 1 to 4 digits (any sensor's below 10000),
    a polarity ``0``, ``1`` or ``-1`` in the convention of ``state[0]`` (as
    in :func:`tectum.sources.files.text.parse_lines`, which sets it on the
    first 0 or -1; ``state[1:3]`` get the largest coordinates, ``state[3]``
    1 if a time is below the one before it, from index ``max(n, 1)``), ``\\n`` or
    ``\\r\\n``, the whole line shorter than 64 bytes.
    Returns (the start of the first line not parsed, n).

    From the start of the next line, 64 bytes: the masks of their non-digits,
    newlines and separators (:func:`masks64`), then each line that ends in them, from
    its start, its newline and the non-digits between. The masks of the 64
    bytes after the last of those newlines are loaded before those lines
    are parsed (they do not wait on them)."""
    literally(digits)  # compiled for each unit: its shifts and masks constants
    scale = np.int64(1)
    for _ in range(digits):
        scale *= 10
    conv = state[0]
    first = n
    ok = True
    base = i
    j = i  # the separator: the first line's after its time (another ends the run)
    while j < end and (buf[j] == 46 or np.uint8(buf[j] - 48) < 10):
        j += 1
    sep = np.int64(buf[j]) if j < end and (buf[j] == 32 or buf[j] == 9 or buf[j] == 44) else np.int64(32)
    if i < end:
        other, lines, seps = masks64(buf, base, sep)
    while ok and i < end:
        if end - base < 64:
            lines &= (_U(1) << _U(end - base)) - _U(1)  # newlines before end only
        if lines == 0:  # no line ends in the 64 bytes (or before end)
            break
        after = base + 64 - np.int64(ctlz(lines))  # past the last newline: the next 64 bytes, loaded first
        other2, lines2, seps2 = masks64(buf, after, sep)
        while lines:
            nl = base + np.int64(cttz(lines))
            lines &= lines - _U(1)
            nd = (other >> _U(i - base)) | _U(1 << 63)  # the non-digits from i on, one at 63 at least
            w = nd
            a = np.int64(cttz(w))  # the first: the time's '.' or the first separator
            w &= w - _U(1)
            b1 = np.int64(cttz(w))
            w &= w - _U(1)
            b2 = np.int64(cttz(w))
            w &= w - _U(1)
            b3 = np.int64(cttz(w))
            dot = buf[_U(i + a)] == 46
            s1 = b1 if dot else a
            s2 = b2 if dot else b1
            s3 = b3 if dot else b2
            # the fields: digits between the marks (values of garbage when ok is False)
            places = s1 - a - 1
            w = word(buf, i + a + 1)  # the places (when dot)
            if dot & (a + digits < 8) & (places > digits):  # the whole part and the places down to 0.1 µs in one word
                m = _low(a)  # the whole part from the word at i, the places from the one at i + 1 (past the '.')
                v = ((word(buf, i) & m) | (word(buf, i + 1) & ~m)) - _ZEROS  # above the digits: garbage, shifted out
                tv = np.int64((digits_value(v, a + digits + 1) + _U(5)) // _U(10))  # half up on its last digit
                ok = (a > 0) & dot
            else:
                frac = (w - _ZEROS) & _low(min(places, digits))  # the places down to 1 µs, then zeros
                if dot & (a + digits <= 8):  # the whole part and the places down to 1 µs in one word
                    v = ((word(buf, i) - _ZEROS) & _low(a)) | (frac << (_U(a << 3) & _U(63)))
                    tv = np.int64(digits_value(v, a + digits))
                    ok = (a > 0) & dot
                else:
                    tv = np.int64(run_value(word(buf, i), min(a, 8)))
                    if a > 8:
                        rest = a - 8 if a < 16 else 8
                        tv = tv * np.int64(_POW10[rest]) + np.int64(run_value(word(buf, i + 8), rest))
                    ok = (a > 0) & (a <= 16) & (tv < big)
                    tv = tv * scale + np.int64(digits_value(frac, digits)) * dot
                # the first place below 1 µs rounds half up
                tv += np.int64(dot & (places > digits) & (((w >> _U(digits << 3)) & _U(255)) >= _U(53)))
            nx = s2 - s1 - 1
            ny = s3 - s2 - 1
            xv = np.int64(_short_value(word(buf, i + s1 + 1), nx))
            yv = np.int64(_short_value(word(buf, i + s2 + 1), ny))
            tail = nl - i - s3  # the bytes after the last separator, the newline's included
            e = word(buf, i + s3 + 1) & _low(tail)
            known = _END_TABLE[(e * _U(_END_HASH)) >> _U(61)]  # the one end e can be: e if it is
            need = np.int64((known >> _U(40)) & _U(3))  # the convention the polarity needs: 0 any, 1 0/1, 2 -1/+1
            top = _U(63 - s3)  # bits 0 to s3 kept; its newline among them unless the separators are before it
            ok &= ((((nd & ~(seps >> _U(i - base))) << top) == ((_U(dot) << _U(a)) << top))  # the '.' alone is
                   & (_U((nx - 1) | (ny - 1)) < _U(4))  # no separator: then the tail is 1 to 63 bytes
                   & ((known & _U(0xFFFFFFFF)) == e)
                   & ((conv | need) != 3))  # not one 0/1 and one -1/+1
            if not ok:
                break
            conv |= need
            o = _U(n)
            t[o] = tv
            x[o] = xv
            y[o] = yv
            p[o] = np.int8(np.uint8(known >> _U(56)))  # +1 or -1
            n += 1
            i = nl + 1
        base = after
        other, lines, seps = other2, lines2, seps2
    # apart (the loop above has registers enough for its own work), on slices in the columns' own types:
    # vectorised (the maxima on int64, element by element: 37 us for 50,000 lines; so: 3 us)
    xs, ys = x[first:n], y[first:n]
    mx, my = np.uint16(0), np.uint16(0)
    for k in range(xs.shape[0]):
        mx = max(mx, xs[k])
        my = max(my, ys[k])
    lo = max(first, 1)
    later = t[lo:max(n, lo)]
    earlier = t[lo - 1:lo - 1 + later.shape[0]]
    down = np.int64(0)  # a count (a sum vectorises)
    for k in range(later.shape[0]):
        down += np.int64(later[k] < earlier[k])
    state[0], state[1], state[2] = conv, max(state[1], np.int64(mx)), max(state[2], np.int64(my))
    if down:
        state[3] = 1
    return i, n
