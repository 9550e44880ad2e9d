"""ROS 1 / ROS 2 bags: the shared recordings decode with the MANIFEST's counts,
bags written here with rosbags (ROS 1 and CDR serialisation) read back
exactly, and the payload kernels agree with slow reference decoders."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from ros_bags import ref_libcaer  # noqa: E402

from tectum import EventPacket, FormatError, concat, get_registry  # noqa: E402
from tectum.sources.files import _ros_kernels as R  # noqa: E402
from tectum.sources.files import open_file  # noqa: E402
from tectum.sources.files.rosbag import RosbagSource, typestore  # noqa: E402

from helpers import decodes_or_names  # noqa: E402


def read(path, **kw):
    src = open_file(str(path), **kw)
    by: dict[str, list] = {}
    for q in src.packets():
        by.setdefault(str(q.kind), []).append(q)
    return {k: concat(v) for k, v in by.items()}, src


# -- shared recordings -------------------------------------------------------------
@pytest.mark.parametrize("rel, n, on, sensor, triggers", [
    ("bags/evt3_eventpacket_ros1.bag", 343_474, 125_183, (640, 480), 4_157),
    ("bags/evt3_eventpacket_ros2_sqlite", 343_474, 125_183, (640, 480), 4_157),
    ("bags/libcaer_rollover_ros2_sqlite", 334_331, None, (640, 480), 0),
])
def test_manifest_counts(shared: Path, rel: str, n: int, on, sensor, triggers) -> None:
    assert get_registry().source_for(str(shared / rel)) is RosbagSource
    got, src = read(shared / rel)
    ev = got["events"]
    ev.validate()
    assert len(ev) == n and ev.sensor == sensor
    if on is not None:
        assert int((ev.p > 0).sum()) == on
    assert len(got.get("triggers", [])) == triggers


def test_ros1_and_ros2_evt3_bags_agree(shared: Path) -> None:
    a, _ = read(shared / "bags/evt3_eventpacket_ros1.bag")
    b, _ = read(shared / "bags/evt3_eventpacket_ros2_sqlite" / "metadata.yaml")
    for c in "txyp":
        assert np.array_equal(getattr(a["events"], c), getattr(b["events"], c))
    assert np.array_equal(a["triggers"].value, b["triggers"].value)


def test_libcaer_rollover_is_monotonic_and_absolute(shared: Path) -> None:
    got, _ = read(shared / "bags/libcaer_rollover_ros2_sqlite")
    t = got["events"].t
    assert np.all(np.diff(t) >= 0)
    # µs since the epoch: the bag was recorded on 2023-12-11
    assert 1_702_300_000_000_000 < t[0] < t[-1] < 1_702_400_000_000_000


def test_libcaer_cmp_mcap_with_empty_storage_id(shared: Path) -> None:
    got, _ = read(shared / "bags/libcaer_cmp_ros2_mcap")
    ev = got["events"]
    ev.validate()
    assert ev.sensor == (346, 260)
    # no independent decoder here: a regression count for the published layout
    assert len(ev) == 571_266


def test_dvs_msgs_bag_equals_ecd_text(shared: Path) -> None:
    got, _ = read(shared / "derived/slider_depth_excerpt_dvs_msgs.bag")
    txt, _ = read(shared / "ecd/slider_depth/events.txt", companions=False)
    ev, ref = got["events"], txt["events"]
    assert len(ev) == 50_000
    for c in "xyp":
        assert np.array_equal(getattr(ev, c), getattr(ref, c))
    assert np.array_equal(ev.t - 1_468_939_993_000_000, ref.t)
    assert len(got["frames"]) == 6


def test_topic_selection(shared: Path) -> None:
    got, _ = read(shared / "derived/slider_depth_excerpt_dvs_msgs.bag", topics="/dvs/image_raw")
    assert set(got) == {"frames"}
    with pytest.raises(FormatError, match="not in the bag"):
        read(shared / "derived/slider_depth_excerpt_dvs_msgs.bag", topics="/nope")


# -- bags written here ---------------------------------------------------------------
def _msgs(ts, events: EventPacket):
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    stamp = Time(sec=int(events.t[0] // 1_000_000), nanosec=int(events.t[0] % 1_000_000) * 1000)
    hdr = {"stamp": stamp, "frame_id": "cam"}
    evs = [T["dvs_msgs/msg/Event"](x=int(x), y=int(y), ts=Time(sec=int(t // 1_000_000),
                                   nanosec=int(t % 1_000_000) * 1000 + 999), polarity=bool(p > 0))
           for t, x, y, p in zip(events.t, events.x, events.y, events.p)]
    return hdr, evs


def _write_bag(path: Path, ros: int, packets: list[EventPacket]) -> None:
    ts = typestore(ros)
    T = ts.types
    V3 = T["geometry_msgs/msg/Vector3"]
    if ros == 1:
        from rosbags.rosbag1 import Writer
        ser = ts.serialize_ros1
        Header = lambda **k: T["std_msgs/msg/Header"](seq=0, **k)  # noqa: E731
    else:
        from rosbags.rosbag2 import Writer
        ser = ts.serialize_cdr
        Header = T["std_msgs/msg/Header"]
    with Writer(path) if ros == 1 else Writer(path, version=8) as w:
        ce = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=ts)
        ci = w.add_connection("/dvs/imu", "sensor_msgs/msg/Imu", typestore=ts)
        cf = w.add_connection("/dvs/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        for k, pkt in enumerate(packets):
            hdr, evs = _msgs(ts, pkt)
            msg = T["dvs_msgs/msg/EventArray"](header=Header(**hdr), height=48, width=64, events=evs)
            ns = int(pkt.t[0]) * 1000
            w.write(ce, ns, ser(msg, "dvs_msgs/msg/EventArray"))
            cov = np.zeros(9)
            imu = T["sensor_msgs/msg/Imu"](header=Header(**hdr), orientation=T["geometry_msgs/msg/Quaternion"](
                x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=cov, angular_velocity=V3(x=0.1 * k, y=0.0, z=0.0),
                angular_velocity_covariance=cov, linear_acceleration=V3(x=0.0, y=9.8, z=0.0),
                linear_acceleration_covariance=cov)
            w.write(ci, ns, ser(imu, "sensor_msgs/msg/Imu"))
            img = np.arange(48 * 64 * 3, dtype=np.uint8).reshape(48, 64, 3) + k
            im = T["sensor_msgs/msg/Image"](header=Header(**hdr), height=48, width=64, encoding="rgb8",
                                            is_bigendian=0, step=64 * 3, data=img.reshape(-1))
            w.write(cf, ns, ser(im, "sensor_msgs/msg/Image"))


@pytest.mark.parametrize("ros", [1, 2])
def test_written_bag_reads_back(tmp_path: Path, small_stream: EventPacket, ros: int) -> None:
    ev = small_stream.slice_time(0, 6_000)
    ev = EventPacket(ev.t + 1_600_000_000_000_000, ev.x, ev.y, ev.p, sensor=ev.sensor)
    parts = [q for q in ev.batches(len(ev) // 3 + 1) if len(q)]
    path = tmp_path / ("b.bag" if ros == 1 else "b2")
    _write_bag(path, ros, parts)
    got, _ = read(path)
    e = got["events"]
    assert e.sensor == (64, 48)
    for c in "txyp":  # the 999 ns added to each stamp are truncated
        assert np.array_equal(getattr(e, c), getattr(ev, c))
    assert len(got["imu"]) == len(parts) and np.allclose(got["imu"].accel[:, 1], 9.8)
    f = got["frames"].images
    assert f.shape == (len(parts), 48, 64, 3)
    rgb = np.arange(48 * 64 * 3, dtype=np.uint8).reshape(48, 64, 3)
    assert np.array_equal(f[0], rgb[..., ::-1])  # rgb8 comes out as BGR


def test_several_event_topics_need_a_choice(tmp_path: Path, small_stream: EventPacket) -> None:
    from rosbags.rosbag2 import Writer

    ts = typestore(2)
    with Writer(tmp_path / "two", version=8) as w:
        for name in ("/a/events", "/b/events"):
            w.add_connection(name, "dvs_msgs/msg/EventArray", typestore=ts)
    with pytest.raises(FormatError, match="several event topics"):
        read(tmp_path / "two")


# -- payload kernels against slow references -------------------------------------------
def test_libcaer_kernel_with_rollover() -> None:
    rng = np.random.default_rng(1)
    ts = [(1 << 31) - 30, (1 << 31) - 5, 3, 40]
    raw = b"".join(struct.pack("<Ii", (int(rng.integers(640)) << 17) | (int(rng.integers(480)) << 2)
                               | (int(rng.integers(2)) << 1) | int(v), t)
                   for t, v in zip(ts, [1, 1, 0, 1]))
    base = 1_700_000_000_123_456_789
    n = len(raw) // 8
    t, x, y, p = np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16), np.empty(n, np.int8)
    k, inval, rolls = R.libcaer_events(np.frombuffer(raw, np.uint8), base, t, x, y, p)
    assert (inval, rolls) == (1, 1)
    got = list(zip(t[:k].tolist(), x[:k].tolist(), y[:k].tolist(), p[:k].tolist()))
    assert got == ref_libcaer(raw, base)
    assert t[2] - t[1] == 40 + (1 << 31) - ((1 << 31) - 5)


def test_libcaer_cmp_kernel() -> None:
    words = np.array([(0 << 12) | 2, (1 << 12) | 7, (2 << 12) | 100, (3 << 12) | (1 << 11) | 20,
                      (4 << 12) | 30, (5 << 12) | 0b101, (6 << 12) | 0b1, (9 << 12)], np.uint16)
    t, x, y = np.empty(40, np.int64), np.empty(40, np.uint16), np.empty(40, np.uint16)
    p = np.empty(40, np.int8)
    n, bad, nbad = R.libcaer_cmp_events(words, 1000, np.zeros(R.LIBCAER_CMP_STATE, np.int64), t, x, y, p)
    assert (bad, nbad) == (7, 1)
    tt = 1000 + (2 << 12 | 7)
    assert list(zip(t[:n].tolist(), x[:n].tolist(), y[:n].tolist(), p[:n].tolist())) == [
        (tt, 100, 20, 1), (tt, 100, 30, -1), (tt, 100, 32, -1), (tt, 100, 38, -1)]


def test_fuzz_mutated_bag(tmp_path: Path, small_stream: EventPacket) -> None:
    """Truncated or bit-flipped ROS 1 bags give FormatError or valid packets."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    ev = small_stream.slice_time(0, 3_000)
    ev = EventPacket(ev.t + 1_600_000_000_000_000, ev.x, ev.y, ev.p, sensor=ev.sensor)
    _write_bag(tmp_path / "b.bag", 1, [q for q in ev.batches(len(ev) // 2 + 1) if len(q)])
    good = (tmp_path / "b.bag").read_bytes()

    @settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck))
    @given(cut=st.integers(0, len(good)), flips=st.lists(st.tuples(st.integers(0, len(good) - 1),
                                                                   st.integers(0, 255)), max_size=6))
    def run(cut, flips):
        raw = bytearray(good)
        for i, v in flips:
            raw[i] = v
        f = tmp_path / "m.bag"
        f.write_bytes(bytes(raw[:cut]) if not flips else bytes(raw))
        decodes_or_names(RosbagSource(str(f)), f)
    run()


@pytest.mark.parametrize("ros", [1, 2])
@pytest.mark.parametrize("frame_id, encoding", [("", "evt3"), ("cam0", "libcaer_cmp"), ("a_longer_frame", "mono")])
def test_event_packet_fields_read_directly(ros: int, frame_id: str, encoding: str) -> None:
    """The hand parser of EventPacket gives what rosbags' deserializer gives,
    whatever the string lengths do to the CDR alignment; a cut message is
    a ValueError."""
    from rosbags.typesys.stores.ros2_humble import builtin_interfaces__msg__Time as Time

    from tectum.sources.files.rosbag import event_packet_fields

    ts = typestore(ros)
    T = ts.types
    hdr = dict(stamp=Time(sec=12, nanosec=345), frame_id=frame_id)
    header = T["std_msgs/msg/Header"](seq=7, **hdr) if ros == 1 else T["std_msgs/msg/Header"](**hdr)
    events = np.arange(37, dtype=np.uint8)
    msg = T["event_camera_msgs/msg/EventPacket"](header=header, height=480, width=640, seq=2**40 + 3,
                                                  time_base=2**50 + 9, encoding=encoding, is_bigendian=True,
                                                  events=events)
    raw = bytes((ts.serialize_ros1 if ros == 1 else ts.serialize_cdr)(msg, "event_camera_msgs/msg/EventPacket"))
    w, h, seq, time_base, enc, big, data = event_packet_fields(raw, ros)
    assert (w, h, seq, time_base, enc, big) == (640, 480, 2**40 + 3, 2**50 + 9, encoding, True)
    assert np.array_equal(data, events)
    with pytest.raises(ValueError):
        event_packet_fields(raw[:-5], ros)


@pytest.mark.abuse
@pytest.mark.parametrize("compression", ["none", "bz2"])
def test_cut_bag_names_the_offset_and_keeps_what_is_complete(tmp_path: Path, small_stream: EventPacket,
                                                             compression: str) -> None:
    """A ROS 1 bag cut short loses its index (written last), so it does not
    open: the error gives the byte where the complete records end; with
    skip_bad, every message wholly before the cut is read (uncompressed
    chunks; compressed ones down to the last complete chunk)."""
    from rosbags.rosbag1 import Reader, Writer

    ev = small_stream.slice_time(0, 6_000)
    ev = EventPacket(ev.t + 1_600_000_000_000_000, ev.x, ev.y, ev.p, sensor=ev.sensor)
    ts = typestore(1)
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    path = tmp_path / "full.bag"
    w = Writer(path)
    if compression == "bz2":
        w.set_compression(Writer.CompressionFormat.BZ2)
    w.chunk_threshold = 1500  # several chunks
    with w:
        c = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=ts)
        for q in ev.batches(40):
            evs = [T["dvs_msgs/msg/Event"](x=int(x), y=int(y), ts=Time(sec=int(t) // 1_000_000,
                   nanosec=int(t) % 1_000_000 * 1000), polarity=bool(p > 0)) for t, x, y, p in zip(q.t, q.x, q.y, q.p)]
            msg = T["dvs_msgs/msg/EventArray"](header=T["std_msgs/msg/Header"](seq=0, stamp=evs[0].ts, frame_id="c"),
                                               height=48, width=64, events=evs)
            w.write(c, int(q.t[0]) * 1000, ts.serialize_ros1(msg, "dvs_msgs/msg/EventArray"))
    data = path.read_bytes()
    with Reader(path) as r:  # where each message's record ends in the file (uncompressed chunks)
        ends = [data.index(raw) + len(raw) for _, _, raw in r.messages()] if compression == "none" else None
    n_per = [len(q) for q in ev.batches(40)]
    first = 13 + 8 + sum(struct.unpack_from("<i", data, 13 + k)[0] for k in (0, 4 + struct.unpack_from("<i", data, 13)[0]))
    for cut in (first + (len(data) - first) // 3, first + (len(data) - first) // 2 + 7, len(data) - 30):
        f = tmp_path / "cut.bag"
        f.write_bytes(data[:cut])
        with pytest.raises(FormatError, match="cut short") as e:
            list(RosbagSource(str(f)).packets())
        assert 13 < e.value.offset <= cut
        src = RosbagSource(str(f), skip_bad=True)
        got = concat([q for q in src.packets() if isinstance(q, EventPacket)])
        assert len(got) and src.skipped_events == 1 and src.skipped_ranges == [(e.value.offset, cut - 1)]
        for col in "txyp":
            assert np.array_equal(getattr(got, col), getattr(ev, col)[:len(got)])
        if ends is not None:
            assert len(got) == sum(k for k, end in zip(n_per, ends) if end <= cut)
