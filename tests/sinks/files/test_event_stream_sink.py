"""The Event Stream 2.0 (.es) and N-MNIST (.bin) writers: byte for byte what
the specifications' slow encoders (tests/format_specs.py) make, in any packet
split; and the CLI's convert, info and run through them (the shared
recordings come back byte-identical)."""

from __future__ import annotations

import filecmp
from pathlib import Path

import numpy as np
import pytest
from format_specs import es_encode, nmnist_encode
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tectum import EventPacket, concat
from tectum.cli import main
from tectum.sinks.files._common import write_all
from tectum.sinks.files.event_stream import EventStreamSink
from tectum.sinks.files.nmnist import NmnistSink
from tectum.sources.files import open_file


@st.composite
def streams(draw: st.DrawFn) -> EventPacket:
    w, h = draw(st.sampled_from([(34, 34), (240, 180), (256, 240)]))
    n = draw(st.integers(1, 80))
    dt = draw(st.lists(st.one_of(st.integers(0, 3), st.sampled_from([126, 127, 128, 254]), st.integers(0, 1 << 20)),
                       min_size=n, max_size=n))
    t = np.cumsum(np.array(dt, np.int64))
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    return EventPacket.from_arrays(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.choice([-1, 1], n),
                                   sensor=(w, h), t_start=0, t_end=int(t[-1]) + 1)


def events(pkt: EventPacket) -> list[tuple[int, int, int, int]]:
    return list(zip(pkt.t.tolist(), pkt.x.tolist(), pkt.y.tolist(), pkt.p.tolist()))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pkt=streams(), split=st.integers(1, 100))
def test_writers_make_the_specified_bytes(tmp_path: Path, pkt: EventPacket, split: int) -> None:
    w, h = pkt.sensor
    es, nm = tmp_path / "o.es", tmp_path / "o.bin"
    write_all(EventStreamSink(str(es)), list(pkt.batches(split)))
    write_all(NmnistSink(str(nm)), list(pkt.batches(split)))
    assert es.read_bytes() == es_encode(1, w, h, [(*e, False) for e in events(pkt)])
    assert nm.read_bytes() == nmnist_encode(events(pkt))
    for path, kw in ((es, {}), (nm, {"sensor": f"{w}x{h}"})):
        back = concat([q for q in open_file(str(path), **kw).packets() if isinstance(q, EventPacket)])
        assert events(back) == events(pkt)


def test_nmnist_overflow_record_at_the_23_bit_boundary(tmp_path: Path) -> None:
    """2^23 - 1 µs still fits the field; 2^23 µs takes one overflow record."""
    pkt = EventPacket.from_arrays([0x7FFFFF, 0x800000], [1, 2], [3, 4], [1, -1], sensor=(34, 34), t_start=0)
    write_all(NmnistSink(str(tmp_path / "b.bin")), [pkt])
    raw = (tmp_path / "b.bin").read_bytes()
    assert raw == nmnist_encode(events(pkt)) and len(raw) == 15 and raw[5:10] == bytes([0, 240, 0, 0, 0])


def test_late_first_event_counts_from_the_first_packet(tmp_path: Path) -> None:
    """Neither format stores a time origin: a stream starting late is written
    from its first packet's start (kept as ``t0``), not as megabytes of
    overflow bytes or records."""
    t0 = 1_600_000_000_000_000
    pkt = EventPacket.from_arrays([t0 + 5, t0 + 300], [1, 2], [3, 4], [1, -1], sensor=(34, 34), t_start=t0)
    for cls, name in ((EventStreamSink, "l.es"), (NmnistSink, "l.bin")):
        sink = cls(str(tmp_path / name))
        write_all(sink, [pkt])
        assert sink.t0 == t0
        assert (tmp_path / name).stat().st_size < 20 + 5 * 5
        back = concat([q for q in open_file(str(tmp_path / name)).packets() if isinstance(q, EventPacket)])
        assert back.t.tolist() == [5, 300]


def test_sizes_the_formats_cannot_hold(tmp_path: Path) -> None:
    wide = EventPacket.from_arrays([1], [0], [0], [1], sensor=(65536, 4))
    with pytest.raises(ValueError, match="16-bit sizes"):
        write_all(EventStreamSink(str(tmp_path / "w.es")), [wide])
    with pytest.raises(ValueError, match="8-bit x and y < 240"):
        write_all(NmnistSink(str(tmp_path / "w.bin")), [EventPacket.from_arrays([1], [0], [0], [1], sensor=(304, 240))])
    assert list(tmp_path.iterdir()) == []


def test_cli_convert_info_run(shared: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """convert gives back the shared files byte for byte (ATIS to DVS: its
    events, the exposures said not written; to .npz: both streams); info and
    run read what convert wrote; the ECD text round-trips through .es."""
    other = shared / "other"
    for src, out in ((other / "dvs.es", "a.es"), (other / "nmnist_sample.bin", "n.bin")):
        assert main(["convert", str(src), str(tmp_path / out)]) == 0
        assert filecmp.cmp(src, tmp_path / out, shallow=False)
    assert main(["convert", str(other / "atis.es"), str(tmp_path / "b.es")]) == 0
    assert "not written: 852,792 exposures" in capsys.readouterr().err
    assert filecmp.cmp(other / "dvs.es", tmp_path / "b.es", shallow=False)
    assert main(["convert", str(other / "atis.es"), str(tmp_path / "b.npz")]) == 0  # npz keeps the exposures
    capsys.readouterr()
    assert main(["info", str(tmp_path / "b.npz")]) == 0
    assert "streams: events 473,225, exposures 852,792" in capsys.readouterr().out
    assert main(["info", str(tmp_path / "a.es")]) == 0
    assert "events: 473,225" in capsys.readouterr().out
    assert main(["run", str(tmp_path / "n.bin")]) == 0
    text = shared / "ecd/slider_depth/events.txt"
    assert main(["run", str(text), "--sink", str(tmp_path / "s.es")]) == 0
    a = concat([q for q in open_file(str(text), companions=False).packets() if isinstance(q, EventPacket)])
    b = concat([q for q in open_file(str(tmp_path / "s.es")).packets() if isinstance(q, EventPacket)])
    assert events(a) == events(b) and b.sensor == a.sensor
