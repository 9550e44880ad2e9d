"""The fast path of the event text parser (:func:`fast_lines`, runs of
plain ``t x y p`` lines read from the places of their non-digits) gives what
the line-by-line parser gives (``parse_lines(..., fast=False)``, the parser
as it was) on any input: the same events, byte offsets, polarity convention,
largest coordinates, bad-line runs and reasons, with and without ``skip``,
for every time unit. Inputs are drawn from a grammar of near-plain lines
(every field's edge: digit counts around the word size and the limits,
separators, signs, CR, blanks, comments, junk), so most lines take the fast
path and the rest fall back to the line-by-line one in the middle of a run."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tectum.sources.files import text
from tectum.sources.files.text import TextSource


def _number(lo: int, hi: int) -> st.SearchStrategy[bytes]:
    """A decimal of lo to hi digits, sometimes with leading zeros."""
    return st.integers(lo, hi).flatmap(lambda k: st.text("0123456789", min_size=k, max_size=k)).map(str.encode)


_TIME = st.one_of(
    st.tuples(_number(1, 18), st.sampled_from([b"", b".", b".5", b".49", b".000000500"])).map(b"".join),
    _number(6, 20),  # integers around the word size and the int64 limit
    st.sampled_from([b"-0.5", b"+1.25", b".5", b"9223372036854.775807", b"9223372036855", b"1e3"]),
)
_COORD = st.one_of(_number(4, 7), st.sampled_from([b"65535", b"65536", b"-1", b"1.0", b"1.5", b"+3"]))
_POL = st.sampled_from([b"0", b"1", b"-1", b"+1", b"2", b"01", b"1.0", b"-0", b""])
_ODD_SEP = st.sampled_from([b"  ", b", ", b" ,", b"\t "])
_END = st.sampled_from([b"\r\n", b" \n", b"\t\r\n", b"\r"])


@st.composite
def _line(draw: st.DrawFn, sep: bytes, pols: tuple[bytes, bytes]) -> bytes:
    """The plain form with the file's separator and polarities, its places
    0 to 12 (around the 6 of µs and the 8 of a word); one line in three
    with a part of another form: a field, a separator, the start or the end."""
    part = draw(st.integers(0, 26)) - 18  # 0 to 8: that part of another form (the simplest line is plain)

    t = draw(_TIME) if part == 0 else draw(st.tuples(_number(1, 3), st.just(b"."), _number(0, 12)).map(b"".join))
    x, y = (draw(_COORD) if part == k else draw(_number(1, 3)) for k in (1, 2))
    p = draw(_POL) if part == 3 else draw(st.sampled_from(pols))
    seps = [draw(_ODD_SEP) if part == k else sep for k in (4, 5, 6)]
    return (b" " if part == 7 else b"") + t + seps[0] + x + seps[1] + y + seps[2] + p + (
        draw(_END) if part == 8 else b"\n")


_OTHER = st.sampled_from([b"# comment 1 2 3\n", b"%x\n", b"\n", b"   \n", b"t x y p\n", b"0.1 2 3\n",
                          b"0.1 2 3 1 4\n", b"0.1 2 3 1 # c\n", b"\xff\xfe 1 2 1\n", b"0.1 2 3 1\x00\n"])
_LINES = st.tuples(st.sampled_from([b" ", b",", b"\t"]), st.sampled_from([(b"0", b"1"), (b"-1", b"1")])).flatmap(
    lambda f: st.lists(st.one_of(*[_line(*f)] * 20, _OTHER), min_size=1, max_size=100))


def _parse(raw: bytes, digits: int, skip: bool, fast: bool) -> tuple[object, ...]:
    buf = np.frombuffer(raw, np.uint8)
    cap = buf.shape[0] // 2 + 2
    cols = [np.zeros(cap, d) for d in (np.int64, np.uint16, np.uint16, np.int8, np.int64)]
    state = np.zeros(text._STATE, np.int64)
    bad = np.zeros((3, 3), np.int64)
    n, used, runs, why = text.parse_lines(buf, np.arange(4), digits, state, skip, *cols, bad, fast)
    return (n, used, runs, why, *(c[:n].tolist() for c in cols), state.tolist(), bad[:runs].tolist())


@given(_LINES, st.sampled_from([6, 3, 0]), st.booleans(), st.integers(0, 70), st.sampled_from([1, 4, 16]))
def test_fast_path_equals_the_careful_one(lines: list[bytes], digits: int, skip: bool, pad: int,
                                          repeat: int) -> None:
    """Repeated, so that runs are long enough for the fast path; padded
    after the last newline by a partial line, so runs end at every distance
    from the buffer's end."""
    raw = b"".join(lines) * repeat + b"7" * pad
    assert _parse(raw, digits, skip, True) == _parse(raw, digits, skip, False)


