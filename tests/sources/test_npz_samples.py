"""Sample streams in ``.npz``: frames, maps and every other kind stacked
beside the events, read back exactly and interleaved with the events in
time order; files with sample streams only; memory stays flat."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sample_streams import splits

import tectum
from tectum import (
    EventPacket,
    FramePacket,
    ImuPacket,
    Kind,
    MapPacket,
    Packet,
    PosePacket,
    ResultPacket,
    SamplePacket,
    TrackPacket,
)
from tectum.cli import main
from tectum.sinks.npz import NpzSink
from tectum.sources import npz as npz_source
from tectum.sources.npz import NpzSource
from tectum.testing import assert_stream_contract, assert_streams_equal


def _write(path: Path, packets: list[Packet]) -> None:
    s = NpzSink(str(path))
    s.open()
    for q in packets:
        s.write(q)
    s.close()


def _recording(seed: int = 0) -> dict[str, Packet]:
    rng = np.random.default_rng(seed)
    n = 5000
    t = np.sort(rng.integers(0, 200_000, n))
    ev = EventPacket.from_arrays(t, rng.integers(0, 32, n), rng.integers(0, 24, n), rng.choice([-1, 1], n),
                                 sensor=(32, 24), t_start=0, t_end=200_000, columns={"vx": rng.normal(size=n)})
    ft = np.arange(1000, 200_000, 10_000)
    frames = FramePacket(ft, images=rng.integers(0, 4096, (len(ft), 24, 32, 3)).astype(np.uint16),
                         exposure_start=ft - 500, exposure_end=ft + 500, t_start=0, t_end=200_000)
    mt = np.array([0, 50_000, 50_000, 199_999])  # two maps at one time
    maps = MapPacket(mt, image=rng.normal(size=(4, 24, 32)).astype(np.float32),
                     depth=np.where(rng.random((4, 24, 32)) < 0.1, np.nan, 2.0).astype(np.float32),
                     confidence=rng.random((4, 24, 32)).astype(np.float32), K=np.tile(np.eye(3), (4, 1, 1)),
                     pose=rng.normal(size=(4, 7)), t_start=0, t_end=200_000)
    it = np.arange(0, 200_000, 997)
    imu = ImuPacket(it, accel=rng.normal(size=(len(it), 3)), gyro=rng.normal(size=(len(it), 3)), t_start=0,
                    t_end=200_000)
    poses = PosePacket([150_000], position=[[1.0, 2, 3]], orientation=[[0, 0, 0, 1.0]], t_start=100_000,
                       t_end=200_000)  # a stream that starts later
    return {"events": ev, "frames": frames, "maps": maps, "imu": imu, "poses": poses}


def _interleave(streams: dict[str, Packet], cuts: list[int]) -> list[Packet]:
    """The streams cut at the same times (µs), packet by packet in time order."""
    out: list[Packet] = []
    bounds = [0, *sorted(set(cuts)), 200_000]
    for a, b in zip(bounds, bounds[1:]):
        for s in streams.values():
            if b > s.t_start:
                out.append(s.slice_time(a, b))
    return out


def _check_order(got: list[Packet]) -> None:
    """Each stream keeps the packet contract; before an event packet comes
    every sample before its end; without events, packets come in the order
    of their ends."""
    by: dict[Kind, list[Packet]] = {}
    for q in got:
        by.setdefault(q.kind, []).append(q)
    for v in by.values():
        assert_stream_contract(v)
    ends = [q.t_end for q in got]
    assert Kind.EVENTS in by or ends == sorted(ends)
    every = {k: np.concatenate([q.t for q in v]) for k, v in by.items() if k != Kind.EVENTS}
    seen = dict.fromkeys(by, 0)
    for q in got:
        if isinstance(q, EventPacket):
            for k, t in every.items():
                assert seen[k] == int(np.searchsorted(t, q.t_end, side="left")), (q, k)
        seen[q.kind] += len(q)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.integers(1, 199_999), max_size=5), chunk=st.sampled_from([300, 1 << 20]),
       sample_bytes=st.sampled_from([1, 5000, 1 << 24]))
def test_round_trip_is_exact_and_in_time_order(tmp_path_factory, cuts: list[int], chunk: int, sample_bytes: int,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    rec = _recording()
    f = tmp_path_factory.mktemp("npz") / "r.npz"
    _write(f, _interleave(rec, cuts))
    monkeypatch.setattr(npz_source, "_SAMPLE_BYTES", sample_bytes)  # rows read at a time
    got = list(NpzSource(str(f), chunk_events=chunk).packets())
    assert_streams_equal(list(rec.values()), got)
    _check_order(got)


def test_the_layout_is_plain_arrays(tmp_path: Path) -> None:
    rec = _recording()
    f = tmp_path / "r.npz"
    _write(f, list(rec.values()))
    z = np.load(f)
    assert sorted(z.files) == sorted(
        ["t", "x", "y", "p", "vx", "sensor", "interval", "frames_t", "frames_images", "frames_exposure_start",
         "frames_exposure_end", "frames_interval", "maps_t", "maps_image", "maps_depth", "maps_confidence",
         "maps_K", "maps_pose", "maps_interval", "imu_t", "imu_accel", "imu_gyro", "imu_interval", "poses_t",
         "poses_position", "poses_orientation", "poses_interval"])
    assert z["frames_images"].shape == (20, 24, 32, 3) and z["frames_images"].dtype == np.uint16
    assert z["maps_K"].shape == (4, 3, 3) and z["poses_interval"].tolist() == [100_000, 200_000]
    assert np.array_equal(z["maps_depth"], rec["maps"].depth, equal_nan=True)  # type: ignore[attr-defined]


def test_samples_only_is_a_recording(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    rec = _recording()
    f = tmp_path / "maps.npz"
    _write(f, [rec["frames"], rec["maps"], rec["imu"]])
    assert "t" not in np.load(f).files
    monkeypatch.setattr(npz_source, "_SAMPLE_BYTES", 20_000)  # a few rows at a time: the streams interleave
    got = list(NpzSource(str(f)).packets())
    assert_streams_equal([rec["frames"], rec["maps"], rec["imu"]], got)
    _check_order(got)
    kinds = [q.kind for q in got]
    assert kinds.index(Kind.MAPS) < max(i for i, k in enumerate(kinds) if k == Kind.FRAMES)  # not one after the other
    capsys.readouterr()
    assert main(["info", str(f)]) == 0
    out = capsys.readouterr().out
    assert "frames 20, imu 201, maps 4" in out and "0 / 199999 µs" in out
    again = tmp_path / "again.npz"
    assert main(["run", str(f), "--sink", str(again)]) == 0
    assert_streams_equal(got, list(NpzSource(str(again)).packets()))


def test_optional_float_fields_missing_from_some_packets_are_nan(tmp_path: Path) -> None:
    a = TrackPacket([1, 2], id=[1, 2], x=[0.0, 1], y=[0.0, 1])
    b = TrackPacket([3], id=[3], x=[2.0], y=[2.0], quality=[0.5])
    c = TrackPacket([4], id=[4], x=[3.0], y=[3.0])
    f = tmp_path / "t.npz"
    _write(f, [a, b, c])
    got = list(NpzSource(str(f)).packets())
    assert_streams_equal([tectum.concat([a, b, c])], got)
    assert np.array_equal(np.load(f)["tracks_quality"], [np.nan, np.nan, 0.5, np.nan], equal_nan=True)


@pytest.mark.parametrize("second, why", [
    (FramePacket([5], images=np.zeros((1, 24, 33), np.uint8)), "changes from uint8 \\(24, 32\\)"),
    (FramePacket([5], images=np.zeros((1, 24, 32), np.uint8), exposure_start=[4]), "in some packets"),
])
def test_a_stream_that_changes_shape_is_refused(tmp_path: Path, second: SamplePacket, why: str) -> None:
    s = NpzSink(str(tmp_path / "f.npz"))
    s.open()
    s.write(FramePacket([1], images=np.zeros((1, 24, 32), np.uint8)))
    with pytest.raises(ValueError, match=why):
        s.write(second)
    s.abort()
    assert os.listdir(tmp_path) == []


def test_ticks_and_results_decide_nothing(tmp_path: Path) -> None:
    f = tmp_path / "f.npz"
    frames = [FramePacket.empty(0, 10), FramePacket([10], images=np.ones((1, 4, 5), np.int32), t_end=20),
              FramePacket.empty(20, 30)]
    _write(f, [*frames, ResultPacket([3], [{"a": 1}])])
    got = list(NpzSource(str(f)).packets())
    assert {q.kind for q in got} == {Kind.FRAMES} and (got[0].t_start, got[-1].t_end) == (0, 30)
    assert_streams_equal(frames, got)


def test_a_stream_of_ticks_only_comes_back_as_a_tick(tmp_path: Path) -> None:
    f = tmp_path / "f.npz"
    _write(f, [FramePacket.empty(0, 10), FramePacket.empty(10, 25)])
    assert [(q.kind, len(q), q.t_start, q.t_end) for q in NpzSource(str(f)).packets()] == [(Kind.FRAMES, 0, 0, 25)]


def test_an_event_column_named_like_a_sample_array_is_refused(tmp_path: Path) -> None:
    ev = EventPacket.from_arrays([1], [0], [0], [1], sensor=(2, 2), columns={"imu_bias": [0.5]})
    s = NpzSink(str(tmp_path / "f.npz"))
    s.write(ev)
    with pytest.raises(ValueError, match="event column 'imu_bias' would be taken for a field of the imu stream"):
        s.write(ImuPacket([2], accel=np.zeros((1, 3)), gyro=np.zeros((1, 3))))
    s.abort()


def test_frames_stream_in_flat_memory(tmp_path: Path) -> None:
    psutil = pytest.importorskip("psutil", reason="psutil not installed")
    proc = psutil.Process()
    f = tmp_path / "big.npz"
    frame = np.arange(720 * 1280, dtype=np.uint32).astype(np.uint8).reshape(1, 720, 1280)
    s = NpzSink(str(f))
    s.open()
    base = peak = proc.memory_info().rss
    for k in range(200):  # 184 MB of frames
        s.write(FramePacket([k * 1000], images=frame, t_start=k * 1000, t_end=(k + 1) * 1000))
        peak = max(peak, proc.memory_info().rss)
    s.close()
    assert peak - base < 60 * 2**20, f"writing: RSS grew by {(peak - base) >> 20} MiB"
    base = peak = proc.memory_info().rss
    n = 0
    for q in NpzSource(str(f)).packets():
        n += len(q)
        peak = max(peak, proc.memory_info().rss)
    assert n == 200
    assert peak - base < 80 * 2**20, f"reading: RSS grew by {(peak - base) >> 20} MiB"


def test_splits_helper_keeps_every_sample() -> None:  # the helper the round-trip tests lean on
    p = TrackPacket([1, 1, 2, 5, 5, 9], id=np.arange(6), x=np.zeros(6), y=np.zeros(6), t_end=12)
    parts = splits(p, [1, 3, 4, 0, 6])
    assert_stream_contract(parts)
    assert_streams_equal([p], parts) and parts[-1].t_end == 12


def test_the_streams_are_known_before_opening(tmp_path: Path) -> None:
    rec = _recording()
    both, samples = tmp_path / "both.npz", tmp_path / "samples.npz"
    _write(both, [rec["events"], rec["imu"]])
    _write(samples, [rec["maps"]])
    assert NpzSource.kinds_for(str(both), {}) == (Kind.EVENTS, Kind.IMU)
    assert NpzSource.kinds_for(str(samples), {}) == (Kind.MAPS,)


def test_the_simulators_ground_truth_file_opens_in_info_convert_and_run(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """``tectum simulate --out run.npz`` writes ``run.npz.truth.npz`` beside
    the events: it opens again as a recording of its poses, APS frames and
    IMU (the arrays as written, exactly), in ``tectum info``, ``convert``
    (the poses to TUM) and ``run``."""
    scene = tmp_path / "scene.toml"
    scene.write_text('sensor = [32, 24]\nbackground = { intensity = 0.5 }\npanorama = { texture = 0.5 }\n'
                     'motion = { angular_velocity = [0.0, 0.3, 0.0] }\n'
                     'davis = { imu_rate_hz = 1000, aps_rate_hz = 100, exposure_us = 2000 }\n')
    ev = tmp_path / "run.npz"
    assert main(["simulate", str(scene), "--duration", "50ms", "--out", str(ev), "-q"]) == 0
    truth_path = tmp_path / "run.npz.truth.npz"
    z = np.load(truth_path)
    capsys.readouterr()
    assert main(["info", str(truth_path)]) == 0
    out = capsys.readouterr().out
    assert f"poses {len(z['pose_t'])}" in out and "frames 5" in out and "imu 50" in out, out
    assert NpzSource.kinds_for(str(truth_path), {}) == (Kind.FRAMES, Kind.IMU, Kind.POSES)
    got = {k: tectum.concat([q for q in NpzSource(str(truth_path)).packets() if q.kind == k])
           for k in (Kind.POSES, Kind.FRAMES, Kind.IMU)}
    np.testing.assert_array_equal(got[Kind.POSES].t, z["pose_t"])
    np.testing.assert_array_equal(got[Kind.POSES].position, z["pose_position"])
    np.testing.assert_array_equal(got[Kind.POSES].orientation, z["pose_orientation"])
    np.testing.assert_array_equal(got[Kind.FRAMES].images, z["aps_images"])
    np.testing.assert_array_equal(got[Kind.FRAMES].exposure_start, z["aps_exposure_start"])
    np.testing.assert_array_equal(got[Kind.IMU].gyro, z["imu_gyro"])
    tum = tmp_path / "truth.tum"
    assert main(["convert", str(truth_path), str(tum), "-q"]) == 0
    rows = np.loadtxt(tum)
    np.testing.assert_allclose(rows[:, 0], z["pose_t"] * 1e-6)
    np.testing.assert_allclose(rows[:, 1:4], z["pose_position"], atol=1e-9)
    back = tmp_path / "back.npz"
    assert main(["run", str(truth_path), "--sink", str(back), "-q"]) == 0
    with np.load(back) as b:
        np.testing.assert_array_equal(b["poses_position"], z["pose_position"])
        np.testing.assert_array_equal(b["frames_images"], z["aps_images"])
    # the events beside it stay events only (the truth series are read from an archive without events)
    assert NpzSource.kinds_for(str(ev), {}) == (Kind.EVENTS,)
