"""Event Stream 2.x (.es) against a byte-at-a-time decoder written from the
specification (tests/format_specs.py), the shared recordings and the
``event_stream`` package.

Hypothesis draws DVS and ATIS files (deltas around the overflow steps, runs
of reset bytes, ATIS overflow bytes of 1-3 steps, threshold crossings among
the events); the slow decoder must read what was meant, and tectum (in drawn
chunk sizes, whole and from a drawn start time) the same events and
crossings value by value.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from format_specs import es_decode, es_encode, es_header
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError, concat
from tectum.sources.files import open_file
from tectum.sources.files.event_stream import EventStreamSource, ExposurePacket


def read(path: Path, **kw) -> tuple[list[tuple], list[tuple], EventStreamSource]:
    src = EventStreamSource(str(path), **kw)
    pk = list(src.packets())
    ev = [q for q in pk if isinstance(q, EventPacket) and len(q)]
    ex = [q for q in pk if isinstance(q, ExposurePacket)]
    events = list(zip(*[np.concatenate([getattr(q, c) for q in ev]).tolist() if ev else [] for c in "txyp"]))
    cross = list(zip(*[np.concatenate([getattr(q, c) for q in ex]).tolist() if ex else []
                       for c in ("t", "x", "y", "second")]))
    return events, cross, src


@st.composite
def files(draw: st.DrawFn) -> tuple[bytes, list[tuple], list[tuple], tuple[int, int]]:
    """(file bytes, the events meant, the threshold crossings meant, sensor)."""
    kind = draw(st.sampled_from([1, 2]))
    w, h = draw(st.sampled_from([(320, 240), (1280, 720), (3, 300)]))
    t, items = 0, []
    for _ in range(draw(st.integers(0, 50))):
        t += draw(st.one_of(st.integers(0, 3), st.sampled_from([62, 63, 64, 125, 126, 127, 128, 254, 255]),
                            st.integers(0, 5000)))
        tc = kind == 2 and draw(st.booleans())
        items.append((t, draw(st.integers(0, w - 1)), draw(st.integers(0, h - 1)), draw(st.sampled_from([1, -1])),
                      tc))
    resets = set(draw(st.lists(st.integers(0, max(len(items) - 1, 0)), max_size=3)))
    codes = draw(st.lists(st.integers(1, 3), min_size=1, max_size=3))
    raw = es_encode(kind, w, h, items, resets, codes)
    events = [(a, b, c, d) for a, b, c, d, tc in items if not tc]
    cross = [(a, b, c, d > 0) for a, b, c, d, tc in items if tc]
    return raw, events, cross, (w, h)


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=files(), chunk=st.one_of(st.sampled_from([64, 1 << 16]), st.integers(64, 300)), data=st.data())
def test_event_stream_equals_the_reference(tmp_path: Path, case: tuple, chunk: int, data: st.DataObject) -> None:
    raw, events, cross, sensor = case
    assert es_decode(raw) == (events, cross)  # the reference reads what was meant
    path = tmp_path / "r.es"
    path.write_bytes(raw)
    got, got_cross, src = read(path, chunk_bytes=chunk)
    assert got == events
    assert got_cross == cross
    assert all(q.sensor == sensor for q in EventStreamSource(str(path)).packets() if isinstance(q, EventPacket))
    if events:
        start = data.draw(st.integers(0, events[-1][0] + 1))
        assert read(path, chunk_bytes=chunk, t_start_us=start)[0] == [e for e in events if e[0] >= start]
        assert read(path, chunk_bytes=chunk, t_end_us=start)[0] == [e for e in events if e[0] < start]


def test_header_only_file_is_empty_with_the_sensor(tmp_path: Path) -> None:
    path = tmp_path / "e.es"
    path.write_bytes(es_header(1, 346, 260))
    pk = list(open_file(str(path)).packets())
    assert sum(len(q) for q in pk) == 0
    assert EventStreamSource(str(path), t_start_us=0, t_end_us=10).info()["sensor"] == (346, 260)


def test_overflow_only_tail_and_huge_delta(tmp_path: Path) -> None:
    """A million overflow bytes (127 s) before an event; overflow bytes after
    the last event add time but make no event."""
    raw = es_header(1, 4, 4) + b"\xff" * 1_000_000 + bytes([5 << 1 | 1, 1, 0, 1, 0]) + b"\xff\xff"
    path = tmp_path / "h.es"
    path.write_bytes(raw)
    assert read(path)[0] == [(127_000_005, 1, 2, 1)]


@pytest.mark.parametrize("kind,msg", [(0, "generic"), (3, "Display"), (4, "color"), (7, "unknown Event Stream type")])
def test_other_types_are_refused_at_the_type_byte(tmp_path: Path, kind: int, msg: str) -> None:
    path = tmp_path / "t.es"
    path.write_bytes(es_header(kind, 32, 32) + bytes(10))
    with pytest.raises(FormatError, match=msg) as e:
        read(path)
    assert e.value.offset == 15


def test_bad_headers(tmp_path: Path) -> None:
    path = tmp_path / "v.es"
    path.write_bytes(es_header(1, 32, 32, version=b"\x01\x00\x00"))
    with pytest.raises(FormatError, match="version 1.0.0") as e:
        read(path)
    assert e.value.offset == 12
    path.write_bytes(es_header(1, 32, 32)[:18])
    with pytest.raises(FormatError, match="inside the Event Stream header") as e:
        read(path)
    assert e.value.offset == 18
    path.write_bytes(es_header(1, 0, 32))
    with pytest.raises(FormatError, match="empty sensor"):
        read(path)
    path.write_bytes(es_header(1, 32, 32))
    with pytest.raises(FormatError, match="the file says sensor 32x32"):
        read(path, sensor="64x64")


def test_truncated_last_event(tmp_path: Path) -> None:
    """A file cut inside an event is named at the event's byte 0; with
    ``skip_bad`` the events before it are read and the cut one counted."""
    raw = es_encode(1, 8, 8, [(3, 1, 1, 1, False), (9, 2, 2, -1, False)])
    path = tmp_path / "c.es"
    path.write_bytes(raw[:-2])
    with pytest.raises(FormatError, match="truncated: 3 of its 5 bytes") as e:
        read(path)
    assert e.value.offset == len(raw) - 5
    events, _, src = read(path, skip_bad=True)
    assert events == [(3, 1, 1, 1)]
    assert src.skipped_events == 1 and src.skipped_ranges == [(len(raw) - 5, len(raw) - 3)]


def test_coordinates_outside_the_sensor(tmp_path: Path) -> None:
    """x or y past the header's size: raised at the event, or dropped and counted."""
    good = [(1, 1, 1, 1, False), (2, 3, 3, -1, False)]
    raw = es_encode(1, 8, 8, good)
    bad = bytes([1 << 1, 9, 0, 1, 0])  # x = 9 on an 8-wide sensor
    path = tmp_path / "o.es"
    path.write_bytes(raw[:25] + bad + raw[25:])
    with pytest.raises(FormatError, match=r"\(9, 6\) lies outside the 8x8 sensor") as e:
        read(path)
    assert e.value.offset == 25
    events, _, src = read(path, skip_bad=True)
    assert events == [(1, 1, 1, 1), (3, 3, 3, -1)] and src.skipped_events == 1
    path.write_bytes(raw[:25] + bytes([1 << 1, 2, 0, 9, 0]) + raw[25:])  # raw y = 9
    with pytest.raises(FormatError, match=r"\(2, 9\) lies outside the 8x8 sensor"):
        read(path)
    raw = es_encode(2, 8, 8, [(1, 1, 1, 1, True)])
    path.write_bytes(raw[:-2] + b"\x09\x00")  # raw y = 9: a crossing outside the sensor
    with pytest.raises(FormatError, match=r"threshold crossing \(1, 9\) lies outside") as e:
        read(path)
    assert e.value.offset == 20
    _, cross, src = read(path, skip_bad=True)
    assert cross == [] and src.skipped_events == 1 and src.skipped_ranges == [(20, 24)]


