"""ROS 1 bags and ROS 2 bag folders (sqlite3 or MCAP), through ``rosbags``.

Messages read (each topic of these types, or the ones named by ``topics``):

* ``dvs_msgs/EventArray`` (rpg_dvs_ros): ``header``, ``height``, ``width``,
  ``events[]`` of ``uint16 x, uint16 y, time ts, bool polarity``. ``t`` is
  each event's ``ts`` in µs since the epoch (ns truncated).
* ``event_camera_msgs/EventPacket`` (ros-event-camera): ``header``,
  ``height``, ``width``, ``seq``, ``time_base``, ``encoding``,
  ``is_bigendian``, ``events`` (bytes). Encodings: ``evt3`` (Prophesee EVT
  3.0 words, decoded by the RAW reader's kernel, state kept across messages;
  ``t`` is the sensor clock in µs with its 24-bit wraps unrolled, as in a RAW
  file; trigger words become :class:`tectum.TriggerPacket`), ``libcaer``
  and ``libcaer_cmp`` (see :mod:`._ros_kernels`; ``t`` in µs since the
  epoch, from ``time_base``). ``mono`` is not decoded (counted in
  :attr:`RosbagSource.undecoded_messages`).
* ``sensor_msgs/Image`` -> :class:`tectum.FramePacket` (``mono8``/``8UC1``,
  ``mono16``/``16UC1``, ``bgr8``, ``rgb8`` (returned as BGR), ``bgra8``,
  ``rgba8``), ``t`` = header stamp.
* ``sensor_msgs/Imu`` -> :class:`tectum.ImuPacket` (m/s², rad/s), ``t`` =
  header stamp.

Only one event topic can be read at a time (a stream has one sensor): with
several, name one in ``topics``. The message types are registered in the
rosbags typestore from their definitions (bags without embedded
definitions need it). A ROS 2 folder whose ``metadata.yaml`` leaves the
storage id empty is opened with the id implied by its files' extension.
Bad input raises :class:`tectum.FormatError` naming the bag, topic and
message number (there is no meaningful byte offset inside a bag database).
"""

from __future__ import annotations

import os
import re
import struct
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tectum import FormatError, FramePacket, ImuPacket, Kind, Packet, TriggerPacket

from . import _kernels as K
from . import _ros_kernels as R
from ._common import EventAssembler, FileSource, SampleTiler

__all__ = ["RosbagSource", "typestore", "bag_root", "DVS_MSGS", "EVENT_CAMERA_MSGS"]

#: Message definitions registered with the rosbags typestore.
DVS_MSGS = {
    "dvs_msgs/msg/Event": "uint16 x\nuint16 y\ntime ts\nbool polarity\n",
    "dvs_msgs/msg/EventArray": "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n",
}
EVENT_CAMERA_MSGS = {
    "event_camera_msgs/msg/EventPacket": (
        "std_msgs/Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\n"
        "string encoding\nbool is_bigendian\nuint8[] events\n"),
}
_EVENT_TYPES = ("dvs_msgs/msg/EventArray", "event_camera_msgs/msg/EventPacket")
_SAMPLE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/Imu")
_IMAGE = {"mono8": (np.uint8, 1), "8uc1": (np.uint8, 1), "mono16": (np.uint16, 1), "16uc1": (np.uint16, 1),
          "bgr8": (np.uint8, 3), "rgb8": (np.uint8, 3), "8uc3": (np.uint8, 3), "bgra8": (np.uint8, 4),
          "rgba8": (np.uint8, 4), "8uc4": (np.uint8, 4)}


