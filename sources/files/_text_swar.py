"""The common event text lines parsed from the places of their non-digits.

Most event text files hold one layout line after line: ``t x y p`` with the
time a decimal (``0.003811000 96 133 0``, the RPG ``events.txt``) or an
integer (µs CSV). In such a line every byte is a digit except a few at known
places: the time's ``.``, three separators, the polarity's ``-``, a ``\r``
and the newline. :func:`fast_lines` takes a window of a few kB at a time:
first the masks of its non-digits and of its newlines, 64 bytes to a 64-bit
word (a loop LLVM vectorises), and the list of its newlines; then each line
from its start and its newline, the non-digits between them read off the
mask (``tzcnt``). The fields lie between those, all digits by construction,
so each number is converted from one 64-bit word by three multiplications
(:func:`digits_value`): no loop over its digits, no branch on its length,
and no line waits on the one before (its start comes from the list), so the
processor overlaps consecutive lines.

A line of any other form (a sign on the time, a coordinate of six or more
digits, blanks around a field, a comment, a header, a bad polarity) ends the
run, and the caller parses it the careful way: the fast path decides nothing
the careful one would decide differently (tests/sources/files/test_text_fast.py
compares the two on drawn and on edge inputs).

Words are read little-endian (byte ``i`` lowest): LLVM turns the eight
byte loads of :func:`word` into one unaligned load. All word arithmetic is
on uint64 (numba turns uint64 mixed with int64 into float64, so every
constant is a ``np.uint64``).

Numba's cache of :func:`tectum.sources.files.text.parse_lines` holds this
module's code and is keyed on text.py alone: after editing only this file,
delete ``sources/files/__pycache__/text.*.nb?`` (or the tests run the old code).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import config, njit, types
from numba.extending import intrinsic

__all__ = ["REACH", "cttz", "digits_value", "fast_lines", "marks_and_newlines", "popcount", "run_value", "scratch",
           "word"]

#: Bytes past ``end`` :func:`fast_lines` may read (the marks of the last
#: 64 bytes: ``buf`` must extend that far).
REACH = 64
_SPAN = 4096  # bytes of the window fast_lines marks at a time

_U = np.uint64
_ZEROS = _U(0x3030303030303030)  # "00000000"
_PAIRS = _U(0x00FF00FF00FF00FF)
_QUADS = _U(0x0000FFFF0000FFFF)
_POW10 = np.array([10 ** k for k in range(9)], np.uint64)
#: ``_LOW_BYTES[k]``: a mask of the k lowest bytes of a word
_LOW_BYTES = np.array([(1 << (8 * k)) - 1 for k in range(8)] + [(1 << 64) - 1], np.uint64)

if config.DISABLE_JIT:  # plain Python (the coverage run): an intrinsic has no Python form

    def cttz(v):  # type: ignore[no-untyped-def]
        """The number of trailing zero bits of the uint64 ``v`` (64 for 0)."""
        v = int(v)
        return _U((v & -v).bit_length() - 1 if v else 64)

    def popcount(v):  # type: ignore[no-untyped-def]
        """The number of one bits of the uint64 ``v``."""
        return _U(bin(int(v)).count("1"))

else:

    @intrinsic
    def cttz(typingctx, v):  # type: ignore[no-untyped-def]
        """The number of trailing zero bits of the uint64 ``v`` (64 for 0):
        one ``tzcnt`` instruction."""
        if not isinstance(v, types.Integer) or v.bitwidth != 64:
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            return builder.cttz(args[0], ir.Constant(ir.IntType(1), 0))

        return types.uint64(v), codegen

    @intrinsic
    def popcount(typingctx, v):  # type: ignore[no-untyped-def]
        """The number of one bits of the uint64 ``v``: one ``popcnt`` instruction."""
        if not isinstance(v, types.Integer) or v.bitwidth != 64:
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            return builder.ctpop(args[0])

        return types.uint64(v), codegen


@njit(cache=True, nogil=True, inline="always")
def word(buf, i):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """``buf[i:i + 8]`` (uint8, ``i >= 0``) as a little-endian uint64."""
    k = _U(i)
    return (_U(buf[k]) | (_U(buf[k + _U(1)]) << _U(8)) | (_U(buf[k + _U(2)]) << _U(16))
            | (_U(buf[k + _U(3)]) << _U(24)) | (_U(buf[k + _U(4)]) << _U(32)) | (_U(buf[k + _U(5)]) << _U(40))
            | (_U(buf[k + _U(6)]) << _U(48)) | (_U(buf[k + _U(7)]) << _U(56)))


@njit(cache=True, nogil=True, inline="always")
def run_value(w, k, have=8):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The value of the ``k`` (0 to 8) decimal digits in the lowest bytes of
    ``w`` (0 for ``k == 0``), of which only the first ``have`` are there (ASCII
    digits; those after count as 0): moved to the word's top (the last digit in
    the highest byte), then pairs, quads and the eight digits combined by three
    multiplications."""
    return digits_value((w - _ZEROS) & _LOW_BYTES[_U(min(k, have))], k)


