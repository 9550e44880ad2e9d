"""EVT 2.0 RAW files against a decoder written from Prophesee's format description.

EVT 2.0 (Prophesee's "EVT 2.0 Format" page): little-endian 32-bit words, the
type in bits 31-28. CD_OFF 0x0 / CD_ON 0x1: bits 27-22 the 6 low bits of the
time, bits 21-11 x, bits 10-0 y. EVT_TIME_HIGH 0x8: bits 27-0 the time's bits
33-6. EXT_TRIGGER 0xA: bits 27-22 the time's low bits, bits 12-8 the trigger
id, bit 0 its value (1 rising edge). OTHERS 0xE and CONTINUED 0xF carry
vendor data (no events); every other type is reserved.

:func:`reference` decodes a word list the slow, obvious way, with tectum's
conventions: p = +1 for CD_ON, -1 for CD_OFF; events and triggers before the
first EVT_TIME_HIGH have no time and are dropped; the 34-bit time unrolls
(a TIME_HIGH falling by more than half its range counts one wrap). Hypothesis
draws a clock (often just before the 2^34 µs wrap) and a mix of every word
type, including words before the first time base and, sometimes, one
reserved word; :func:`reference`'s output is checked against what was meant,
then tectum's reader (in drawn chunk sizes) against it, value by value: t, x,
y, p of every event, t, channel and value of every trigger; a reserved word
raises a FormatError at its byte, or with ``skip_bad`` is dropped alone.
"""

from __future__ import annotations

from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from prophesee_raw import check_stream, read_raw, write_raw

from tectum import EventPacket
from tectum.sources.files._common import FROM_EXTENT, FROM_OPTION
from tectum.sources.files.prophesee import Evt2Source

HIGH_BITS = 28
TIME_BITS = 34
RESERVED = [0x2, 0x3, 0x4, 0x5, 0x6, 0x7, 0x9, 0xB, 0xC, 0xD]


def reference(words: list[int]) -> tuple[list[tuple[int, int, int, int]], list[tuple[int, int, int]], int]:
    """(events (t, x, y, p), triggers (t, id, value), reserved words) of EVT 2.0 ``words``."""
    events, triggers, reserved = [], [], 0
    high = None  # the last TIME_HIGH's 28 bits
    wraps = 0
    for w in words:
        kind, payload = w >> 28, w & 0x0FFFFFFF
        low = (w >> 22) & 0x3F
        if kind == 0x8:
            if high is not None and high - payload > 1 << (HIGH_BITS - 1):
                wraps += 1
            high = payload
        elif kind in (0x0, 0x1):
            if high is not None:
                t = (wraps << TIME_BITS) + (high << 6) + low
                events.append((t, (w >> 11) & 0x7FF, w & 0x7FF, 1 if kind == 0x1 else -1))
        elif kind == 0xA:
            if high is not None:
                triggers.append(((wraps << TIME_BITS) + (high << 6) + low, (w >> 8) & 0x1F, w & 1))
        elif kind not in (0xE, 0xF):
            reserved += 1
    return events, triggers, reserved


