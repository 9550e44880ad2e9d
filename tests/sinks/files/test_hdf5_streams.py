"""HDF5 files hold the sample streams beside the events (frames, IMU,
triggers, poses ... one group per kind), and a sink says plainly what it did
not write (issue 20, item 5)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from davis_recording import counts, write_davis
from sink_inputs import samples

import tectum
from tectum import EventPacket, Kind, Packet, SamplePacket, concat, packet_class
from tectum.sinks.files._common import write_all

pytest.importorskip("h5py")

from tectum.sinks.files.hdf5 import Hdf5Sink  # noqa: E402
from tectum.sources.files.hdf5 import Hdf5Source  # noqa: E402

TECTUM = [sys.executable, "-m", "tectum"]
SAMPLE_KINDS = [k for k in Kind if k not in (Kind.EVENTS, Kind.RESULTS, Kind.ANY)]


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([*TECTUM, *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r


def by_kind(packets: list[Packet]) -> dict[str, Packet]:
    out: dict[str, list[Packet]] = {}
    for p in packets:
        out.setdefault(str(p.kind), []).append(p)
    return {k: concat(v) for k, v in out.items()}


def assert_same(a: Packet, b: Packet) -> None:
    assert a.kind == b.kind
    assert np.array_equal(a.t, b.t)
    if isinstance(a, EventPacket):
        assert isinstance(b, EventPacket) and a.sensor == b.sensor
        for c in "xyp":
            assert np.array_equal(a[c], b[c]), c
        return
    assert isinstance(a, SamplePacket) and isinstance(b, SamplePacket)
    assert set(a.data) == set(b.data)
    for name in a.data:
        assert a.data[name].dtype == b.data[name].dtype, name
        assert np.array_equal(a.data[name], b.data[name], equal_nan=a.data[name].dtype.kind == "f"), name


def test_davis_recording_converts_to_h5_with_every_stream(tmp_path: Path) -> None:
    packets = write_davis(tmp_path / "davis.npz")
    n = counts(packets)
    out = tmp_path / "out.h5"
    r = cli("convert", str(tmp_path / "davis.npz"), str(out))
    assert "3,000 events" in r.stdout and "10 frames, 200 imu samples, 16 triggers" in r.stdout
    assert "not written" not in r.stderr
    info = json.loads(cli("info", str(out), "--json").stdout)
    assert info["streams"] == n
    back = by_kind(list(Hdf5Source(str(out)).packets()))
    for kind, want in by_kind(packets).items():
        assert_same(back[kind], want)
    assert back["frames"].images.dtype == np.uint8 and back["frames"].images.shape == (10, 26, 34)
    with __import__("h5py").File(out) as h:  # a plain HDF5 reader sees the documented layout
        assert h["imu"].attrs["kind"] == "imu" and h["imu/gyro"].shape == (200, 3)
        assert h["imu/gyro"].attrs["unit"] == "rad/s" and h["imu/t"].dtype == np.int64
        assert h["frames/images"].compression == "gzip" and h["frames/images"].chunks[1:] == (26, 34)


def test_real_davis346_keeps_frames_triggers_and_imu(shared: Path, tmp_path: Path) -> None:
    src = shared / "aedat/davis346.aedat4"
    out = tmp_path / "davis346.h5"
    r = cli("convert", str(src), str(out))
    assert "78,830 events, 59 frames, 2,363 imu samples, 236 triggers" in r.stdout, r.stdout
    assert "not written" not in r.stderr
    want = by_kind(list(tectum.sources.files.open_file(str(src)).packets()))
    back = by_kind(list(Hdf5Source(str(out)).packets()))
    assert set(back) == set(want)
    for kind in want:
        assert_same(back[kind], want[kind])


@pytest.mark.parametrize("kind", SAMPLE_KINDS, ids=str)
def test_every_sample_kind_round_trips(kind: Kind, tmp_path: Path) -> None:
    pkt = samples(kind)
    assert isinstance(pkt, SamplePacket)
    if kind in (Kind.FRAMES, Kind.MAPS):  # images of a size
        cls = packet_class(kind)
        name = "images" if kind == Kind.FRAMES else "depth"
        pkt = cls(pkt.t, t_start=pkt.t_start, t_end=pkt.t_end + 500, **{**pkt.data, name: np.arange(
            len(pkt) * 12, dtype=np.float32).reshape(len(pkt), 3, 4)})
    first, rest = pkt.split_at(int(pkt.t[10]))
    path = tmp_path / "s.h5"
    write_all(Hdf5Sink(str(path)), [first, rest])
    back = [q for q in Hdf5Source(str(path)).packets() if q.kind == kind]
    assert_same(concat(back), pkt)
    assert (back[0].t_start, back[-1].t_end) == (pkt.t_start, pkt.t_end)


def test_optional_field_missing_from_part_of_a_stream_is_nan(tmp_path: Path) -> None:
    a = tectum.ImuPacket([10, 20], accel=np.ones((2, 3)), gyro=np.zeros((2, 3)), t_start=0, t_end=30)
    b = tectum.ImuPacket([30], accel=np.ones((1, 3)), gyro=np.zeros((1, 3)), temperature=[25.0], t_start=30,
                         t_end=40)
    path = tmp_path / "imu.h5"
    write_all(Hdf5Sink(str(path)), [a, b, tectum.ImuPacket.empty(40, 50)])
    back = concat([q for q in Hdf5Source(str(path)).packets() if q.kind == Kind.IMU])
    assert np.array_equal(back.temperature, [np.nan, np.nan, 25.0], equal_nan=True)
    assert (back.t_start, back.t_end) == (0, 50)


def test_time_range_and_relative_times_apply_to_the_streams(tmp_path: Path) -> None:
    write_davis(tmp_path / "davis.npz")
    cli("convert", str(tmp_path / "davis.npz"), str(tmp_path / "out.h5"))
    cut = by_kind(list(Hdf5Source(str(tmp_path / "out.h5"), t_start_us=1_050_000, t_end_us=1_100_000).packets()))
    for kind, pkt in cut.items():
        assert len(pkt) and pkt.t[0] >= 1_050_000 and pkt.t[-1] < 1_100_000, kind
    assert len(cut["imu"]) == 50 and len(cut["frames"]) == 2  # at 1,065,000 and 1,085,000 µs
    rel = by_kind(list(Hdf5Source(str(tmp_path / "out.h5"), apply_t0=False).packets()))
    assert rel["events"].t[0] < 10_000 and rel["imu"].t[0] == 0  # one clock: t_offset is the first event's packet start


def test_results_are_said_not_written(tmp_path: Path) -> None:
    sink = Hdf5Sink(str(tmp_path / "r.h5"))
    write_all(sink, [tectum.ResultPacket([1, 2], items=[{"a": 1}, None])])
    assert sink.not_written == {"results": 2}


def test_a_format_that_holds_events_only_says_what_it_left_out(tmp_path: Path) -> None:
    write_davis(tmp_path / "davis.npz")
    raw = tmp_path / "out.raw"
    want = f"{raw}: not written: 10 frames, 200 imu samples, 16 triggers (EVT 2.0 holds events only)"
    r = cli("convert", str(tmp_path / "davis.npz"), str(raw))
    assert r.stderr.strip() == want and r.stdout.strip() == f"3,000 events -> {raw}"
    r = cli("run", str(tmp_path / "davis.npz"), "--sink", str(raw), "-q")
    assert r.stderr.strip() == want
    r = cli("convert", str(tmp_path / "davis.npz"), str(tmp_path / "out.aedat4"))
    assert r.stderr.strip() == (f"{tmp_path / 'out.aedat4'}: not written: 16 triggers "
                                "(AEDAT 4.0 holds events, frames and imu only)")
