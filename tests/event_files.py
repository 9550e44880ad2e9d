"""Small event files laid out from the formats' descriptions, for the
readers' damage and resynchronisation tests: jAER AEDAT 2.0 (DVS128
layout) and ROS 1 bags of ``dvs_msgs/EventArray`` (written with rosbags)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tectum import EventPacket

AEDAT2_DVS128_HEADER = b"#!AER-DAT2.0\r\n# AEChip: ch.unizh.ini.jaer.chip.retina.DVS128\r\n"


def aedat2_dvs128(ev: EventPacket) -> bytes:
    """jAER DVS128 layout: the header, then big-endian (address, time µs)
    pairs; x stored mirrored (127 - x), y from the bottom (127 - y), bit 0
    set for OFF."""
    pairs = np.empty((len(ev), 2), ">u4")
    pairs[:, 0] = ((127 - ev.y.astype(np.int64)) << 8) | ((127 - ev.x.astype(np.int64)) << 1) | (ev.p < 0)
    pairs[:, 1] = ev.t
    return AEDAT2_DVS128_HEADER + pairs.tobytes()


def dvs_bag(path: Path, ev: EventPacket, per_msg: int = 100) -> bytes:
    """A ROS 1 bag of ``dvs_msgs/EventArray`` messages of ``per_msg``
    events (``ev.t`` in µs since the epoch); its bytes."""
    from rosbags.rosbag1 import Writer

    from tectum.sources.files.rosbag import typestore

    ts = typestore(1)
    T = ts.types
    Time, Event = T["builtin_interfaces/msg/Time"], T["dvs_msgs/msg/Event"]
    with Writer(path) as w:
        c = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=ts)
        for k in range(0, len(ev), per_msg):
            t, x, y, p = (a[k:k + per_msg] for a in (ev.t, ev.x, ev.y, ev.p))
            evs = [Event(x=int(a), y=int(b), ts=Time(sec=int(s) // 1_000_000, nanosec=int(s) % 1_000_000 * 1000),
                         polarity=bool(q > 0)) for s, a, b, q in zip(t, x, y, p)]
            hdr = T["std_msgs/msg/Header"](seq=k, stamp=evs[0].ts, frame_id="cam")
            msg = T["dvs_msgs/msg/EventArray"](header=hdr, height=ev.sensor[1], width=ev.sensor[0], events=evs)
            w.write(c, int(t[0]) * 1000, ts.serialize_ros1(msg, "dvs_msgs/msg/EventArray"))
    return path.read_bytes()