@st.composite
def streams(draw: st.DrawFn) -> tuple[tuple[int, int], list[int], list, list]:
    """(sensor, words, the events meant, the triggers meant)."""
    w, h = draw(st.sampled_from([(640, 480), (1280, 720), (2048, 2048)]))
    clock = draw(st.one_of(st.integers((1 << TIME_BITS) - 5000, (1 << TIME_BITS) - 1),
                           st.integers(0, (1 << TIME_BITS) - 1), st.integers(0, 1000)))
    words: list[int] = []
    events: list[tuple[int, int, int, int]] = []
    triggers: list[tuple[int, int, int]] = []
    timed = False
    origin = 0  # the meant times count from the first TIME_HIGH's wrap period

    def cd(meant: bool) -> None:
        x, y, on = draw(st.integers(0, w - 1)), draw(st.integers(0, h - 1)), draw(st.booleans())
        words.append((int(on) << 28) | ((clock & 0x3F) << 22) | (x << 11) | y)
        if meant:
            events.append((clock - origin, x, y, 1 if on else -1))

    def trigger(meant: bool) -> None:
        ident, value = draw(st.integers(0, 31)), draw(st.integers(0, 1))
        junk = draw(st.sampled_from([0, (1 << 13) | (1 << 21), 0b1111110]))  # unused bits set
        words.append((0xA << 28) | ((clock & 0x3F) << 22) | (ident << 8) | value | junk)
        if meant:
            triggers.append((clock - origin, ident, value))

    def vendor() -> None:
        words.append((draw(st.sampled_from([0xE, 0xF])) << 28) | draw(st.integers(0, (1 << 28) - 1)))

    for _ in range(draw(st.integers(0, 3))):  # before any time base: no time, dropped
        draw(st.sampled_from([cd, trigger, lambda meant: vendor()]))(False)
    steps = ["cd", "cd", "cd", "cd", "trigger", "vendor", "time_high", "advance", "advance"]
    for _ in range(draw(st.integers(1, 80))):
        step = draw(st.sampled_from(steps)) if timed else "time_high"
        if step == "advance":
            old = clock >> 6
            clock += draw(st.one_of(st.integers(0, 70), st.integers(0, 1 << 20), st.integers(0, (1 << 32) - 1)))
            if clock >> 6 != old:
                words.append((0x8 << 28) | ((clock >> 6) & 0x0FFFFFFF))
        elif step == "time_high":  # also repeated without a change
            if not timed:
                origin = clock >> TIME_BITS << TIME_BITS
            timed = True
            words.append((0x8 << 28) | ((clock >> 6) & 0x0FFFFFFF))
        elif step == "cd":
            cd(True)
        elif step == "trigger":
            trigger(True)
        else:
            vendor()
    return (w, h), words, events, triggers


def header(sensor: tuple[int, int]) -> str:
    return f"% evt 2.0\n% geometry {sensor[0]}x{sensor[1]}\n% end\n"


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=streams(), chunk=st.sampled_from([64, 68, 132, 1 << 16]), data=st.data())
def test_evt2_equals_the_reference(tmp_path: Path, case: tuple, chunk: int, data: st.DataObject) -> None:
    at = data.draw(st.integers(0, len(case[1])))
    bad = (data.draw(st.sampled_from(RESERVED)) << 28) | data.draw(st.integers(0, (1 << 28) - 1))
    check_stream(Evt2Source, tmp_path / "r.raw", header(case[0]), "I", case, reference, chunk, at, bad)


def test_without_geometry_the_sensor_is_the_extent_of_the_coordinates(tmp_path: Path) -> None:
    """No ``% geometry`` line: the size is the largest coordinates + 1, and
    the source says where it came from (``tectum info`` prints it)."""
    path = tmp_path / "g.raw"
    write_raw(path, "% evt 2.0\n% end\n", [0x8 << 28, 1 << 28 | 5 << 22 | 11 << 11 | 6, 5 << 22 | 2 << 11 | 8], "I")
    src = Evt2Source(str(path))
    assert {q.sensor for q in src.packets() if isinstance(q, EventPacket)} == {(12, 9)}
    assert src.sensor_from == FROM_EXTENT
    src = Evt2Source(str(path), sensor="640x480")
    assert {q.sensor for q in src.packets() if isinstance(q, EventPacket)} == {(640, 480)}
    assert src.sensor_from == FROM_OPTION


def test_time_high_wrap_fixed_case(tmp_path: Path) -> None:
    """The clock passes 2^34 µs: TIME_HIGH falls from 0xFFFFFFF to 0 and times keep counting."""
    top = (1 << HIGH_BITS) - 1
    words = [0x8 << 28 | top, 1 << 28 | 63 << 22 | 5 << 11 | 6, 0x8 << 28 | 0, 0 << 28 | 1 << 22 | 7 << 11 | 8,
             0xA << 28 | 2 << 22 | 3 << 8 | 1]
    path = tmp_path / "wrap.raw"
    write_raw(path, header((640, 480)), words, "I")
    events, triggers = read_raw(Evt2Source, path)
    assert events == [((top << 6) + 63, 5, 6, 1), ((1 << TIME_BITS) + 1, 7, 8, -1)]
    assert triggers == [((1 << TIME_BITS) + 2, 3, 1)]