def typestore(ros: int = 2) -> Any:
    """A rosbags typestore (ROS 1 Noetic or ROS 2 Humble) with the event
    message types added."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for defs in (DVS_MSGS, EVENT_CAMERA_MSGS):
        for name, text in defs.items():
            types.update(get_types_from_msg(text, name))
    ts.register(types)
    return ts


def bag_root(path: str) -> tuple[Path, int]:
    """(the bag to open, ROS version): a ``.bag`` file, or a ROS 2 folder
    given as itself, its ``metadata.yaml`` or one of its data files."""
    p = Path(path)
    if p.is_file() and p.suffix == ".bag":
        return p, 1
    if p.is_file():
        p = p.parent
    if (p / "metadata.yaml").is_file():
        return p, 2
    raise FormatError("not a ROS 1 bag nor a ROS 2 bag folder (no metadata.yaml)", path=path, offset=0)


def _stamp_us(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000 + int(stamp.nanosec) // 1000  # same field names in both typestores


def _fixed_metadata(root: Path, stack: list[Any]) -> Path:
    """``root``, or a temporary twin whose metadata names the storage plugin
    that the folder's data files imply (when ``storage_identifier`` is empty)."""
    text = (root / "metadata.yaml").read_text()
    m = re.search(r"^(\s*)storage_identifier:\s*(['\"]{2}|)\s*$", text, re.M)
    if m is None:
        return root
    files = [q for q in root.iterdir() if q.suffix in (".mcap", ".db3")]
    if not files:
        return root
    storage = "mcap" if files[0].suffix == ".mcap" else "sqlite3"
    tmp = tempfile.TemporaryDirectory(prefix="tectum-bag-")
    stack.append(tmp)
    twin = Path(tmp.name)
    (twin / "metadata.yaml").write_text(text[:m.start()] + f"{m.group(1)}storage_identifier: {storage}"
                                        + text[m.end():])
    for q in root.iterdir():
        if q.name != "metadata.yaml":
            os.symlink(q.resolve(), twin / q.name)
    return twin


