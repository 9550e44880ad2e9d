"""AEDAT 4.0 event packets in every buffer layout, value by value.

The reader splits each packet's ``Event`` structs (int64 t, int16 x, int16
y, bool polarity, 3 padding bytes) with whole-word loads where the vector is
8-byte aligned in memory, and byte by byte where it is not. tectum's own
writer makes both: compressed packets are decompressed into an aligned
scratch buffer, while with ``compression="none"`` the reader splits the file
bytes in place, so a frame of odd size before an event packet leaves its
vector unaligned (a 1x1 frame puts it 5 bytes past a word). Hypothesis
draws a stream of event packets with frames of a drawn shape between them,
on a square and a non-square sensor (a swap of x and y is only visible on
the latter in size checks, never in values), writes it and compares every
event's t, x, y and p and every frame's time and pixels with what was
written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FramePacket, Packet
from tectum.sinks.files.aedat4 import write_aedat4
from tectum.sources.files.aedat4 import Aedat4Source

COMPRESSIONS = ["none", "lz4", "none", "zstd"]


@st.composite
def streams(draw: st.DrawFn, sensor: tuple[int, int]) -> list[Packet]:
    """A frame, event packets and more frames (one drawn shape) back to back in time."""
    w, h = sensor
    fh, fw = draw(st.integers(1, 7)), draw(st.integers(1, 7))
    out: list[Packet] = []
    clock = draw(st.integers(0, 1 << 40))
    kinds = ["frame", "events"] + draw(st.lists(st.sampled_from(["events", "frame"]), max_size=5))
    for kind in kinds:
        start = clock
        if kind == "frame":
            clock += draw(st.integers(1, 1000))
            img = np.array(draw(st.lists(st.integers(0, 255), min_size=fh * fw, max_size=fh * fw)), np.uint8)
            out.append(FramePacket(np.array([clock - 1], np.int64), images=img.reshape(1, fh, fw),
                                   t_start=start, t_end=clock))
            continue
        n = draw(st.integers(1, 40))
        t = start + np.cumsum(draw(st.lists(st.integers(0, 50), min_size=n, max_size=n)))
        x = draw(st.lists(st.integers(0, w - 1), min_size=n, max_size=n))
        y = draw(st.lists(st.integers(0, h - 1), min_size=n, max_size=n))
        p = draw(st.lists(st.sampled_from([-1, 1]), min_size=n, max_size=n))
        clock = int(t[-1]) + 1
        out.append(EventPacket.from_arrays(t, x, y, p, sensor=sensor, t_start=start, t_end=clock))
    return out


def _columns(pkts: list[Packet], kind: type) -> list[Packet]:
    return [q for q in pkts if isinstance(q, kind) and len(q)]


def check_round_trip(path: Path, written: list[Packet], compression: str) -> None:
    write_aedat4(str(path), written, compression=compression)
    got = list(Aedat4Source(str(path)).packets())
    ev_in, ev_out = _columns(written, EventPacket), _columns(got, EventPacket)
    for c in "txyp":
        want = np.concatenate([getattr(q, c) for q in ev_in]).tolist() if ev_in else []
        have = np.concatenate([getattr(q, c) for q in ev_out]).tolist() if ev_out else []
        assert have == want, f"column {c} ({compression})"
    assert all(q.sensor == written[0].sensor for q in ev_out if isinstance(written[0], EventPacket))
    fr_in, fr_out = _columns(written, FramePacket), _columns(got, FramePacket)
    assert [int(t) for q in fr_out for t in q.t] == [int(t) for q in fr_in for t in q.t]
    for a, b in zip([im for q in fr_in for im in q.images], [im for q in fr_out for im in q.images]):
        assert np.array_equal(np.asarray(b).reshape(a.shape), a)


@pytest.mark.parametrize("sensor", [(346, 260), (128, 128)], ids=["346x260", "128x128"])
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), compression=st.sampled_from(COMPRESSIONS))
def test_aedat4_events_and_frames_equal_what_was_written(tmp_path: Path, sensor: tuple[int, int],
                                                         data: st.DataObject, compression: str) -> None:
    written = data.draw(streams(sensor))
    check_round_trip(tmp_path / "s.aedat4", written, compression)


@pytest.mark.parametrize("sensor", [(346, 260), (128, 128)], ids=["346x260", "128x128"])
@pytest.mark.parametrize("frame", [(1, 1), (1, 3), (3, 5), (2, 3)])
def test_an_odd_frame_before_uncompressed_events(tmp_path: Path, sensor: tuple[int, int],
                                                 frame: tuple[int, int]) -> None:
    """A fixed unaligned case: a frame of 1-15 bytes, then events whose x and y all differ."""
    fh, fw = frame
    fr = FramePacket(np.array([5], np.int64), images=np.full((1, fh, fw), 7, np.uint8), t_start=0, t_end=10)
    x, y = [1, 2, 3, 200 % sensor[0]], [0, 9, 100, 127]
    ev = EventPacket.from_arrays([10, 20, 30, 31], x, y, [1, -1, 1, -1], sensor=sensor, t_start=10, t_end=40)
    check_round_trip(tmp_path / "odd.aedat4", [fr, ev], "none")
