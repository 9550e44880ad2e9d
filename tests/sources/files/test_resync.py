"""``skip_bad`` resynchronises after a bad record (issue 20, item 15).

One corrupt timestamp used to drop everything after it (the running maximum
stayed at the bad time: 80-95% of a file lost), or, falling by more than half
the 32-bit range, to count a false wrap and shift every later time by 2^32 µs.
Here files written by tectum's writers (or laid out from the format's spec)
get one record's time corrupted, or a short run of bytes overwritten; read
with ``skip_bad``, the rest must come out exactly as written, and the count
of dropped events must be exact.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from event_files import AEDAT2_DVS128_HEADER, aedat2_dvs128, dvs_bag

from tectum import EventPacket, concat
from tectum.sinks.files import SINKS
from tectum.sinks.files._common import write_all
from tectum.sources.files import open_file

pytestmark = pytest.mark.abuse

N = 6_000
CHUNK = 4096  # bytes read at a time: a few hundred records, so corruptions land near chunk edges too


def stream(n: int = N, w: int = 128, h: int = 128) -> EventPacket:
    """Strictly increasing times (each event identifies its record)."""
    rng = np.random.default_rng(7)
    t = 1_000 + np.cumsum(rng.integers(1, 40, n))
    return EventPacket.from_arrays(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.choice([-1, 1], n),
                                   sensor=(w, h))


# -- each format: a file of stream() and where record i's time lies -------------------------
def _sink_file(name: str, path: Path, ev: EventPacket) -> bytes:
    cls = next(c for c in SINKS if c.name == name)
    write_all(cls(str(path)), [ev])
    return path.read_bytes()


def dat_file(path: Path, ev: EventPacket) -> tuple[bytes, Callable[[int], tuple[int, str]]]:
    data = _sink_file("dat", path, ev)
    first = len(data) - 8 * len(ev)
    return data, lambda i: (first + 8 * i, "<u4")


def npy_file(path: Path, ev: EventPacket) -> tuple[bytes, Callable[[int], tuple[int, str]]]:
    data = _sink_file("npy", path, ev)
    dt = np.load(path, mmap_mode="r").dtype
    first = len(data) - dt.itemsize * len(ev)
    field, off = dt.fields["t"][0], dt.fields["t"][1]
    assert field == np.dtype("<i8")
    return data, lambda i: (first + dt.itemsize * i + off, "<i8")


def aedat2_file(path: Path, ev: EventPacket) -> tuple[bytes, Callable[[int], tuple[int, str]]]:
    data = aedat2_dvs128(ev)
    path.write_bytes(data)
    return data, lambda i: (len(AEDAT2_DVS128_HEADER) + 8 * i + 4, ">u4")


FORMATS = {"dat": (dat_file, ".dat"), "npy": (npy_file, ".npy"), "aedat2": (aedat2_file, ".aedat")}


def read(path: Path, **kw) -> tuple[EventPacket, object]:
    src = open_file(str(path), skip_bad=True, chunk_bytes=CHUNK, **kw)
    pkts = [q for q in src.packets() if isinstance(q, EventPacket)]
    for q in pkts:
        q.validate()
    return concat(pkts), src


def assert_same(got: EventPacket, want: EventPacket) -> None:
    assert len(got) == len(want)
    for c in "txyp":
        assert np.array_equal(getattr(got, c), getattr(want, c)), c


# which record, by where it falls
WHERE = {"middle": N // 2, "third": 2, "before-last": N - 2, "chunk-end": CHUNK // 8 - 1, "chunk-start": CHUNK // 8,
         "two-chunks-on": 2 * CHUNK // 8 - 1}
#: how the time is corrupted: a function of the good value
HOW = {"spike": lambda v: v + (1 << 30), "dip": lambda v: v // 3, "top": lambda v: 0xFFFFFFF0,
       "zero": lambda v: 0, "bit": lambda v: v ^ (1 << 29)}


@pytest.mark.parametrize("how", list(HOW))
@pytest.mark.parametrize("where", list(WHERE))
@pytest.mark.parametrize("fmt", list(FORMATS))
def test_one_corrupt_time_costs_one_event(tmp_path: Path, fmt: str, where: str, how: str) -> None:
    make, ext = FORMATS[fmt]
    ev = stream()
    f = tmp_path / ("c" + ext)
    data, at = make(f, ev)
    i = WHERE[where]
    pos, dt = at(i)
    raw = bytearray(data)
    good = int(np.frombuffer(raw, dt, 1, pos)[0])
    assert good == ev.t[i]
    raw[pos:pos + np.dtype(dt).itemsize] = np.array([HOW[how](good)], dt).tobytes()
    f.write_bytes(bytes(raw))
    got, src = read(f, **({"sensor": "128x128"} if fmt == "npy" else {}))
    keep = np.ones(N, bool)
    keep[i] = False
    assert src.skipped_events == 1, (len(got), src.skipped_events)
    assert_same(got, ev.select(keep))
    assert src.skipped_ranges[0][0] <= pos <= src.skipped_ranges[-1][1] + 8


@pytest.mark.parametrize("length", [3, 16, 40])
@pytest.mark.parametrize("fmt", list(FORMATS))
def test_a_short_run_of_bad_bytes_costs_only_its_records(tmp_path: Path, fmt: str, length: int) -> None:
    """Bytes overwritten with 0xFF across record boundaries: what is kept
    plus what is counted as skipped is every record, only records touched
    by the damage are lost, and everything kept was written."""
    make, ext = FORMATS[fmt]
    ev = stream()
    f = tmp_path / ("r" + ext)
    data, at = make(f, ev)
    pos = at(N // 2)[0] - 5
    raw = bytearray(data)
    raw[pos:pos + length] = b"\xff" * length
    f.write_bytes(bytes(raw))
    got, src = read(f, **({"sensor": "128x128"} if fmt == "npy" else {}))
    size = {"dat": 8, "aedat2": 8}.get(fmt) or np.load(tmp_path / ("r" + ext), mmap_mode="r").dtype.itemsize
    touched = length // size + 2
    assert len(got) + src.skipped_events == N
    assert src.skipped_events <= touched
    # every kept event is one written (records away from the damage are intact)
    rows = np.searchsorted(ev.t, got.t)
    rows = np.minimum(rows, N - 1)
    intact = (ev.t[rows] == got.t) & (ev.x[rows] == got.x) & (ev.y[rows] == got.y) & (ev.p[rows] == got.p)
    assert intact.sum() >= len(got) - touched
    assert np.array_equal(got.t[intact], ev.t[rows[intact]])


def test_dat_high_time_is_no_wrap(tmp_path: Path) -> None:
    """A time near the top of the 32-bit range between low ones used to count
    a wrap: every later event came out 71 minutes late, with no error."""
    ev = stream()
    f = tmp_path / "w.dat"
    data, at = dat_file(f, ev)
    raw = bytearray(data)
    pos = at(100)[0]
    raw[pos:pos + 4] = struct.pack("<I", 0xFFFFFF00)
    f.write_bytes(bytes(raw))
    got, src = read(f)
    assert int(got.t[-1]) == int(ev.t[-1]) and src.skipped_events == 1


# -- bags ------------------------------------------------------------------------------
@pytest.mark.parametrize("how", ["spike", "dip", "zero"])
def test_bag_one_corrupt_time_costs_one_event(tmp_path: Path, how: str) -> None:
    pytest.importorskip("rosbags")
    ev = stream(3_000)
    ev = EventPacket(ev.t + 1_600_000_000_000_000, ev.x, ev.y, ev.p, sensor=ev.sensor)
    f = tmp_path / "b.bag"
    dvs_bag(f, ev, per_msg=250)
    raw = bytearray(f.read_bytes())
    i = 1_234
    sec, us = divmod(int(ev.t[i]), 1_000_000)
    needle = struct.pack("<HHII", int(ev.x[i]), int(ev.y[i]), sec, us * 1000)
    pos = raw.index(needle) + 4
    assert raw.count(needle) == 1
    new = {"spike": sec + 1000, "dip": sec - 1000, "zero": 0}[how]
    raw[pos:pos + 4] = struct.pack("<I", new)
    f.write_bytes(bytes(raw))
    src = open_file(str(f), skip_bad=True)
    got = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    keep = np.ones(len(ev), bool)
    keep[i] = False
    assert src.skipped_events == 1
    assert_same(got, ev.select(keep))


# -- AEDAT 4.0: counts from the packet table ---------------------------------------------
def aedat4_file(path: Path, ev: EventPacket, compression: str = "lz4") -> list:
    from tectum.sinks.files.aedat4 import Aedat4Sink
    from tectum.sources.files.aedat4 import Aedat4Source

    write_all(Aedat4Sink(str(path), compression=compression, packet_events=500), [ev])
    return Aedat4Source(str(path)).packet_table()


@pytest.mark.parametrize("compression", ["lz4", "none"])
@pytest.mark.parametrize("damage", ["payload", "size"])
@pytest.mark.parametrize("ranged", [False, True])
def test_aedat4_bad_packet_counts_what_the_table_lists(tmp_path: Path, compression: str, damage: str,
                                                       ranged: bool) -> None:
    """One event packet damaged (its payload, or its header's size): the
    error names the packet; with skip_bad the events of that packet
    alone are lost, counted as the table lists them (kept + skipped = the
    table's total), on the streaming and the indexed (time range) paths."""
    from tectum import FormatError
    from tectum.sources.files.aedat4 import Aedat4Source

    ev = stream()
    f = tmp_path / "d.aedat4"
    table = aedat4_file(f, ev, compression)
    evs = [e for e in table if e.elements]
    bad = evs[len(evs) // 2]
    raw = bytearray(f.read_bytes())
    if damage == "payload":
        raw[bad.offset + 12:bad.offset + 40] = b"\xa5" * 28
    elif damage == "size":
        raw[bad.offset - 4:bad.offset] = (1 << 29).to_bytes(4, "little")
    f.write_bytes(bytes(raw))
    span = {"t_start_us": int(ev.t[0]), "t_end_us": int(ev.t[-1]) + 1} if ranged else {}
    with pytest.raises(FormatError) as e:
        list(Aedat4Source(str(f), **span).packets())
    assert e.value.offset == bad.offset - 8
    src = Aedat4Source(str(f), skip_bad=True, **span)
    got = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    assert len(got) + src.skipped_events == sum(e.elements for e in evs) == len(ev)
    assert src.skipped_events == bad.elements
    lost = (ev.t >= bad.t_first) & (ev.t <= bad.t_last)
    assert_same(got, ev.select(~lost))


def test_aedat4_info_says_its_counts_are_the_tables(tmp_path: Path, capsys) -> None:
    """``info`` counts from the packet table without decoding, and says so;
    with use_index=false it decodes, and a corrupt packet is an error."""
    from tectum.cli import main

    ev = stream()
    f = tmp_path / "i.aedat4"
    table = aedat4_file(f, ev)
    bad = [e for e in table if e.elements][3]
    raw = bytearray(f.read_bytes())
    raw[bad.offset + 12:bad.offset + 40] = b"\xa5" * 28
    f.write_bytes(bytes(raw))
    assert main(["info", str(f)]) == 0
    out = capsys.readouterr().out
    assert "6,000" in out and "from the file's packet table, not decoded" in out
    assert main(["info", f"{f}?use_index=false"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and f"at byte {bad.offset - 8}: packet of stream 0" in err[0]
