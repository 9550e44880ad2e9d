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


#: Events decoded into one set of columns before they are committed.
_BATCH_EVENTS = 1 << 16
_NO_WHERE = np.empty(0, np.int64)


def event_packet_fields(raw: bytes, version: int) -> tuple[int, int, int, int, str, bool, np.ndarray]:
    """(width, height, seq, time_base, encoding, is_bigendian, events) of a
    serialized ``event_camera_msgs/EventPacket``, read directly (a generic
    deserializer costs more than decoding the events). ROS 1: packed, the
    header has a ``seq``, strings are length-prefixed. ROS 2 (CDR): a 4-byte
    encapsulation (byte 1: 0 big-, 1 little-endian), each field aligned to
    its size from there, strings counted with their terminating NUL.
    ``events`` is a view of ``raw``. ValueError when ``raw`` is too short."""
    cdr = version == 2
    if cdr and len(raw) < 4:
        raise ValueError("message shorter than its CDR encapsulation")
    e = ">" if cdr and raw[1] == 0 else "<"
    origin = 4 if cdr else 0
    i = origin

    def take(fmt: str, size: int) -> Any:
        nonlocal i
        if cdr:
            i += (-(i - origin)) % size
        if i + size > len(raw):
            raise ValueError(f"message of {len(raw)} bytes ends inside a field at byte {i}")
        v = struct.unpack_from(e + fmt, raw, i)[0]
        i += size
        return v

    def text() -> str:
        nonlocal i
        n = take("I", 4)
        if i + n > len(raw):
            raise ValueError(f"string of {n} bytes runs past the message")
        out = raw[i:i + n]
        i += n
        return out.rstrip(b"\0").decode("latin1")

    if not cdr:
        take("I", 4)  # header seq
    take("I", 4), take("I", 4)  # stamp
    text()  # frame_id
    height, width = take("I", 4), take("I", 4)
    seq, time_base = take("Q", 8), take("Q", 8)
    enc = text()
    big = bool(take("B", 1))
    n = take("I", 4)
    if i + n > len(raw):
        raise ValueError(f"{n} event bytes run past the message")
    return width, height, seq, time_base, enc, big, np.frombuffer(raw, np.uint8, n, i)


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
            if version == 1 and root.stat().st_size > 0:
                yield from self._unindexed(root, e)
                return
            raise FormatError(f"bag does not open: {e}", path=self.path) from None
        self._files.append(reader)
        conns = self._select(list(reader.connections))
        yield from self._decode(version, self._messages(reader, conns))

    def _unindexed(self, root: Path, why: Exception) -> Iterator[Packet]:
        """A ROS 1 bag whose index does not read (a bag cut short loses it):
        with ``skip_bad``, its complete messages, read record by record;
        else a FormatError saying where the complete records end."""
        import mmap

        from ._ros1_scan import Scan, ros1_messages, scan_ros1

        with open(root, "rb") as f:
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        self._files.append(data)
        try:
            found = scan_ros1(data)
        except (ValueError, KeyError, struct.error) as e:
            raise FormatError(f"bag does not open ({why}) and its records do not read: {e}", path=self.path) from None
        where = f"cut short: its records end at byte {found.cut}" if found.cut is not None else "index damaged"
        if not self.skip_bad:
            self._fail(f"bag does not open ({why}): {where} (skip_bad reads the complete messages)", found.cut)
        picked = self._select(list(found.connections.values()))
        scan = Scan({}, None)
        yield from self._decode(1, (m for m in ros1_messages(data, scan) if m[0] in picked))
        if found.cut is not None:
            self._note_skip(found.cut, len(data) - 1, 1)

    def _decode(self, version: int, messages: Iterator[tuple[Any, int, bytes]]) -> Iterator[Packet]:
        """The packets of the bag's ``messages`` (connection, time, raw)."""
        store = typestore(version)
        deser = store.deserialize_ros1 if version == 1 else store.deserialize_cdr
        decoder = _Decoder(self, version)
        count: dict[str, int] = {}
        for conn, _, raw in messages:
            k = count[conn.topic] = count.get(conn.topic, 0) + 1
            try:
                yield from decoder.message(deser, conn, raw)
            except (ValueError, KeyError, IndexError, AssertionError, struct.error) as e:  # deserialisation errors
                if not self.skip_bad:
                    self._fail(f"message {k} of {conn.topic} ({conn.msgtype}) does not decode: {e}")
                self._note_skip(k, k, 1)
            if self.t_end_us is not None and decoder.asm is not None and decoder.cols is not None:
                yield from decoder.flush()
                if decoder.asm.past_end():
                    break
        yield from decoder.flush()
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


