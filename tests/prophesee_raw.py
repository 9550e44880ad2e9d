"""Prophesee RAW files for the EVT 2.0 and 3.0 reference tests: write words
behind a header, read every event and trigger back as tuples, and check a
stream against its reference, a reserved word named at its byte or dropped
alone."""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tectum import EventPacket, FormatError, TriggerPacket

Decoded = tuple[list[tuple[int, ...]], list[tuple[int, ...]]]


def write_raw(path: Path, header: str, words: list[int], word: str) -> int:
    """``header`` then ``words`` (struct code ``word``: ``I`` or ``H``),
    little-endian; returns the header's length (bytes)."""
    path.write_bytes(header.encode() + struct.pack(f"<{len(words)}{word}", *words))
    return len(header)


def read_raw(source: type, path: Path, **kw: Any) -> Decoded:
    """(events (t, x, y, p), triggers (t, channel, value)) of a RAW file."""
    pkts = list(source(str(path), **kw).packets())
    ev = [q for q in pkts if isinstance(q, EventPacket) and len(q)]
    tr = [q for q in pkts if isinstance(q, TriggerPacket) and len(q)]
    cols = [np.concatenate([getattr(q, c) for q in ev]).tolist() if ev else [] for c in "txyp"]
    tcols = [np.concatenate([q.t for q in tr]).tolist() if tr else []]
    tcols += [np.concatenate([q.data[c] for q in tr]).tolist() if tr else [] for c in ("channel", "value")]
    return list(zip(*cols)), list(zip(*tcols))


def check_stream(source: type, path: Path, header: str, word: str, case: tuple,
                 reference: Callable[[list[int]], tuple[list, list, int]], chunk: int, at: int, bad: int) -> None:
    """``case`` (sensor, words, events meant, triggers meant): the reference
    reads what was meant and the reader (``chunk_bytes=chunk``) the same,
    on that sensor; then ``bad`` (a reserved word) inserted before
    ``words[at]`` raises a FormatError at its byte and, with ``skip_bad``,
    leaves the rest as without it (which the reference says too), counted
    as one skipped word at its bytes."""
    sensor, words, events, triggers = case
    assert reference(words)[:2] == (events, triggers)
    write_raw(path, header, words, word)
    assert read_raw(source, path, chunk_bytes=chunk) == (events, triggers)
    assert all(q.sensor == sensor for q in source(str(path)).packets() if isinstance(q, EventPacket))
    spoiled = words[:at] + [bad] + words[at:]
    head = write_raw(path, header, spoiled, word)
    with pytest.raises(FormatError, match="invalid EVT") as e:
        read_raw(source, path, chunk_bytes=chunk)
    assert e.value.offset == head + struct.calcsize(word) * at
    assert reference(spoiled) == (events, triggers, 1)
    assert read_raw(source, path, chunk_bytes=chunk, skip_bad=True) == (events, triggers)
    lenient = source(str(path), chunk_bytes=chunk, skip_bad=True)
    for _ in lenient.packets():
        pass
    at_byte, size = head + struct.calcsize(word) * at, struct.calcsize(word)
    assert lenient.skipped_events == 1 and lenient.skipped_ranges == [(at_byte, at_byte + size - 1)]
