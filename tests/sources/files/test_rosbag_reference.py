"""ROS bags against messages serialised by hand from the specs (tests/ros_bags.py).

Hypothesis draws a bag: ROS 1 (format 2.0, written here record by record) or
ROS 2 (CDR, little- or big-endian, in a folder rosbags' writer holds), one
event topic in one of the layouts tectum decodes from the message bytes
(``dvs_msgs/EventArray``; ``event_camera_msgs/EventPacket`` with ``evt3``
or ``libcaer`` payloads, either byte order), the events split over drawn
messages, plus ``sensor_msgs/Image`` in every supported encoding (row
padding, 16-bit big-endian data) or an unsupported one, and
``sensor_msgs/Imu``. What tectum reads must equal, value by value, what the
slow decoders below (written from the message definitions and the payload
formats) make of the same messages: t, x, y, p, triggers, frames, IMU.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("rosbags")

from ros_bags import dvs_event_array, event_packet, image, imu, ref_libcaer, ros2_bag, write_ros1_bag  # noqa: E402

from tectum import EventPacket, FormatError, FramePacket, ImuPacket, TriggerPacket  # noqa: E402
from tectum.sources.files.rosbag import RosbagSource  # noqa: E402

EPOCH_NS = 1_600_000_000_123_456_789
IMAGE = {"mono8": ("u1", 1), "8UC1": ("u1", 1), "mono16": ("u2", 1), "16UC1": ("u2", 1), "bgr8": ("u1", 3),
         "8UC3": ("u1", 3), "rgb8": ("u1", 3), "bgra8": ("u1", 4), "8UC4": ("u1", 4), "rgba8": ("u1", 4)}
TYPES = {"/events": None, "/image": "sensor_msgs/Image", "/imu": "sensor_msgs/Imu"}


# -- slow references, from the payload descriptions ------------------------------------
def ref_evt3(words: list[int]) -> tuple[list[tuple[int, int, int, int]], list[tuple[int, int, int]]]:
    """The EVT 3.0 words these tests write: ADDR_Y 0x0, ADDR_X 0x2 (an event,
    polarity bit 11), TIME_LOW 0x6, TIME_HIGH 0x8 (a fall by more than half
    its 12 bits is a 24-bit wrap), EXT_TRIGGER 0xA (id bits 11-8, value bit 0)."""
    events, triggers = [], []
    y = low = wraps = 0
    high = None
    for w in words:
        kind, v = w >> 12, w & 0xFFF
        if kind == 0x8:
            if high is not None and high - v > 1 << 11:
                wraps += 1
            high = v
        elif kind == 0x6:
            low = v
        elif kind == 0x0:
            y = v & 0x7FF
        elif high is not None and kind == 0x2:
            events.append(((wraps << 24) + (high << 12) + low, v & 0x7FF, y, 1 if v & 0x800 else -1))
        elif high is not None and kind == 0xA:
            triggers.append(((wraps << 24) + (high << 12) + low, (v >> 8) & 0xF, v & 1))
    return events, triggers


def ref_image(h: int, w: int, enc: str, big: bool, step: int, data: bytes) -> np.ndarray:
    """Rows of ``step`` bytes, the first ``w * channels * item`` of each the
    pixels; 16-bit in the message's byte order; RGB(A) turned to BGR(A)."""
    kind, ch = IMAGE[enc]
    dt = np.dtype(kind).newbyteorder(">" if big else "<")
    rows = [np.frombuffer(data[r * step:r * step + w * ch * dt.itemsize], dt) for r in range(h)]
    img = np.array(rows).astype(kind).reshape((h, w) if ch == 1 else (h, w, ch))
    return img[..., [2, 1, 0] + ([3] if ch == 4 else [])] if enc in ("rgb8", "rgba8") else img


