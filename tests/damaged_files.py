"""Helpers for the hostile-input tests of the text-like readers (event text,
CSV, TUM, PLY) and HDF5: random text, seeded byte mutations, the number of
rows a reader must keep or count as skipped, and the packet checks every
read must pass."""

from __future__ import annotations

import re
import string

import numpy as np

from tectum import EventPacket, Packet, PosePacket

__all__ = ["random_text", "event_text_rows", "sample_text_rows", "mutate", "check_packets"]

_SEPARATORS = set(b" \t,\r")


def random_text(size: int, seed: int = 0) -> bytes:
    """Printable ASCII (newlines included) at random: ~1 line in 100 bytes."""
    alphabet = np.frombuffer(string.printable.encode(), np.uint8)
    return np.random.default_rng(seed).choice(alphabet, size).tobytes()


def _lines(raw: bytes) -> list[bytes]:
    lines = raw.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    return lines


def event_text_rows(raw: bytes) -> int:
    """Lines an event text reader must keep or count as skipped: not blank
    (spaces, tabs, commas, CR), not a ``#``/``%`` comment, not the header
    (a first line with ASCII letters)."""
    n = 0
    for k, ln in enumerate(_lines(raw)):
        if not ln or set(ln) <= _SEPARATORS or ln.startswith((b"#", b"%")):
            continue
        if k == 0 and re.search(rb"[A-Za-z]", ln):
            continue
        n += 1
    return n


def sample_text_rows(raw: bytes) -> int:
    """Lines a sample-file reader (TUM, CSV) sees as rows: not blank, not a
    ``#`` comment (the CSV header is one of them)."""
    return sum(1 for ln in _lines(raw) if ln.strip() and not ln.strip().startswith(b"#"))


def mutate(raw: bytes, rng: np.random.Generator, lines: bool = False) -> tuple[str, bytes]:
    """``raw`` damaged at random: cut short, up to 8 bytes overwritten, up to
    64 random bytes spliced in, or (``lines``) a line repeated or moved, so
    times go back. Returns (what was done, the bytes)."""
    ops = ["truncate", "flip", "splice"] + (["line"] if lines else [])
    op = ops[int(rng.integers(len(ops)))]
    out = bytearray(raw)
    if op == "truncate":
        return op, bytes(out[:int(rng.integers(0, len(out) + 1))])
    if op == "flip":
        for _ in range(int(rng.integers(1, 9))):
            out[int(rng.integers(len(out)))] = int(rng.integers(256))
        return op, bytes(out)
    if op == "splice":
        i = int(rng.integers(len(out) + 1))
        out[i:i] = rng.bytes(int(rng.integers(1, 65)))
        return op, bytes(out)
    rows = raw.split(b"\n")
    a, b = (int(v) for v in rng.integers(0, len(rows), 2))
    rows.insert(b, rows[a])
    return op, b"\n".join(rows)


def check_packets(packets: list[Packet]) -> None:
    """The packet contract on what a reader gave: events valid (times in
    order inside their interval, in the sensor, polarity ±1), samples in
    order inside their interval, poses finite, and each stream's times
    non-decreasing from packet to packet."""
    last: dict[str, int] = {}
    for q in packets:
        q.validate()
        if isinstance(q, PosePacket) and len(q):
            assert np.isfinite(q.position).all() and np.isfinite(q.orientation).all()
        if len(q):
            k = str(q.kind)
            assert int(q.t[0]) >= last.get(k, -(1 << 63)), f"{k} times go back between packets"
            last[k] = int(q.t[-1])
            if isinstance(q, EventPacket):
                assert (q.x < q.sensor[0]).all() and (q.y < q.sensor[1]).all()
