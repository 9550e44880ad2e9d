"""Recognising Prophesee RAW and DAT files by their first bytes (what
``open_file`` and the registry see), whatever the case of the header's
words, and the same answer when every class sniffs the same bytes in turn."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum.sources.files.prophesee import DatSource, Evt2Source, Evt3Source

_BODY = np.arange(1000, dtype="<u4").tobytes()  # binary words after the header

HEADS = [
    (b"% evt 2.0\n% geometry 640x480\n% end\n", "evt2"),
    (b"% date 2020\n% EVT 2.0\n", "evt2"),
    (b"% format EVT2;height=480;width=640\n% end\n", "evt2"),
    (b"% evt 3.0\n% end\n", "evt3"),
    (b"% camera_integrator_name Prophesee\n% format EVT3;height=720;width=1280\n% end\n", "evt3"),
    (b"% Format evt3.0\n", "evt3"),
    (b"% Data file containing Event2D events.\n% Version 2\n% Height 720\n% Width 1280\n", "dat"),
    (b"% date 2020\n% plugin_name hal_plugin_gen3_fx3\n% end\n", None),  # a RAW header naming no format
    (b"no header at all\n", None),
]


@pytest.mark.parametrize("head, fmt", HEADS)
def test_each_class_recognises_its_own_heads(head: bytes, fmt: str | None) -> None:
    data = head + (b"\x0c\x08" if fmt == "dat" else b"") + _BODY
    for _ in range(2):  # the second time from the cache
        got = {cls.format for cls in (Evt2Source, Evt3Source, DatSource) if cls.sniff(data)}
        assert got == ({fmt} if fmt else set())


def test_equal_heads_in_turn_and_other_heads_between() -> None:
    """The cache answers by content: equal bytes in new objects, and heads
    of every kind one after another, get each their own answer."""
    for _ in range(3):
        for head, fmt in HEADS:
            data = bytes(bytearray(head + _BODY))  # a new object each time
            assert Evt2Source.sniff(data) == (fmt == "evt2")
            assert Evt3Source.sniff(data) == (fmt == "evt3")


_LINES = [b"1.5 0 0 0 0 0 0 1", b"12 1 2 3 0.6 0 0.8 0", b"t,ax,ay,az,gx,gy,gz", b"10,0,0,9.81,0.1,0.2,0.3",
          b"t,x,y,z", b"1,0.5,0.25,2.0", b"# tectum imu", b"# a comment", b"", b"evt 2.0", b"1 2 3 4"]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([b"%", b"% ", b"%1 ", b"%t,", b"", b" "]), st.lists(st.sampled_from(_LINES), max_size=6),
       st.binary(max_size=40))
def test_text_sniffers_say_no_to_a_prophesee_header_at_once(first: bytes, lines: list[bytes], tail: bytes) -> None:
    """The pose and sample text sniffers, which come before the RAW and DAT
    ones, answer a head starting with ``%`` without parsing its lines, and
    every head as their full text test does (``_sniff_text``)."""
    from tectum.sources.files.samples_csv import CsvSource
    from tectum.sources.files.tum import TumSource

    head = first + b"\n".join(lines) + b"\n" + tail
    for cls in (TumSource, CsvSource):
        assert cls.sniff(head) == cls._sniff_text(head)
