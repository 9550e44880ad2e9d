"""The first lines of an event text file checked in one compiled pass.

Deciding what a text file is (:func:`tectum.sources.files.text.looks_like_events_text`)
and how its columns read (:func:`._text_layout.text_layout`) take its first
20 data lines apart with regular expressions and line splitting: ~15 µs each,
on every file opened. Most files start with plain event lines
(``0.003811000 96 133 0``, ``15,1,2,1``), for which both answers are known once
those lines are seen to be plain: :func:`plain_head` checks that in one pass
(~1 µs) and reports what the layout needs of the time column. Any other head
(comments, a header, signs, exponents, odd blanks, fewer lines) gets a "no",
and the callers decide the careful way, so the answers never differ
(tests/sources/files/test_text_head.py compares the two on drawn heads).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["plain_head", "plain_events_head", "PLAIN_LINES"]

#: Lines :func:`plain_head` checks: the lines the sniffer and the layout judge by
PLAIN_LINES = 20


@njit(cache=True, nogil=True, inline="always")
def _digits_end(buf, i, n):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The index of the first byte from ``i`` on that is no ASCII digit (``n`` at the end)."""
    while i < n and np.uint8(buf[i] - 48) < 10:
        i += 1
    return i


@njit(cache=True, nogil=True)
def plain_head(buf, lines, k):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Whether ``buf`` (uint8) starts with ``lines`` complete plain event
    lines, and what its field ``k`` (0 to 3) holds there: (plain, whether
    any field ``k`` has a ``.``, the most characters of a field ``k``
    without its sign). A plain line: optional spaces or tabs, three numbers
    of digits with an optional ``.`` and places (``0.5``, ``12``, ``7.``),
    a polarity ``0``, ``1``, ``-1`` or ``+1``, the fields apart by runs of
    spaces, tabs and commas, optional spaces, tabs and CRs, a newline.
    Such a line has no letters, is no comment nor blank, and fits any
    form the careful deciders accept."""
    n = buf.shape[0]
    i = 0
    dot = False
    width = 0
    for _ in range(lines):
        while i < n and (buf[i] == 32 or buf[i] == 9):
            i += 1
        for f in range(4):
            if f > 0:
                s = i
                while i < n and (buf[i] == 32 or buf[i] == 9 or buf[i] == 44):
                    i += 1
                if i == s:
                    return False, False, 0
            s = i
            if f < 3:
                i = _digits_end(buf, i, n)
                if i == s:
                    return False, False, 0
                if i < n and buf[i] == 46:
                    dot |= f == k
                    i = _digits_end(buf, i + 1, n)
            else:
                signed = i < n and (buf[i] == 45 or buf[i] == 43)
                if signed:
                    i += 1
                    s += 1
                if i < n and (buf[i] == 49 or (buf[i] == 48 and not signed)):
                    i += 1
                else:
                    return False, False, 0
            if f == k:
                width = max(width, i - s)
        while i < n and (buf[i] == 32 or buf[i] == 9 or buf[i] == 13):
            i += 1
        if i >= n or buf[i] != 10:
            return False, False, 0
        i += 1
    return True, dot, width


def plain_events_head(head: bytes) -> bool:
    """Whether a file's ``head`` starts with :data:`PLAIN_LINES` plain event
    lines (:func:`plain_head`): the sniffers' common question (the event text
    source says yes at once, the pose and sample text sources no)."""
    return bool(plain_head(np.frombuffer(head, np.uint8), PLAIN_LINES, 0)[0])