# -- drawn bags -------------------------------------------------------------------------
@st.composite
def bags(draw: st.DrawFn, ros: int, be: bool, layout: str, pbe: bool) -> dict[str, Any]:
    """A bag of ROS ``ros`` (CDR big-endian: ``be``), events in ``layout``
    (EVT 3.0 payload words big-endian: ``pbe``), and what it holds."""
    w, h = draw(st.sampled_from([(64, 48), (346, 260), (640, 480)]))
    frame = draw(st.sampled_from(["", "c", "cam", "dvs0", "camera"]))  # CDR: the fields after it aligned anew
    n_msgs = draw(st.integers(1, 4))
    msgs: list[tuple[str, int, bytes]] = []  # (topic, receive time ns, raw)
    events: list[tuple[int, int, int, int]] = []
    triggers: list[tuple[int, int, int]] = []
    pixel = st.tuples(st.integers(0, w - 1), st.integers(0, h - 1), st.booleans())
    if layout == "dvs":
        t = EPOCH_NS
        for _ in range(n_msgs):
            evs = []
            for x, y, on in draw(st.lists(pixel, max_size=8)):
                t += draw(st.integers(0, 3_000_000))  # ns: sub-µs parts are truncated
                evs.append((t, x, y, on))
            events += [(tt // 1000, x, y, 1 if on else -1) for tt, x, y, on in evs]
            msgs.append(("/events", t, dvs_event_array(ros, be, t, w, h, evs, frame)))
    elif layout == "libcaer":
        start = draw(st.one_of(st.integers((1 << 31) - 3000, (1 << 31) - 1), st.integers(0, 1 << 33)))
        clock = start
        for k in range(n_msgs):
            pixels = draw(st.lists(pixel, max_size=8))
            clocks = [clock := clock + draw(st.integers(0, 2000)) for _ in pixels]
            # the host time of the clock's high bits at the packet's first event, ns
            base = EPOCH_NS + ((clocks[0] if clocks else clock) >> 31 << 31) * 1000
            payload = b""
            for (x, y, on), clock in zip(pixels, clocks):
                valid = draw(st.integers(0, 4)) > 0
                junk = draw(st.sampled_from([0, 1 << 31]))  # bit 31 of the time is not the clock's
                payload += struct.pack("<II", (x << 17) | (y << 2) | (int(on) << 1) | int(valid),
                                       (clock & 0x7FFFFFFF) | junk)
            events += ref_libcaer(payload, base)
            msgs.append(("/events", EPOCH_NS + clock * 1000, event_packet(ros, be, EPOCH_NS, w, h, k, base, "libcaer",
                                                                          False, payload, frame)))
    else:
        clock = draw(st.one_of(st.integers((1 << 24) - 3000, (1 << 24) - 1), st.integers(0, (1 << 24) - 1)))
        words: list[int] = []
        cuts = []
        for _ in range(n_msgs):
            for x, y, on in draw(st.lists(pixel, max_size=8)):
                clock += draw(st.integers(0, 5000))
                words += [0x8000 | (clock >> 12) & 0xFFF, 0x6000 | clock & 0xFFF, y, 0x2000 | (int(on) << 11) | x]
                if draw(st.integers(0, 3)) == 0:
                    words.append(0xA000 | draw(st.integers(0, 15)) << 8 | draw(st.integers(0, 1)))
            cuts.append(len(words))
        events, triggers = ref_evt3(words)
        for k, (a, b) in enumerate(zip([0] + cuts, cuts)):
            payload = struct.pack(f"{'>' if pbe else '<'}{b - a}H", *words[a:b])
            msgs.append(("/events", EPOCH_NS + k, event_packet(ros, be, EPOCH_NS, w, h, k, 0, "evt3", pbe, payload,
                                                                     frame)))
    frames, samples = [], []
    t0 = EPOCH_NS if layout != "evt3" else 0
    for k in range(draw(st.integers(0, 3))):
        enc = draw(st.sampled_from([*IMAGE, "yuv422"]))
        ih, iw = draw(st.integers(1, 4)), draw(st.integers(1, 4))
        kind, ch = IMAGE.get(enc, ("u1", 2))
        step = iw * ch * np.dtype(kind).itemsize + draw(st.integers(0, 3))
        data = draw(st.binary(min_size=ih * step, max_size=ih * step))
        big = draw(st.booleans())
        stamp = t0 + k * 1_000_000
        msgs.append(("/image", stamp, image(ros, be, stamp, ih, iw, enc, big, step, data)))
        if enc in IMAGE:
            frames.append((stamp // 1000, ref_image(ih, iw, enc, big, step, data)))
    finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
    for k in range(draw(st.integers(0, 3))):
        a, g = draw(st.lists(finite, min_size=3, max_size=3)), draw(st.lists(finite, min_size=3, max_size=3))
        stamp = t0 + k * 1_500_000 + 999
        msgs.append(("/imu", stamp, imu(ros, be, stamp, a, g)))
        samples.append((stamp // 1000, a, g))
    msgs.sort(key=lambda m: m[1])  # a bag's messages come in receive-time order
    topics = {"/events": {"dvs": "dvs_msgs/EventArray"}.get(layout, "event_camera_msgs/EventPacket"),
              "/image": "sensor_msgs/Image", "/imu": "sensor_msgs/Imu"}
    return dict(ros=ros, sensor=(w, h), msgs=msgs, topics=topics, events=events, triggers=triggers,
                frames=frames, imu=samples, undecoded=sum(1 for m in msgs if m[0] == "/image") - len(frames))


def write(path: Path, bag: dict[str, Any]) -> Path:
    if bag["ros"] == 1:
        write_ros1_bag(path.with_suffix(".bag"), bag["topics"], bag["msgs"])
        return path.with_suffix(".bag")
    ros2_bag(path, bag["topics"], bag["msgs"])
    return path


def read(path: Path, **kw: Any) -> tuple[dict[str, list[Any]], RosbagSource]:
    src = RosbagSource(str(path), **kw)
    got: dict[str, list[Any]] = {"events": [], "triggers": [], "frames": [], "imu": []}
    for q in src.packets():
        if isinstance(q, EventPacket):
            assert q.sensor == src._sensor(q.sensor)
            got["events"] += zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), q.p.tolist())
        elif isinstance(q, TriggerPacket):
            got["triggers"] += zip(q.t.tolist(), q.channel.tolist(), q.value.tolist())
        elif isinstance(q, FramePacket):
            got["frames"] += zip(q.t.tolist(), q.images)
        elif isinstance(q, ImuPacket):
            got["imu"] += zip(q.t.tolist(), q.accel.tolist(), q.gyro.tolist())
    return got, src


CASES = [(1, False, "dvs", False), (2, False, "dvs", False), (2, True, "dvs", False), (1, False, "libcaer", False),
         (2, True, "libcaer", False), (1, False, "evt3", False), (1, False, "evt3", True), (2, False, "evt3", True),
         (2, True, "evt3", False)]


@pytest.mark.parametrize("ros, be, layout, pbe", CASES)
def test_bag_equals_the_reference(tmp_path: Path, ros: int, be: bool, layout: str, pbe: bool) -> None:
    @settings(max_examples=10, deadline=None)
    @given(bag=bags(ros, be, layout, pbe))
    def check(bag: dict[str, Any]) -> None:
        equals_the_reference(write(tmp_path / f"b{len(list(tmp_path.iterdir()))}", bag), bag)
    check()


def equals_the_reference(path: Path, bag: dict[str, Any]) -> None:
    got, src = read(path)
    assert got["events"] == bag["events"]
    assert got["triggers"] == bag["triggers"]
    assert [t for t, _ in got["frames"]] == [t for t, _ in bag["frames"]]
    for (_, a), (_, b) in zip(got["frames"], bag["frames"]):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert got["imu"] == [(t, list(a), list(g)) for t, a, g in bag["imu"]]
    assert src.undecoded_messages == bag["undecoded"]
    if bag["events"]:
        src2 = RosbagSource(str(path))
        assert next(q for q in src2.packets() if isinstance(q, EventPacket)).sensor == bag["sensor"]


# -- the branches a drawn bag does not reach -----------------------------------------------
def _events_bag(tmp_path: Path, ros: int, raws: list[bytes], typ: str = "dvs_msgs/EventArray") -> Path:
    tmp_path.mkdir(exist_ok=True)
    msgs = [("/events", EPOCH_NS + k, raw) for k, raw in enumerate(raws)]
    return write(tmp_path / "e", dict(ros=ros, topics={"/events": typ}, msgs=msgs))


@pytest.mark.parametrize("ros", [1, 2])
def test_a_message_that_does_not_decode_is_named_or_skipped(tmp_path: Path, ros: int) -> None:
    good = dvs_event_array(ros, False, EPOCH_NS, 64, 48, [(EPOCH_NS, 1, 2, 1)])
    bad = bytearray(dvs_event_array(ros, False, EPOCH_NS, 64, 48, [(EPOCH_NS + 5000, 3, 4, 0)]))
    n_at = len(bad) - 13 - 4  # the event count, before the one 13-byte event (aligned in CDR too)
    struct.pack_into("<I", bad, n_at, 1000)  # more events than bytes
    path = _events_bag(tmp_path, ros, [good, bytes(bad), good[:-1] if ros == 1 else good[:-3]])
    with pytest.raises(FormatError, match=r"message 2 of /events \(dvs_msgs/msg/EventArray\) does not decode"):
        read(path)
    got, src = read(path, skip_bad=True)
    assert got["events"] == [(EPOCH_NS // 1000, 1, 2, 1)] and src.skipped_ranges == [(2, 3)]  # messages 2 and 3, merged


@pytest.mark.parametrize("ros", [1, 2])
def test_libcaer_cmp_packets_and_a_bad_word(tmp_path: Path, ros: int) -> None:
    """libcaer_cmp (the encoding's description in ``_ros_kernels``): TIME_HIGH
    2, TIME_LOW 7, ADDR_X 100, ADDR_Y 20 ON (one event), VECT_BASE_Y 30 OFF,
    VECT_8 0b101 (y 30 and 32), VECT_12 0b1 (y 38); code 9 is no word."""
    words = [(0 << 12) | 2, (1 << 12) | 7, (2 << 12) | 100, (3 << 12) | (1 << 11) | 20,
             (4 << 12) | 30, (5 << 12) | 0b101, (6 << 12) | 0b1]
    t = 1_000_000 + (2 << 12 | 7)
    want = [(t, 100, 20, 1), (t, 100, 30, -1), (t, 100, 32, -1), (t, 100, 38, -1)]
    raws = [event_packet(ros, False, EPOCH_NS, 346, 260, k, 1_000_000_000, "libcaer_cmp", be,
                         struct.pack(f"{'>' if be else '<'}{len(ws)}H", *ws))
            for k, (be, ws) in enumerate([(False, words), (True, words + [9 << 12])])]
    path = _events_bag(tmp_path, ros, raws, "event_camera_msgs/EventPacket")
    with pytest.raises(FormatError, match="invalid libcaer_cmp word 0x9000 at byte 14"):
        read(path)
    got, src = read(path, skip_bad=True)
    assert got["events"] == want + want and src.skipped_ranges == [(1, 1)]


@pytest.mark.parametrize("ros", [1, 2])
def test_evt3_bad_word_mono_and_undecoded_encodings(tmp_path: Path, ros: int) -> None:
    words = [0x8000, 0x6005, 0x0003, 0x2004, 0x1000, 0x2006]  # 0x1 is reserved
    raws = [event_packet(ros, False, 0, 64, 48, 9, 0, "evt3", False, struct.pack("<6H", *words)),
            event_packet(ros, False, 0, 64, 48, 10, 0, "mono", False, b"\x01\x02")]
    path = _events_bag(tmp_path, ros, raws, "event_camera_msgs/EventPacket")
    with pytest.raises(FormatError, match="invalid EVT3 word 0x1000 at byte 8"):
        read(path)
    got, src = read(path, skip_bad=True)
    assert got["events"] == [(5, 4, 3, -1), (5, 6, 3, -1)]
    assert src.skipped_ranges == [(9, 9)] and src.undecoded_messages == 1


@pytest.mark.parametrize("ros", [1, 2])
def test_image_shorter_than_its_rows_is_named(tmp_path: Path, ros: int) -> None:
    raw = image(ros, False, EPOCH_NS, 2, 3, "mono8", False, 3, b"\x00" * 5)
    path = write(tmp_path / "i", dict(ros=ros, topics={"/image": "sensor_msgs/Image"}, msgs=[("/image", 0, raw)]))
    with pytest.raises(FormatError, match=r"image 3x2 mono8 with step 3 has 5 bytes"):
        read(path)


def test_topics_and_sensor(tmp_path: Path) -> None:
    raw = event_packet(1, False, 0, 0, 0, 0, 0, "evt3", False, struct.pack("<4H", 0x8000, 0x6001, 0x0002, 0x2003))
    path = _events_bag(tmp_path, 1, [raw], "event_camera_msgs/EventPacket")
    with pytest.raises(FormatError, match="give no width/height"):
        read(path)
    got, src = read(path, sensor="8x8")
    assert got["events"] == [(1, 3, 2, -1)]
    with pytest.raises(FormatError, match=r"topics not in the bag: \['/nope'\]"):
        read(path, topics="/nope,/events")


@pytest.mark.parametrize("ros", [1, 2])
def test_time_window(tmp_path: Path, ros: int) -> None:
    evs = [(EPOCH_NS + k * 1000, k, k, k % 2) for k in range(20)]
    raws = [dvs_event_array(ros, False, EPOCH_NS, 64, 48, evs[k:k + 4]) for k in range(0, 20, 4)]
    path = _events_bag(tmp_path, ros, raws)
    lo, hi = EPOCH_NS // 1000 + 5, EPOCH_NS // 1000 + 11
    got, _ = read(path, t_start_us=lo, t_end_us=hi)
    assert got["events"] == [(t // 1000, x, y, 1 if p else -1) for t, x, y, p in evs if lo <= t // 1000 < hi]


def test_bag_root(tmp_path: Path) -> None:
    """A ROS 2 folder given by its metadata.yaml; a file that is neither is named."""
    raw = dvs_event_array(2, True, EPOCH_NS, 64, 48, [(EPOCH_NS, 1, 2, 1)])
    path = _events_bag(tmp_path, 2, [raw])
    got, _ = read(path / "metadata.yaml")
    assert got["events"] == [(EPOCH_NS // 1000, 1, 2, 1)]
    (tmp_path / "x.txt").write_text("no bag")
    with pytest.raises(FormatError, match="not a ROS 1 bag nor a ROS 2 bag folder"):
        read(tmp_path / "x.txt")


@pytest.mark.parametrize("encoding, words, want", [
    ("evt3", [0x8000, 0x6005, 0x0003, 0x2004, 0x2806], [(5, 4, 3, -1), (5, 6, 3, 1)]),
    ("libcaer_cmp", [(1 << 12) | 7, (2 << 12) | 100, (3 << 12) | (1 << 11) | 20], [(1_000_007, 100, 20, 1)]),
])
def test_big_endian_payload_words(tmp_path: Path, encoding: str, words: list[int], want: list) -> None:
    """``is_bigendian`` payloads: the same words in either byte order give
    the same events (the kernels take native-order words)."""
    for be in (False, True):
        raw = event_packet(1, False, 0, 346, 260, 1, 1_000_000_000, encoding, be,
                           struct.pack(f"{'>' if be else '<'}{len(words)}H", *words))
        got, _ = read(_events_bag(tmp_path / str(be), 1, [raw], "event_camera_msgs/EventPacket"))
        assert got["events"] == want, be
