"""EVT 3.0 RAW files against a decoder written from Prophesee's format description.

EVT 3.0 (Prophesee's "EVT 3.0 Format" page): little-endian 16-bit words, the
type in bits 15-12, a decoder state carried from word to word.
EVT_ADDR_Y 0x0: bits 10-0 y (bit 11 the system type). EVT_ADDR_X 0x2: one
event at x = bits 10-0, polarity bit 11, with the state's y and time.
VECT_BASE_X 0x3: bits 10-0 the vector base x, bit 11 the vectors' polarity.
VECT_12 0x4 / VECT_8 0x5: bit b of the 12 (8) low bits set gives an event at
base + b; the base then moves on by 12 (8). EVT_TIME_LOW 0x6 / EVT_TIME_HIGH
0x8: the low and high 12 bits of the 24-bit time. EXT_TRIGGER 0xA: bits 11-8
the trigger id, bit 0 its value. CONTINUED_4 0x7, OTHERS 0xE, CONTINUED_12
0xF carry no events; every other type is reserved.

:func:`reference` decodes word lists the slow, obvious way, with tectum's
conventions: p = +1 for polarity 1; nothing has a time before the first
EVT_TIME_HIGH (events and triggers dropped; vectors still move the base);
before any ADDR_Y / VECT_BASE_X, y and the base are 0 and the vectors' polarity
OFF (a zeroed register); the time unrolls its 24-bit wrap (a TIME_HIGH
falling by more than half its range counts one). Hypothesis draws a clock
(often just before the 2^24 µs wrap) and every word type; tectum's reader (in
drawn chunk sizes) must give the same t, x, y, p and triggers value by value,
and a reserved word raises a FormatError at its byte or, with ``skip_bad``,
is dropped alone.
"""

from __future__ import annotations

from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from prophesee_raw import check_stream, read_raw, write_raw

from tectum.sources.files.prophesee import Evt3Source

TIME_BITS = 24
RESERVED = [0x1, 0x9, 0xB, 0xC, 0xD]


def reference(words: list[int]) -> tuple[list[tuple[int, int, int, int]], list[tuple[int, int, int]], int]:
    """(events (t, x, y, p), triggers (t, id, value), reserved words) of EVT 3.0 ``words``."""
    events, triggers, reserved = [], [], 0
    y = base = low = wraps = 0
    high = None
    vector_p = -1
    for w in words:
        kind = w >> 12
        t = None if high is None else (wraps << TIME_BITS) + (high << 12) + low
        if kind == 0x0:
            y = w & 0x7FF
        elif kind == 0x2:
            if t is not None:
                events.append((t, w & 0x7FF, y, 1 if w & 0x800 else -1))
        elif kind == 0x3:
            base, vector_p = w & 0x7FF, (1 if w & 0x800 else -1)
        elif kind in (0x4, 0x5):
            width = 12 if kind == 0x4 else 8
            for b in range(width):
                if t is not None and w >> b & 1:
                    events.append((t, base + b, y, vector_p))
            base += width
        elif kind == 0x6:
            low = w & 0xFFF
        elif kind == 0x8:
            if high is not None and high - (w & 0xFFF) > 1 << 11:
                wraps += 1
            high = w & 0xFFF
        elif kind == 0xA:
            if t is not None:
                triggers.append((t, (w >> 8) & 0xF, w & 1))
        elif kind not in (0x7, 0xE, 0xF):
            reserved += 1
    return events, triggers, reserved