class RosbagSource(FileSource):
    """Events, frames, IMU and triggers from ROS 1 / ROS 2 bags.

    Parameters (besides :class:`FileSource`'s; ``chunk_bytes`` is unused:
    bags are read one message at a time)
    ------------------------------------------------------------------
    topics:
        Comma-separated topics to read (default: every supported topic; a
        bag with several event topics needs one named here).
    """

    name = "rosbag"
    format = "rosbag"
    extensions = (".bag", "metadata.yaml", ".db3", ".mcap")
    produces = (Kind.EVENTS, Kind.FRAMES, Kind.IMU, Kind.TRIGGERS)

    def __init__(self, path: str, topics: str | None = None, **kw: Any) -> None:
        super().__init__(path, **kw)
        self.topics = [s.strip() for s in topics.split(",") if s.strip()] if topics else None
        #: Messages skipped because their encoding is not decoded (``mono``).
        self.undecoded_messages = 0
        #: libcaer 31-bit clock rollovers seen inside packets.
        self.rollovers = 0

    @classmethod
    def sniff_dir(cls, path: str) -> bool:
        return os.path.isfile(os.path.join(path, "metadata.yaml"))

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"#ROSBAG V2.0") or head.lstrip().startswith(b"rosbag2_bagfile_information")

    def _select(self, conns: list[Any]) -> list[Any]:
        known = [c for c in conns if c.msgtype in _EVENT_TYPES + _SAMPLE_TYPES]
        if self.topics is not None:
            missing = set(self.topics) - {c.topic for c in conns}
            if missing:
                self._fail(f"topics not in the bag: {sorted(missing)} (it has {sorted({c.topic for c in conns})})")
            known = [c for c in known if c.topic in self.topics]
        ev = sorted({c.topic for c in known if c.msgtype in _EVENT_TYPES})
        if len(ev) > 1:
            self._fail(f"several event topics {ev}: choose one with topics=")
        return known

    def _packets(self) -> Iterator[Packet]:
        try:
            from rosbags.rosbag1 import Reader as Reader1
            from rosbags.rosbag2 import Reader as Reader2
        except ImportError:  # pragma: no cover - extra not installed
            raise FormatError("reading ROS bags needs the 'ros' extra (pip install rosbags)", path=self.path) from None
        root, version = bag_root(self.path)
        keep: list[Any] = []
        if version == 2:
            root = _fixed_metadata(root, keep)
        self._files += keep
        try:  # the bags' own definitions are not parsed (MCAP's IDL ones defeat rosbags): ours are used
            reader = (Reader1 if version == 1 else Reader2)(root)
            reader.open()
        except Exception as e:  # rosbags raises its own error classes, OSError, KeyError...
            raise FormatError(f"bag does not open: {e}", path=self.path) from None
        self._files.append(reader)
        store = typestore(version)
        deser = store.deserialize_ros1 if version == 1 else store.deserialize_cdr
        conns = self._select(list(reader.connections))
        decoder = _Decoder(self, version)
        count: dict[str, int] = {}
        for conn, _, raw in self._messages(reader, conns):
            k = count[conn.topic] = count.get(conn.topic, 0) + 1
            try:
                yield from decoder.message(deser, conn, raw)
            except (ValueError, KeyError, IndexError, AssertionError, struct.error) as e:  # deserialisation errors
                if not self.skip_bad:
                    self._fail(f"message {k} of {conn.topic} ({conn.msgtype}) does not decode: {e}")
                self._note_skip(k, k, 1)
            if (self.t_end_us is not None and decoder.asm is not None and decoder.asm.last_t is not None
                    and decoder.asm.last_t >= self.t_end_us):
                break
        if decoder.asm is not None:
            yield from decoder.asm.finish()

    def _messages(self, reader: Any, conns: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        """The bag's messages; a corrupt bag (chunk, index, database) raises
        FormatError instead of rosbags' own errors."""
        it = reader.messages(connections=conns)
        while True:
            try:
                item = next(it)
            except StopIteration:
                return
            except Exception as e:  # rosbags' ReaderError, struct/zstd/sqlite errors on corrupt bags
                raise FormatError(f"bag is corrupt: {type(e).__name__}: {e}", path=self.path) from None
            yield item

    def close(self) -> None:
        for f in self._files:
            try:
                f.close() if hasattr(f, "close") else f.cleanup()
            except Exception:  # closing a half-open reader
                pass
        self._files = []


class _Decoder:
    """Per-stream state while walking the messages of one bag."""

    def __init__(self, src: RosbagSource, version: int) -> None:
        self.src = src
        self.version = version
        self.asm: EventAssembler | None = None
        self.tiler = SampleTiler(src)
        self.evt3_state = np.zeros(K.EVT3_STATE, np.int64)
        self.cmp_state = np.zeros(R.LIBCAER_CMP_STATE, np.int64)

    def _assembler(self, w: int, h: int) -> EventAssembler:
        if self.asm is None:
            sensor = self.src._sensor((int(w), int(h)) if w and h else None)
            if sensor is None:
                self.src._fail("the event messages give no width/height: give sensor=WxH")
            self.asm = EventAssembler(self.src, sensor)
        return self.asm

    def message(self, deser: Any, conn: Any, raw: bytes) -> Iterator[Packet]:
        typ = conn.msgtype
        if typ == "dvs_msgs/msg/EventArray":
            yield from self._dvs(raw)
        elif typ == "event_camera_msgs/msg/EventPacket":
            yield from self._event_packet(deser(raw, typ))
        elif typ == "sensor_msgs/msg/Image":
            out = self._image(conn.topic, deser(raw, typ))
            if out is not None:
                yield out
        elif typ == "sensor_msgs/msg/Imu":
            m = deser(raw, typ)
            a, g = m.linear_acceleration, m.angular_velocity
            out = self.tiler.push(ImuPacket, conn.topic, np.array([_stamp_us(m.header.stamp)]),
                                  accel=np.array([[a.x, a.y, a.z]]), gyro=np.array([[g.x, g.y, g.z]]))
            if out is not None:
                yield out

    def _dvs(self, raw: bytes) -> Iterator[Packet]:
        buf = np.frombuffer(raw, np.uint8)
        if self.version == 1:
            cdr, origin, be = False, 0, False
            i = 12  # seq, stamp sec, stamp nsec
        else:
            cdr, origin, be = True, 4, raw[1] == 0  # encapsulation 0x0000 CDR_BE, 0x0001 CDR_LE
            i = 12  # stamp sec, nanosec after the 4-byte encapsulation
        u = ">u4" if be else "<u4"
        strlen = int(np.frombuffer(raw, u, 1, i)[0])
        i += 4 + strlen
        if cdr:
            i += (-(i - origin)) & 3
        h, w, n = (int(v) for v in np.frombuffer(raw, u, 3, i))
        i += 12
        if n > (len(raw) - i) // 9:
            raise ValueError(f"{n} events do not fit in {len(raw)} bytes")
        t, x, y = np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16)
        p = np.empty(n, np.int8)
        if R.dvs_events(buf, i, n, cdr, origin, be, t, x, y, p) < 0:
            raise ValueError("events run past the message")
        yield from self._assembler(w, h).push(t, x, y, p)

    def _event_packet(self, m: Any) -> Iterator[Packet]:
        enc = str(m.encoding)
        data = np.asarray(m.events, np.uint8)
        asm = self._assembler(m.width, m.height)
        if enc == "evt3":
            words = np.frombuffer(data.tobytes(), ">u2" if m.is_bigendian else "<u2", len(data) // 2)
            n = words.shape[0] * 12
            t, x, y = np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16)
            p, where = np.empty(n, np.int8), np.empty(n, np.int64)
            trig = np.empty((words.shape[0], 3), np.int64)
            ne, nt, bad, nbad, _ = K.decode_evt3(words, self.evt3_state, not self.src.skip_bad, t, x, y, p, where, trig)
            if bad >= 0:
                if not self.src.skip_bad:
                    raise ValueError(f"invalid EVT3 word 0x{int(words[bad]):04x} at byte {2 * bad}")
                self.src._note_skip(int(m.seq), int(m.seq), int(nbad))
            yield from asm.push(t[:ne], x[:ne], y[:ne], p[:ne])
            if nt:
                out = self.tiler.push(TriggerPacket, "triggers", trig[:nt, 0], channel=trig[:nt, 1].astype(np.int16),
                                      value=trig[:nt, 2].astype(np.int8))
                if out is not None:
                    yield out
        elif enc == "libcaer":
            n = len(data) // 8
            t, x, y = np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16)
            p = np.empty(n, np.int8)
            ne, _, rolls = R.libcaer_events(data, np.int64(m.time_base), t, x, y, p)
            self.src.rollovers += rolls
            yield from asm.push(t[:ne], x[:ne], y[:ne], p[:ne])
        elif enc == "libcaer_cmp":
            words = np.frombuffer(data.tobytes(), ">u2" if m.is_bigendian else "<u2", len(data) // 2)
            n = words.shape[0] * 12
            t, x, y = np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16)
            p = np.empty(n, np.int8)
            ne, bad, nbad = R.libcaer_cmp_events(words, np.int64(int(m.time_base) // 1000), self.cmp_state, t, x, y, p)
            if bad >= 0:
                if not self.src.skip_bad:
                    raise ValueError(f"invalid libcaer_cmp word 0x{int(words[bad]):04x} at byte {2 * bad}")
                self.src._note_skip(int(m.seq), int(m.seq), int(nbad))
            order = np.argsort(t[:ne], kind="stable")  # words are grouped by pixel column, not by time
            yield from asm.push(t[order], x[order], y[order], p[order])
        else:
            self.src.undecoded_messages += 1

    def _image(self, topic: str, m: Any) -> FramePacket | None:
        enc = str(m.encoding).lower()
        if enc not in _IMAGE:
            self.src.undecoded_messages += 1
            return None
        dtype, ch = _IMAGE[enc]
        h, w, step = int(m.height), int(m.width), int(m.step)
        item = np.dtype(dtype).itemsize
        data = np.asarray(m.data, np.uint8)
        if step < w * ch * item or data.shape[0] < h * step:
            raise ValueError(f"image {w}x{h} {enc} with step {step} has {data.shape[0]} bytes")
        rows = data[:h * step].reshape(h, step)[:, :w * ch * item]
        img = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(">" if m.is_bigendian else "<"))
        img = img.reshape((h, w) if ch == 1 else (h, w, ch)).astype(dtype)
        if enc in ("rgb8", "rgba8"):
            img = img[..., [2, 1, 0] + ([3] if ch == 4 else [])]
        return self.tiler.push(FramePacket, topic, np.array([_stamp_us(m.header.stamp)]), images=img[None])
