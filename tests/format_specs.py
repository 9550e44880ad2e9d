"""Slow, obvious encoders and decoders of the Event Stream 2.0 and N-MNIST
layouts, written from their specifications (neuromorphic-paris/event_stream's
README; the N-MNIST dataset page and its authors' Python reader), one byte or
record at a time, for the reader and writer tests to compare with.

Events are ``(t, x, y, p)`` tuples with tectum's top-left y and p ±1; ATIS
threshold crossings are ``(t, x, y, second)``.
"""

from __future__ import annotations

MAGIC = b"Event Stream"


def es_header(kind: int, w: int, h: int, version: bytes = b"\x02\x00\x00") -> bytes:
    return MAGIC + version + bytes([kind]) + w.to_bytes(2, "little") + h.to_bytes(2, "little")


def es_encode(kind: int, w: int, h: int, items: list[tuple[int, int, int, int, bool]],
              resets: set[int] = frozenset(), overflow_codes: list[int] | None = None) -> bytes:
    """An Event Stream file of ``items`` ``(t, x, y, p_or_second, is_tc)``
    (times non-decreasing from 0). ``resets``: indices of items preceded by a
    run of reset bytes; ``overflow_codes`` (ATIS): the overflow bytes' low
    bits to cycle through (1-3), so that files mix 63, 126 and 189 µs steps."""
    out = bytearray(es_header(kind, w, h))
    last = 0
    codes = overflow_codes or [3]
    c = 0
    for i, (t, x, y, v, tc) in enumerate(items):
        if i in resets:
            out += bytes([0xFE] * 5) if kind == 1 else bytes([0xFC] * 5)
        d = t - last
        last = t
        if kind == 1:
            while d >= 127:
                out.append(0xFF)
                d -= 127
            out.append((d << 1) | (1 if v > 0 else 0))
        else:
            while d >= 63:
                code = codes[c % len(codes)]
                if 63 * code > d:
                    code = d // 63
                c += 1
                out.append(0xFC | code)
                d -= 63 * code
            out.append((d << 2) | ((1 if v > 0 else 0) << 1) | (1 if tc else 0))
        raw_y = h - 1 - y
        out += bytes([x & 0xFF, x >> 8, raw_y & 0xFF, raw_y >> 8])
    return bytes(out)


def es_decode(raw: bytes) -> tuple[list[tuple[int, int, int, int]], list[tuple[int, int, int, bool]]]:
    """Events and ATIS threshold crossings of a DVS or ATIS file, byte by byte."""
    assert raw.startswith(MAGIC) and raw[12] == 2
    kind = raw[15]
    h = int.from_bytes(raw[18:20], "little")
    events: list[tuple[int, int, int, int]] = []
    crossings: list[tuple[int, int, int, bool]] = []
    t = 0
    i = 20
    while i < len(raw):
        b = raw[i]
        if kind == 1 and b in (0xFE, 0xFF):
            t += 127 if b == 0xFF else 0
            i += 1
            continue
        if kind == 2 and b >> 2 == 0x3F:
            t += 63 * (b & 3)
            i += 1
            continue
        if i + 5 > len(raw):
            raise ValueError("truncated")
        t += b >> 1 if kind == 1 else b >> 2
        x = raw[i + 1] | raw[i + 2] << 8
        y = h - 1 - (raw[i + 3] | raw[i + 4] << 8)
        on = bool(b & 1) if kind == 1 else bool(b & 2)
        if kind == 2 and b & 1:
            crossings.append((t, x, y, on))
        else:
            events.append((t, x, y, 1 if on else -1))
        i += 5
    return events, crossings


def nmnist_encode(events: list[tuple[int, int, int, int]]) -> bytes:
    """N-MNIST records of events (times non-decreasing from 0), with a
    time-overflow record (``y = 240``, adding 2^13 µs) wherever the 23-bit
    field runs out, as many as it takes."""
    out = bytearray()
    add = 0
    for t, x, y, p in events:
        while t - add >= 1 << 23:
            out += bytes([0, 240, 0, 0, 0])
            add += 1 << 13
        r = t - add
        out += bytes([x, y, (r >> 16) | (0x80 if p > 0 else 0), (r >> 8) & 0xFF, r & 0xFF])
    return bytes(out)


def nmnist_decode(raw: bytes) -> list[tuple[int, int, int, int]]:
    """Events of N-MNIST records, as the dataset authors' reader reads them."""
    out = []
    add = 0
    for i in range(0, len(raw) - len(raw) % 5, 5):
        x, y, a, b, c = raw[i:i + 5]
        if y == 240:
            add += 1 << 13
            continue
        out.append((((a & 0x7F) << 16 | b << 8 | c) + add, x, y, 1 if a & 0x80 else -1))
    return out