@st.composite
def streams(draw: st.DrawFn) -> tuple[tuple[int, int], list[int], list, list]:
    """(sensor, words, the events meant, the triggers meant)."""
    w, h = draw(st.sampled_from([(640, 480), (1280, 720), (2048, 2048)]))
    clock = draw(st.one_of(st.integers((1 << TIME_BITS) - 5000, (1 << TIME_BITS) - 1),
                           st.integers(0, (1 << TIME_BITS) - 1)))
    words: list[int] = []
    events: list[tuple[int, int, int, int]] = []
    triggers: list[tuple[int, int, int]] = []
    origin = clock >> TIME_BITS << TIME_BITS

    def addr_y(y: int) -> None:
        words.append(draw(st.sampled_from([0, 0x800])) | y)  # bit 11: system type, not a coordinate

    def time(full: bool) -> None:
        if full:
            words.append(0x8000 | (clock >> 12) & 0xFFF)
        words.append(0x6000 | clock & 0xFFF)

    # before any time base: an event, a vector and a trigger without time (dropped)
    for _ in range(draw(st.integers(0, 2))):
        words.append(draw(st.sampled_from([0x2000 | 5, 0x4000 | 0x0F0, 0x5000 | 0x81, 0xA101])))
    if draw(st.booleans()):  # a time low before the first high: kept for it
        words.append(0x6000 | clock & 0xFFF)
    words.append(0x8000 | (clock >> 12) & 0xFFF)
    time(False)
    steps = ["single", "single", "vector", "vector", "trigger", "vendor", "advance", "advance", "time"]
    for _ in range(draw(st.integers(1, 50))):
        step = draw(st.sampled_from(steps))
        if step == "advance":
            old = clock
            # TIME_HIGH moves by less than half its range (2^11): a step of exactly half is no wrap
            # (the reference, the kernel), yet the clock would have moved on (found by a cold-cache run)
            clock += draw(st.one_of(st.integers(0, 50), st.integers(0, 1 << 16), st.integers(0, (1 << 23) - (1 << 12))))
            time(clock >> 12 != old >> 12)
        elif step == "time":  # repeated without a change
            time(draw(st.booleans()))
        elif step == "single":
            y, x, on = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1)), draw(st.booleans())
            addr_y(y)
            words.append(0x2000 | (int(on) << 11) | x)
            events.append((clock - origin, x, y, 1 if on else -1))
        elif step == "vector":
            y, on = draw(st.integers(0, h - 1)), draw(st.booleans())
            masks = draw(st.lists(st.tuples(st.sampled_from([12, 8]), st.integers(0, 0xFFF)), min_size=1, max_size=4))
            base = draw(st.integers(0, w - sum(n for n, _ in masks)))
            addr_y(y)
            words.append(0x3000 | (int(on) << 11) | base)
            for n, mask in masks:
                mask &= (1 << n) - 1
                words.append((0x4000 if n == 12 else 0x5000) | mask)
                events += [(clock - origin, base + b, y, 1 if on else -1) for b in range(n) if mask >> b & 1]
                base += n
        elif step == "trigger":
            ident, value = draw(st.integers(0, 15)), draw(st.integers(0, 1))
            words.append(0xA000 | (ident << 8) | value | draw(st.sampled_from([0, 0xFE])))  # unused bits
            triggers.append((clock - origin, ident, value))
        else:
            words.append((draw(st.sampled_from([0x7, 0xE, 0xF])) << 12) | draw(st.integers(0, 0xFFF)))
    return (w, h), words, events, triggers


def header(sensor: tuple[int, int]) -> str:
    return f"% format EVT3;height={sensor[1]};width={sensor[0]}\n% geometry {sensor[0]}x{sensor[1]}\n% end\n"


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=streams(), chunk=st.sampled_from([64, 66, 130, 1 << 16]), data=st.data())
def test_evt3_equals_the_reference(tmp_path: Path, case: tuple, chunk: int, data: st.DataObject) -> None:
    at = data.draw(st.integers(0, len(case[1])))
    bad = (data.draw(st.sampled_from(RESERVED)) << 12) | data.draw(st.integers(0, 0xFFF))
    check_stream(Evt3Source, tmp_path / "r.raw", header(case[0]), "H", case, reference, chunk, at, bad)


def test_registers_before_they_are_written(tmp_path: Path) -> None:
    """Vectors before any VECT_BASE_X / ADDR_Y: base x 0, y 0, OFF; a
    vector before the time base moves the base without events."""
    words = [0x4000 | 0x001, 0x8000 | 3, 0x6000 | 7, 0x5000 | 0x03, 0x2800 | 9]
    path = tmp_path / "zero.raw"
    write_raw(path, header((640, 480)), words, "H")
    t = (3 << 12) + 7
    assert read_raw(Evt3Source, path) == ([(t, 12, 0, -1), (t, 13, 0, -1), (t, 9, 0, 1)], [])
    assert read_raw(Evt3Source, path)[0] == reference(words)[0]


def test_time_high_wrap_fixed_case(tmp_path: Path) -> None:
    """The clock passes 2^24 µs: TIME_HIGH falls from 0xFFF to 0 and times keep counting."""
    words = [0x8FFF, 0x6FFE, 0x0000 | 4, 0x2000 | 1, 0x8000, 0x6002, 0x2800 | 2, 0xA301]
    path = tmp_path / "wrap.raw"
    write_raw(path, header((640, 480)), words, "H")
    assert read_raw(Evt3Source, path) == ([((1 << 24) - 2, 1, 4, -1), ((1 << 24) + 2, 2, 4, 1)], [((1 << 24) + 2, 3, 1)])
