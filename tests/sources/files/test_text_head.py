"""The one-pass check of a text file's first lines (:func:`plain_head`)
gives the sniffer and the layout the answers they give from the lines split
and matched (the check switched off), on heads drawn around the plain form:
every field's edges (signs, exponents, places, polarities), separators,
blanks, CRs, comments, headers, kind lines, fewer than 20 lines, a head cut
anywhere. And it is taken on the common heads."""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum.sources.files import _text_layout, samples_csv, text, tum
from tectum.sources.files._text_head import PLAIN_LINES, plain_head
from tectum.sources.files._text_layout import text_layout
from tectum.sources.files.samples_csv import CsvSource
from tectum.sources.files.tum import TumSource

_DIGITS = st.one_of(st.integers(0, 9999), st.integers(10 ** 15, 10 ** 20 - 1)).map(lambda v: str(v).encode())
_PLACES = st.sampled_from([b"", b".", b".5", b".003811000"])
_SEP = st.sampled_from([b" ", b"\t", b",", b", ", b" \t"])
#: What breaks the plain form, at one place of one line
_ODD = {"field": [b"-0.5", b"+1", b".5", b"1e3", b"x", b"", b"1 .5"], "sep": [b";", b"", b" ;"],
        "pol": [b"2", b"-0", b"+0", b"01", b"1.0", b"", b"1 1"], "lead": [b"\r", b",", b"\x0b"],
        "trail": [b"\x0b", b",", b" #", b";"],
        "line": [b"# c", b"% c", b"", b"  ", b"t,x,y,p", b"t_us x y p", b"# tectum events", b"# tectum imu",
                 b"timestamp,x,y,polarity"]}


@st.composite
def _line(draw: st.DrawFn, places: tuple[bytes, ...], odd: str | None) -> bytes:
    """A plain line, its fields' places ``places`` (None: drawn), or one odd at ``odd``."""
    if odd == "line":
        return draw(st.sampled_from(_ODD["line"]))
    part = {odd: draw(st.sampled_from(_ODD[odd]))} if odd else {}
    sep = part.get("sep", draw(_SEP))
    fields = [draw(_DIGITS) + (draw(_PLACES) if q is None else q) for q in places]
    if odd == "field":
        fields[draw(st.integers(0, 2))] = part["field"]
    return (part.get("lead", draw(st.sampled_from([b"", b"", b" ", b"\t"]))) + sep.join(fields) + sep
            + part.get("pol", draw(st.sampled_from([b"0", b"1", b"-1", b"+1"])))
            + part.get("trail", draw(st.sampled_from([b"", b"", b"\r", b" ", b"\t\r"]))))


@st.composite
def _head(draw: st.DrawFn) -> bytes:
    """Plain lines, each field's places one form for the file or drawn a
    line at a time, one line maybe odd (in the first 20 or past them); 15
    to 25 of them, the head maybe cut anywhere."""
    places = tuple(draw(st.one_of(st.none(), _PLACES)) for _ in range(3))
    n = draw(st.integers(15, 25))
    at = draw(st.integers(0, n))
    odd = draw(st.sampled_from([None, *_ODD]))
    head = b"\n".join(draw(_line(places, odd if k == at else None)) for k in range(n)) + b"\n"
    return head[:draw(st.integers(0, len(head)))] if draw(st.integers(0, 5)) == 0 else head


def _careful(monkeypatch: pytest.MonkeyPatch) -> None:
    """The layout and the other sniffers deciding without the one-pass check."""
    monkeypatch.setattr(_text_layout, "plain_head", lambda buf, lines, k: (False, False, 0))
    for module in (tum, samples_csv):  # the pose and sample sniffers, which say no to plain event lines
        monkeypatch.setattr(module, "plain_events_head", lambda head: False)


def _same_answers(head: bytes, columns: str | None) -> None:
    sniffed = text.looks_like_events_text(head)
    layout = text_layout(head, columns)
    others = (TumSource.sniff(head), CsvSource.sniff(head))
    assert sniffed == text._events_text_lines(head), head
    with pytest.MonkeyPatch.context() as m:
        _careful(m)
        assert layout == text_layout(head, columns), head
        assert others == (TumSource.sniff(head), CsvSource.sniff(head)), head


@settings(max_examples=150)
@given(_head(), st.sampled_from([None, "txyp", "xytp", "ptxy", "xypt"]))
def test_the_check_changes_no_answer(head: bytes, columns: str | None) -> None:
    _same_answers(head, columns)


@pytest.mark.parametrize("odd", list(_ODD))
def test_each_odd_piece_anywhere(odd: str) -> None:
    """Every odd piece in a line of plain ones, in the first line, the
    20th (the last judged) and the 21st, each in heads of integer times of
    17 and 18 digits (µs and ns) and of decimals in every field."""
    for value in _ODD[odd]:
        for times, coords in [(b"17000000000000000", b"12"), (b"170000000000000000", b"12"), (b"0.5", b"3.")]:
            fields = [times, coords, coords]
            for at in (0, 19, 20):
                lines = []
                for k in range(22):
                    f = list(fields)
                    part = {odd: value} if k == at else {}
                    if k == at and odd == "field":
                        f[k % 3] = value
                    sep = part.get("sep", b", " if k % 2 else b"\t")
                    line = part.get("lead", b" " if k == 3 else b"") + sep.join(f) + sep + part.get(
                        "pol", [b"0", b"1", b"-1", b"+1"][k % 4]) + part.get("trail", b"\r" if k == 5 else b"")
                    lines.append(value if k == at and odd == "line" else line)
                head = b"\n".join(lines) + b"\n"
                for columns in (None, "xytp", "xypt"):
                    _same_answers(head, columns)
                    _same_answers(head.replace(b"+1", b"1").replace(b"-1", b"0"), columns)


@pytest.mark.parametrize("line, unit", [(b"0.003811000 96 133 0", "s"), (b"15,1,2,1", "us"),
                                        (b"1700000000000000000\t1\t2\t-1\r", "ns"), (b" 7. 1 2 +1 ", "s")])
def test_the_check_is_taken_on_common_heads(monkeypatch: pytest.MonkeyPatch, line: bytes, unit: str) -> None:
    head = (line + b"\n") * 30
    assert plain_head(np.frombuffer(head, np.uint8), PLAIN_LINES, 0)[0]
    assert text.looks_like_events_text(head) and text_layout(head).time_unit == unit
    monkeypatch.setattr(text, "_events_text_lines", lambda head: False)  # the careful ways out of reach
    monkeypatch.setattr(_text_layout, "_header", lambda head: ([], []))
    assert text.looks_like_events_text(head) and text_layout(head).time_unit == unit
    assert not plain_head(np.frombuffer(head[:-1], np.uint8), 30, 0)[0]  # the 30th line without its newline


def test_a_bad_line_after_long_numbers_is_judged_at_once() -> None:
    """The careful sniffer's form matches each number one way: with a
    number's digits splittable between two parts (the form it had), a bad
    line after k lines of long numbers retried every split of them, hours
    for 20 lines of ns times (31 s for 3)."""
    head = b"1700000000000000000,1234,1234,1\n" * 20 + b"1700000000000000000,1,2,2\n"
    start = time.process_time()
    assert text._events_text_lines(head) and not text._events_text_lines(head[:33 * 6] + b"1,2,3,2\n")
    assert time.process_time() - start < 1.0