def _words(data: np.ndarray, big_endian: bool) -> np.ndarray:
    """The payload's 16-bit words in native byte order (the kernels read an
    array of another byte order as native: numba does not swap)."""
    return np.frombuffer(data, ">u2" if big_endian else "<u2", len(data) // 2).astype(np.uint16, copy=False)


class _Decoder:
    """Per-stream state while walking the messages of one bag."""

    def __init__(self, src: RosbagSource, version: int) -> None:
        self.src = src
        self.version = version
        self.asm: EventAssembler | None = None
        self.tiler = SampleTiler(src)
        self.evt3_state = np.zeros(K.EVT3_STATE, np.int64)
        self.cmp_state = np.zeros(R.LIBCAER_CMP_STATE, np.int64)
        self.cols: tuple[np.ndarray, ...] | None = None  # reserved columns, self.n of them filled
        self.n = 0
        self.triggers: list[np.ndarray] = []  # rows (t, channel, value) waiting for the next flush

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
            yield from self._event_packet(*event_packet_fields(raw, self.version))
        elif typ == "sensor_msgs/msg/Image":
            frame = self._image(conn.topic, deser(raw, typ))
            if frame is not None:
                yield frame
        elif typ == "sensor_msgs/msg/Imu":
            m = deser(raw, typ)
            a, g = m.linear_acceleration, m.angular_velocity
            imu = self.tiler.push(ImuPacket, conn.topic, np.array([_stamp_us(m.header.stamp)]),
                                  accel=np.array([[a.x, a.y, a.z]]), gyro=np.array([[g.x, g.y, g.z]]))
            if imu is not None:
                yield imu

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
        yield from self._room(w, h, n)
        t, x, y, p = self._free()
        if R.dvs_events(buf, i, n, cdr, origin, be, t, x, y, p) < 0:
            raise ValueError("events run past the message")
        self.n += n

    # -- events of many messages decoded into one set of columns ----------------
    def _room(self, w: int, h: int, need: int) -> Iterator[Packet]:
        """Make room for ``need`` more events (committing the batch when full)."""
        asm = self._assembler(w, h)
        if self.cols is not None and self.n + need <= self.cols[0].shape[0]:
            return
        yield from self.flush()
        self.cols = asm.reserve(max(need, _BATCH_EVENTS))

    def _free(self) -> tuple[np.ndarray, ...]:
        assert self.cols is not None
        return tuple(c[self.n:] for c in self.cols)

    def flush(self) -> Iterator[Packet]:
        """Commit the events decoded so far, and their triggers."""
        if self.cols is not None:
            assert self.asm is not None
            n, self.cols, self.n = self.n, None, 0
            yield from self.asm.commit(n)
        if self.triggers:
            trig = np.concatenate(self.triggers)
            self.triggers = []
            out = self.tiler.push(TriggerPacket, "triggers", trig[:, 0], channel=trig[:, 1].astype(np.int16),
                                  value=trig[:, 2].astype(np.int8))
            if out is not None:
                yield out

    def _event_packet(self, w: int, h: int, seq: int, time_base: int, enc: str, be: bool,
                      data: np.ndarray) -> Iterator[Packet]:
        if enc == "evt3":
            words = _words(data, be)
            yield from self._room(w, h, words.shape[0] * 12 + 12)
            trig = np.empty((words.shape[0], 3), np.int64)
            ne, nt, bad, nbad, _ = K.decode_evt3(words, self.evt3_state, not self.src.skip_bad, *self._free(),
                                                 _NO_WHERE, trig)
            self.n += ne
            if bad >= 0:
                if not self.src.skip_bad:
                    raise ValueError(f"invalid EVT3 word 0x{int(words[bad]):04x} at byte {2 * bad}")
                self.src._note_skip(seq, seq, int(nbad))
            if nt:
                self.triggers.append(trig[:nt])
        elif enc == "libcaer":
            yield from self._room(w, h, len(data) // 8)
            ne, _, rolls = R.libcaer_events(data, np.int64(time_base), *self._free())
            self.n += ne
            self.src.rollovers += rolls
        elif enc == "libcaer_cmp":
            words = _words(data, be)
            n = words.shape[0] * 12
            t, x, y = np.empty(n, np.int64), np.empty(n, np.uint16), np.empty(n, np.uint16)
            p = np.empty(n, np.int8)
            ne, bad, nbad = R.libcaer_cmp_events(words, np.int64(time_base // 1000), self.cmp_state, t, x, y, p)
            if bad >= 0:
                if not self.src.skip_bad:
                    raise ValueError(f"invalid libcaer_cmp word 0x{int(words[bad]):04x} at byte {2 * bad}")
                self.src._note_skip(seq, seq, int(nbad))
            order = np.argsort(t[:ne], kind="stable")  # words are grouped by pixel column, not by time
            yield from self._room(w, h, ne)
            for dst, src in zip(self._free(), (t, x, y, p)):
                dst[:ne] = src[order]
            self.n += ne
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
