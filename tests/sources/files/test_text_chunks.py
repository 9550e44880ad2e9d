"""The text reader's ways through a file, against slow obvious references:
any chunk size reads the same events, errors, skips and sensor as one chunk
(pooled buffers, lines across chunks, the sensor pass holding one chunk
without a copy or several with); a last line without its newline reads as
with it, blanks after the last newline as nothing; the sniffer,
``first_lines`` (which read only the first lines of a head) and the time
unit read from the values give what reading every line one by one gives."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from tectum import EventPacket
from tectum.sources.files._text_layout import first_lines, text_layout
from tectum.sources.files.text import TextSource, looks_like_events_text

_ODD = [b"# comment", b"%x", b"", b"   ", b"0.5 1 2", b"0.5 1 2 7", b"-1 2 3 1", b"0.000001 70000 1 1", b"x y"]


@st.composite
def _files(draw: st.DrawFn) -> bytes:
    """Lines of a file: plain events in time order (either polarity
    convention), now and then a comment, a blank or a bad line, maybe a
    header; no final newline (the file's end is drawn apart)."""
    pols = draw(st.sampled_from([(b"0", b"1"), (b"-1", b"1")]))
    lines = [b"t x y p"] if draw(st.booleans()) else []
    t = 0
    for _ in range(draw(st.integers(1, 40))):
        if draw(st.integers(0, 9)) == 0:
            lines.append(draw(st.sampled_from(_ODD)))
            continue
        t += draw(st.integers(0, 3000))
        lines.append(b"%d.%06d %d %d %s" % (t // 10**6, t % 10**6, draw(st.integers(0, 400)),
                                            draw(st.integers(0, 300)), draw(st.sampled_from(pols))))
    return b"\n".join(lines)


def _read(raw: bytes, **kw: object) -> tuple[object, ...]:
    """Events, sensor and skips, or the error, of ``raw`` read as a file."""
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "events.txt"
        f.write_bytes(raw)
        src = TextSource(str(f), companions=False, **kw)  # type: ignore[arg-type]
        try:
            pk = [q for q in src.packets() if isinstance(q, EventPacket) and len(q)]
        except Exception as e:  # noqa: BLE001 - the error is the result compared
            return type(e).__name__, str(e).replace(str(f), "FILE")
        cols = [np.concatenate([getattr(q, c) for q in pk]).tolist() if pk else [] for c in "txyp"]
        return cols, pk[0].sensor if pk else None, src.skipped_events


@given(_files(), st.sampled_from([b"\n", b"", b"\n  ", b"\n\t\x0b\x0c", b"\n\n \r"]),
       st.sampled_from([64, 65, 100, 257, 4096]), st.booleans())
def test_any_chunk_size_and_file_end_read_the_same(body: bytes, end: bytes, chunk: int, skip: bool) -> None:
    ref = _read(body + b"\n", skip_bad=skip)
    assert _read(body + end, skip_bad=skip) == ref
    assert _read(body + end, skip_bad=skip, chunk_bytes=chunk) == ref


_NUM = rb"[+-]?(?:\d+\.?\d*|\.\d+)"
_EVENT_LINE = re.compile(rb"^\s*" + _NUM + rb"(?:[ \t,]+" + _NUM + rb"){2}[ \t,]+(" + _NUM + rb")\s*$")


def _lines_one_by_one(head: bytes, k: int, strip: bool, comments: tuple[bytes, ...]) -> list[bytes]:
    out = []
    for raw in head.split(b"\n")[:-1]:  # the complete lines
        ln = raw.strip()
        if ln and not (ln if strip else raw).startswith(comments):
            out.append(ln if strip else raw)
    return out[:k]


def _sniff_one_by_one(head: bytes) -> bool:
    """The sniffer's rule, line by line: a CSV header may come first, then
    up to 20 lines of 4 numbers whose 4th is 0, 1, -1 or +1 (or one such
    line making the whole of a short head)."""
    if head.startswith(b"# tectum ") and not head.startswith(b"# tectum events"):
        return False
    lines = _lines_one_by_one(head, 21, False, (b"#", b"%"))
    if lines and re.search(rb"[A-Za-z]", lines[0]) and b"," in lines[0]:
        lines = lines[1:]
    if len(lines) < 2:
        return len(lines) == 1 and len(head) < 4096 and bool(_EVENT_LINE.match(lines[0]))
    return all((m := _EVENT_LINE.match(ln)) is not None and m.group(1) in (b"0", b"1", b"-1", b"+1")
               for ln in lines[:20])


_NUMBER = st.sampled_from([b"0", b"12", b"0.5", b".5", b"1.", b"+3", b"-2"])
_POLARITY = st.sampled_from([b"0", b"1", b"-1", b"+1"])
_SEP = st.sampled_from([b" ", b"\t", b",", b", "])
_BLANK = st.sampled_from([b"", b" ", b"\t", b"\r", b" \x0c"])
_ODD_FIELD = st.sampled_from([b"-0", b"+0", b"01", b"2", b"1.0", b"", b"1e3", b"x", b"+-1"])
_ODD_SEP = st.sampled_from([b";", b"\r", b"\x0b", b""])


@st.composite
def _heads(draw: st.DrawFn) -> bytes:
    """Lines of event text the sniffer takes, maybe a CSV header, comments
    and blanks among them, and maybe one line with a part of another form
    (a field, a separator, a fifth field, a comment's mark)."""
    lines = []
    for _ in range(draw(st.integers(0, 24))):
        f = [draw(_NUMBER), draw(_NUMBER), draw(_NUMBER), draw(_POLARITY)]
        lines.append(draw(_BLANK) + draw(_SEP).join(f) + draw(_BLANK))
        if draw(st.integers(0, 9)) == 0:
            lines.append(draw(st.sampled_from([b"# c", b"%c", b"", b"  ", b"\r", b"\x0b"])))
    if lines and draw(st.booleans()):
        f = [draw(_NUMBER), draw(_NUMBER), draw(_NUMBER), draw(_POLARITY), b"1"][:draw(st.integers(3, 5))]
        f[draw(st.sampled_from([3 % len(f), draw(st.integers(0, len(f) - 1))]))] = draw(_ODD_FIELD)
        odd = draw(st.one_of(_SEP, _SEP, _ODD_SEP)).join(f)
        lines.insert(draw(st.integers(0, len(lines))), draw(st.sampled_from([b"", b"t x y p", b"%"])) + odd)
    if draw(st.booleans()):
        lines.insert(0, draw(st.sampled_from([b"t,x,y,p", b"t x y p", b"# tectum events", b"# tectum imu"])))
    return b"\n".join(lines)


_EDGES = [b"0 0 0 %s\n0.5 1 2 1\n" % p for p in (b"0", b"1", b"-1", b"+1", b"-0", b"+0", b"01", b"2", b"1.0", b"1e3")]


@given(st.one_of(_heads(), st.sampled_from(_EDGES)), st.booleans())
def test_sniffer_and_first_lines_equal_reading_line_by_line(lines: bytes, newline: bool) -> None:
    head = lines + (b"\n" if newline else b"")
    assert looks_like_events_text(head) == _sniff_one_by_one(head)
    for k in (0, 1, 3, 21):
        for strip in (True, False):
            for comments in ((b"#", b"%"), (b"#",)):
                assert first_lines(head, k, strip=strip, comments=comments) == _lines_one_by_one(
                    head, k, strip, comments)


def _unit_one_by_one(head: bytes) -> str:
    """The time unit the first column's values say (no header): seconds
    for decimals or no values, ns for 18 digits and more, else µs."""
    lines = _lines_one_by_one(head, 20, True, (b"#", b"%"))
    times = [re.split(rb"[ \t,;]+", ln)[0] for ln in lines]
    if not times or any(b"." in v for v in times):
        return "s"
    return "ns" if max(len(v.lstrip(b"+-")) for v in times) >= 18 else "us"


_TIMES = st.sampled_from([b"12", b"0.5", b"", b"+3", b"-7", b"123456789012345678", b"12345678901234567", b"1\r2", b"."])


@given(st.lists(st.tuples(_TIMES, _SEP, st.sampled_from([b"", b" ", b"#", b"%"])), max_size=25), st.booleans())
def test_time_unit_from_the_values_equals_reading_line_by_line(rows: list[tuple[bytes, bytes, bytes]],
                                                               newline: bool) -> None:
    head = b"\n".join(lead + t + sep + b"1" + sep + b"2" for t, sep, lead in rows) + (b"\n" if newline else b"")
    assert text_layout(head).time_unit == _unit_one_by_one(head)