_EDGES = {
    "t": [b"0.5", b"5.", b".5", b"-0.5", b"+1.5", b"12345678.1", b"123456789.1", b"1234567812345678.5",
          b"12345678123456789.5", b"9223372036854.775807", b"9223372036853.999999", b"9223372036854",
          b"9223372036854775807", b"1.0000004999", b"1.0000005", b"1.9999995", b"1.12345678901234567890",
          b"1e3", b"0x10", b"1..5", b"1." + b"5" * 70],  # the last: a line past the 64 bytes of a mask
    "x": [b"", b"0", b"00000", b"000000", b"65535", b"65536", b"99999", b"100000", b"-1", b"+1", b"1.0", b"1.5", b"1a"],
    "p": [b"0", b"1", b"-1", b"+1", b"2", b"01", b"-0", b"1.0", b"", b"-", b"11", b"-2"],
    "sep": [b" ", b",", b"\t", b"  ", b", ", b";", b"\r"],
    "end": [b"\n", b"\r\n", b" \n", b"\r\r\n", b"\r", b"\n\n", b"\x00\n", b" " * 14 + b"\n", b" " * 30 + b"\n"],
}


def _row(pols: tuple[bytes, bytes], k: int = 1, t: bytes = b"0.250000", x: bytes = b"10", y: bytes = b"20",
         p: bytes | None = None, sep: bytes = b" ", end: bytes = b"\n") -> bytes:
    """A plain line, its polarity the second of ``pols`` every third ``k``."""
    return t + sep + x + sep + y + sep + (p if p is not None else pols[k % 3 == 0]) + end


def test_each_odd_field_inside_a_fast_run() -> None:
    """Every edge of every part, on a line (with either polarity of either
    convention) in the middle of a long plain run, read the same both ways."""
    for pols in ((b"1", b"0"), (b"1", b"-1")):
        plain = [_row(pols, k) for k in range(60)]
        for part, values in _EDGES.items():
            for v in values:
                odd = [_row(pols, k, **{part: v}) for k in (1, 3)]  # either polarity of the convention
                if part == "x":
                    odd += [_row(pols, k, y=v) for k in (1, 3)]
                raw = b"".join(plain + odd + plain)
                for digits in (6, 3, 0):
                    for skip in (False, True):
                        assert _parse(raw, digits, skip, True) == _parse(raw, digits, skip, False), (part, v)


@pytest.mark.parametrize("sep", [b" ", b",", b"\t"])
def test_the_fast_path_is_taken_and_rounds_like_the_careful_one(sep: bytes) -> None:
    """A long plain run, with each separator, is read by the fast path
    (nearly all of it: only its last 64 bytes the careful way), with the
    rounding below 1 µs."""
    rows = [(k * 7919 % 100_000_000_000, k % 346, k * 31 % 260, k & 1) for k in range(3000)]
    raw = b"".join(b"%d.%09d%s%d%s%d%s%d\n" % (t // 10**9, t % 10**9, sep, x, sep, y, sep, p) for t, x, y, p in rows)
    fast = _parse(raw, 6, False, True)
    assert fast == _parse(raw, 6, False, False)
    assert fast[4] == [(t + 500) // 1000 for t, *_ in rows]  # ns -> µs, half up
    calls = []
    real = text.fast_lines

    def spy(*a: object) -> tuple[int, int]:
        calls.append(real(*a))
        return calls[-1]

    text.fast_lines = spy  # the kernel's Python form calls the module's global
    try:
        text.parse_lines.py_func(np.frombuffer(raw, np.uint8), np.arange(4), 6, np.zeros(3, np.int64), False,
                                 *[np.zeros(3002, d) for d in (np.int64, np.uint16, np.uint16, np.int8)],
                                 np.empty(0, np.int64), np.zeros((1, 3), np.int64), True)
    finally:
        text.fast_lines = real
    assert calls[0][1] > 2990


def test_reader_gives_the_same_events_either_way(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Through the reader (chunks, sensor pass, packets): a file mixing
    plain runs with comments, CRLF and -1/+1 lines reads the same with the
    fast path switched off."""
    lines = []
    for k in range(4000):
        lines.append(b"%d.%06d%s%d %d %s%s" % (k // 1000, k % 1000 * 997, b"\t" if k % 900 == 5 else b" ", k % 300,
                                               k % 200, b"1" if k % 3 else b"0", b"\r\n" if k % 700 < 3 else b"\n"))
        if k % 1500 == 7:
            lines.append(b"# a comment\n")
    f = tmp_path / "e.txt"
    f.write_bytes(b"".join(lines))

    def read() -> list[list[int]]:
        pk = [q for q in TextSource(str(f), companions=False, chunk_bytes=4096).packets() if len(q)]
        return [np.concatenate([getattr(q, c) for q in pk]).tolist() for c in "txyp"]

    fast = read()
    original = text.parse_lines

    def careful(*a: object) -> object:
        return original(*a, False)

    monkeypatch.setattr(text, "parse_lines", careful)
    assert read() == fast
    assert len(fast[0]) == 4000
