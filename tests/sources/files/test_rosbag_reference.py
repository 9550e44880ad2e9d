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

import pytest

pytest.importorskip("rosbags")

from ros_bags import event_packet, ros2_bag, write_ros1_bag  # noqa: E402

from tectum import EventPacket, FramePacket, ImuPacket, TriggerPacket  # noqa: E402
from tectum.sources.files.rosbag import RosbagSource  # noqa: E402

EPOCH_NS = 1_600_000_000_123_456_789
IMAGE = {"mono8": ("u1", 1), "8UC1": ("u1", 1), "mono16": ("u2", 1), "16UC1": ("u2", 1), "bgr8": ("u1", 3),
         "8UC3": ("u1", 3), "rgb8": ("u1", 3), "bgra8": ("u1", 4), "8UC4": ("u1", 4), "rgba8": ("u1", 4)}
TYPES = {"/events": None, "/image": "sensor_msgs/Image", "/imu": "sensor_msgs/Imu"}


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


def _events_bag(tmp_path: Path, ros: int, raws: list[bytes], typ: str = "dvs_msgs/EventArray") -> Path:
    tmp_path.mkdir(exist_ok=True)
    msgs = [("/events", EPOCH_NS + k, raw) for k, raw in enumerate(raws)]
    return write(tmp_path / "e", dict(ros=ros, topics={"/events": typ}, msgs=msgs))


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