def test_shared_dvs_equals_its_csv_and_atis_has_the_same_events(shared: Path) -> None:
    """dvs.es and the CSV of the same events (top-left y) agree event for
    event; atis.es holds those events too, plus 852,792 threshold crossings."""
    csv = np.loadtxt(shared / "other/dvs.csv", delimiter=",", skiprows=1, dtype=np.int64)
    for name, crossings in (("dvs", 0), ("atis", 852_792)):
        src = open_file(str(shared / f"other/{name}.es"))
        pk = list(src.packets())
        ev = concat([q for q in pk if isinstance(q, EventPacket)])
        assert len(ev) == 473_225 and ev.sensor == (320, 240)
        for col, got in enumerate((ev.t, ev.x, ev.y, (ev.p > 0).astype(np.int64))):
            np.testing.assert_array_equal(got, csv[:, col])
        assert sum(len(q) for q in pk if isinstance(q, ExposurePacket)) == crossings


def test_equals_the_event_stream_package(shared: Path, tmp_path: Path) -> None:
    """The neuromorphic-systems reader (bottom-left y) on the shared files and a
    drawn-free generated ATIS file with every overflow code."""
    es = pytest.importorskip("event_stream")
    gen = tmp_path / "g.es"
    items = [(t * 61, t % 7, t % 5, 1 if t % 3 else -1, t % 2 == 0) for t in range(400)]
    gen.write_bytes(es_encode(2, 7, 5, items, {5, 50}, [1, 2, 3]))
    for path in (shared / "other/dvs.es", shared / "other/atis.es", gen):
        d = es.Decoder(str(path))
        ref = np.concatenate(list(d))
        events, cross, _ = read(path)
        cd = ref[~ref["exposure"]] if d.type == "atis" else ref
        on = cd["polarity"] if d.type == "atis" else cd["on"]
        assert events == list(zip(cd["t"].tolist(), cd["x"].tolist(), (d.height - 1 - cd["y"]).tolist(),
                                  np.where(on, 1, -1).tolist()))
        if d.type == "atis":
            tc = ref[ref["exposure"]]
            assert cross == list(zip(tc["t"].tolist(), tc["x"].tolist(), (d.height - 1 - tc["y"]).tolist(),
                                     tc["polarity"].tolist()))
