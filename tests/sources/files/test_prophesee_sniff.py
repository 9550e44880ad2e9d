"""Recognising Prophesee RAW and DAT files by their first bytes (what
``open_file`` and the registry see), whatever the case of the header's
words, and the same answer when every class sniffs the same bytes in turn."""

from __future__ import annotations

import numpy as np
import pytest

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