@njit(cache=True, nogil=True, inline="always")
def digits_value(v, k):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The value of the ``k`` (0 to 8) decimal digits in the lowest bytes of
    ``v``, one digit (0 to 9) a byte, the bytes above them 0."""
    v <<= (_U(64) - (_U(k) << _U(3))) & _U(63)
    v = (v * _U(10) + (v >> _U(8))) & _PAIRS
    v = ((v * _U(1 + (100 << 16))) >> _U(16)) & _QUADS
    return (v * _U(1 + (10000 << 32))) >> _U(32)


@njit(cache=True, nogil=True, inline="always")
def marks_and_newlines(buf, at):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Masks of the bytes of ``buf[at:at + 64]`` that are no ASCII digit and
    of its newlines (bit j for byte ``at + j``), in one vectorised loop."""
    marks = _U(0)
    lines = _U(0)
    for j in range(64):
        c = buf[np.uint64(at + j)]
        marks |= _U((c < 48) | (c > 57)) << _U(j)
        lines |= _U(c == 10) << _U(j)
    return marks, lines


@njit(cache=True, nogil=True, inline="always")
def _blank(c):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    return (c == 32) | (c == 9) | (c == 44)


@njit(cache=True, nogil=True)
def scratch():  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The room :func:`fast_lines` needs (marks, ends): made once per buffer, not per call."""
    return np.empty(_SPAN // 64 + 2, np.uint64), np.empty(_SPAN + 4, np.int64)


@njit(cache=True, nogil=True)
def fast_lines(buf, i, end, digits, big, state, t, x, y, p, n, where, marks, ends):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Parse lines of the plain form ``t x y p`` from ``buf[i]`` (a line's
    start) while they come, up to a line ending before ``end`` (``buf``
    readable :data:`REACH` bytes past it), into the columns from index
    ``n`` (``where`` gets the line offsets unless it is empty). The plain
    form: a time of 1 to 16 whole digits below ``big`` (the largest whole
    part) with an optional ``.`` and places (the first ``digits``, 0 to 6,
    are the µs, the next rounds half up), one separator (space, tab or
    comma, the same three times), coordinates of 1 to 5 digits up to 65535,
    a polarity ``0``, ``1`` or ``-1`` in the convention of ``state[0]`` (as
    in :func:`tectum.sources.files.text.parse_lines`, which sets it on the
    first 0 or -1; ``state[1:3]`` get the largest coordinates), ``\\n`` or
    ``\\r\\n``, the whole line shorter than 64 bytes. ``marks`` (uint64)
    and ``ends`` (int64) are room for the window, of :func:`scratch`.
    Returns (the start of the first line not parsed, n).

    A window of up to :data:`_SPAN` bytes at a time: first the masks of its
    non-digits and the list of its newlines, then its lines, each from its
    start and newline (so no line waits on the one before) and the
    non-digits between them."""
    scale = np.int64(1)
    for _ in range(digits):
        scale *= 10
    track = where.shape[0] > 0
    conv, xmax, ymax = state[0], state[1], state[2]
    ok = True
    span = 256  # the window grows while its lines are all plain: an odd line soon after costs little
    while ok:
        base = i
        lim = min(base + span, end)
        span = min(2 * span, _SPAN)
        words = (lim - base + 63) >> 6
        k = np.int64(0)
        for b in range(words):
            at = base + 64 * b
            marks[b], bits = marks_and_newlines(buf, at)
            if b == words - 1:
                bits &= (_U(2) << _U(lim - at - 1)) - _U(1)  # newlines before lim only
            count = np.int64(popcount(bits))
            for j in range(4):  # the usual few whatever their number: no branch to mispredict
                ends[k + j] = at + np.int64(cttz(bits))
                bits &= bits - _U(1)
            k += 4
            while bits:
                ends[k] = at + np.int64(cttz(bits))
                k += 1
                bits &= bits - _U(1)
            if count < 4:
                k += count - 4
        marks[words] = 0
        if k == 0:
            break
        for li in range(k):
            nl = ends[np.uint64(li)]
            off = _U(i - base)
            wi = off >> _U(6)
            sh = off & _U(63)
            w = (marks[wi] >> sh) | ((marks[wi + _U(1)] << _U(1)) << (_U(63) - sh))  # the marks from i on
            size = nl - i  # the newline's offset
            a = np.int64(cttz(w))  # the first: the time's '.' or the first separator
            w &= w - _U(1)
            b1 = np.int64(cttz(w))
            w &= w - _U(1)
            b2 = np.int64(cttz(w))
            w &= w - _U(1)
            b3 = np.int64(cttz(w))
            dot = buf[np.uint64(i + a)] == 46
            s1 = b1 if dot else a
            s2 = b2 if dot else b1
            s3 = b3 if dot else b2
            minus = buf[np.uint64(i + s3 + 1)] == 45  # the polarity's '-'
            cr = buf[np.uint64(nl - 1)] == 13
            # the fields: digits between the marks (values of garbage when ok is False)
            places = s1 - a - 1
            w = word(buf, i + a + 1)  # the places (when dot)
            if dot and a + digits <= 8:  # the whole part and the places down to 1 µs in one word
                v = (word(buf, i) - _ZEROS) & _LOW_BYTES[_U(a if a < 8 else 8)]
                v |= ((w - _ZEROS) & _LOW_BYTES[_U(min(places, digits))]) << (_U(a << 3) & _U(63))
                tv = np.int64(digits_value(v, a + digits))
                ok = (a > 0) & (size < 64)
            else:
                tv = np.int64(run_value(word(buf, i), min(a, 8)))
                if a > 8:
                    rest = a - 8 if a < 16 else 8
                    tv = tv * np.int64(_POW10[rest]) + np.int64(run_value(word(buf, i + 8), rest))
                ok = (a > 0) & (a <= 16) & (tv < big) & (size < 64)
                tv *= scale
                if dot:
                    tv += np.int64(run_value(w, digits, places))  # the places down to 1 µs
            # the first place below 1 µs rounds half up
            tv += np.int64(dot & (places > digits) & (((w >> _U(digits << 3)) & _U(255)) >= _U(53)))
            sep = buf[np.uint64(i + s1)]
            nx = s2 - s1 - 1
            xv = np.int64(run_value(word(buf, i + s1 + 1), min(nx, 8)))
            ny = s3 - s2 - 1
            yv = np.int64(run_value(word(buf, i + s2 + 1), min(ny, 8)))
            pc = buf[np.uint64(nl - 1 - cr)]
            one = np.int64(pc == 49)
            neg = np.int64(minus)
            need = 2 * neg + (1 - one) * (1 - neg)  # the convention the polarity needs: 0 any, 1 0/1, 2 -1/+1
            ok &= (_blank(sep) & (buf[np.uint64(i + s2)] == sep) & (buf[np.uint64(i + s3)] == sep)
                   & (nx > 0) & (nx <= 5) & (ny > 0) & (ny <= 5) & (xv <= 65535) & (yv <= 65535)
                   & (size - s3 - 1 - np.int64(cr) == 1 + neg) & ((one == 1) | ((pc == 48) & (neg == 0)))
                   & ((need == 0) | (conv == 0) | (conv == need)))
            if not ok:
                break
            conv += need * np.int64(conv == 0)
            o = np.uint64(n)
            t[o] = tv
            x[o] = xv
            y[o] = yv
            p[o] = 2 * one * (1 - neg) - 1
            xmax = max(xmax, xv)
            ymax = max(ymax, yv)
            if track:
                where[o] = i
            n += 1
            i = nl + 1
    state[0], state[1], state[2] = conv, xmax, ymax
    return i, n
