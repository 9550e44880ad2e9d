"""Write events and sample streams to ``.npz`` with named arrays, streaming.

Members of the archive (each a ``.npy`` array, so ``numpy.load`` reads the
file; :class:`tectum.sources.npz.NpzSource` reads it back as packets):

* events: ``t`` (int64 µs), ``x``, ``y`` (uint16), ``p`` (int8 ±1), one
  array per extra per-event column by its name (``vx``, ``noise`` ...),
  ``sensor`` = ``[width, height]`` and ``interval`` = ``[t_start, t_end]`` µs;
* every sample stream of kind ``KIND`` (``frames``, ``maps``, ``imu``,
  ``poses``, ``angular_velocity`` ...): ``KIND_t`` (int64 µs), one array
  ``KIND_FIELD`` per field stacked over the samples, shape ``(N, *field
  shape)`` (frames: ``frames_images`` ``(N, H, W)`` or ``(N, H, W, C)``, with
  ``frames_exposure_start``/``_end`` when present; maps: ``maps_image``,
  ``maps_depth``, ``maps_confidence`` ``(N, H, W)``, ``maps_K`` ``(N, 3, 3)``,
  ``maps_pose`` ``(N, 7)``, those present; IMU: ``imu_accel``, ``imu_gyro``
  ``(N, 3)``), and ``KIND_interval`` = ``[t_start, t_end]`` µs.

A file with sample streams and no events has no ``t``/``x``/``y``/``p``.
Within a stream a field keeps its dtype and sample shape (images of one
size); an optional float field missing from some packets is NaN in their
rows, as :func:`tectum.concat` joins them. Result packets (Python objects)
are not stored.

Each array is appended to its own temporary ``.npy`` file as packets come
(memory stays bounded, whatever the number of frames); :meth:`NpzSink.close`
fixes the headers, stores them into the archive under a temporary name and
renames it into place, so an aborted run leaves no half-written file.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from typing import IO, ClassVar

import numpy as np

from tectum import EventPacket, Kind, Packet, ResultPacket, SamplePacket, Sink

__all__ = ["NpzSink", "write_npz"]

_HEADER = 128  # bytes reserved for each .npy header (format 1.0 pads to 64)


class _Member:
    """One array of the archive, streamed into a temporary ``.npy`` file."""

    def __init__(self, folder: str, name: str, dtype: np.dtype, shape: tuple[int, ...]) -> None:
        self.name, self.dtype, self.shape = name, dtype, shape
        self.rows = 0
        self.f: IO[bytes] = open(os.path.join(folder, name + ".npy"), "wb")
        self.f.write(b"\0" * _HEADER)

    def append(self, a: np.ndarray) -> None:
        if a.dtype != self.dtype or a.shape[1:] != self.shape:
            raise ValueError(f"npz: array {self.name!r} changes from {self.dtype} {self.shape} to {a.dtype} "
                             f"{a.shape[1:]} per sample")
        self.f.write(np.ascontiguousarray(a).tobytes())
        self.rows += a.shape[0]

    def store(self, zf: zipfile.ZipFile) -> None:
        _finish_npy(self.f, self.dtype, (self.rows, *self.shape))
        self.f.close()
        zf.write(self.f.name, self.name + ".npy")


class _Samples:
    """The members of one sample stream."""

    def __init__(self, folder: str, cls: type[SamplePacket], t_start: int) -> None:
        self.folder, self.cls = folder, cls
        self.prefix = str(cls.kind) + "_"
        self.t = _Member(folder, self.prefix + "t", np.dtype(np.int64), ())
        self.fields: dict[str, _Member] = {}
        self.interval = [t_start, t_start]

    def write(self, pkt: SamplePacket) -> None:
        self.interval[1] = pkt.t_end
        n = len(pkt)
        if n == 0:  # empty ticks never decide a field's dtype or shape
            return
        for name, a in pkt.data.items():
            if name not in self.fields:
                self.fields[name] = _Member(self.folder, self.prefix + name, a.dtype, a.shape[1:])
                if self.t.rows:
                    self._fill(name, self.t.rows)  # the field is new: NaN for the rows before
        for name, m in self.fields.items():
            if name in pkt.data:
                m.append(pkt.data[name])
            else:
                self._fill(name, n)
        self.t.append(pkt.t)

    def _fill(self, name: str, n: int) -> None:
        m = self.fields[name]
        spec = self.cls.fields.get(name)
        if spec is None or not spec.optional or m.dtype.kind != "f":
            raise ValueError(f"npz: {self.cls.kind} field {name!r} is in some packets of the stream and not in "
                             "others (only optional float fields may be; their missing rows are NaN)")
        m.append(np.full((n, *m.shape), np.nan, m.dtype))

    def store(self, zf: zipfile.ZipFile) -> None:
        for m in (self.t, *self.fields.values()):
            m.store(zf)
        zf.writestr(self.prefix + "interval.npy", _npy_bytes(np.array(self.interval, np.int64)))

    def close(self) -> None:
        for m in (self.t, *self.fields.values()):
            m.f.close()


class NpzSink(Sink):
    """Events (with every extra column) and sample streams (frames, maps,
    IMU, poses, ...) to a ``.npz`` file; see the module docstring for the
    layout.

    Parameters
    ----------
    path:
        The output file; replaced atomically when the run ends well.
    compress:
        Deflate the archive (smaller, slower).
    """

    name = "npz"
    extensions = (".npz",)
    consumes: ClassVar[tuple[Kind, ...]] = (Kind.ANY,)

    def __init__(self, path: str, compress: bool = False) -> None:
        self.path = path
        self.compress = compress
        self._dir: tempfile.TemporaryDirectory[str] | None = None
        self._events: dict[str, _Member] = {}
        self._samples: dict[Kind, _Samples] = {}
        self._sensor: tuple[int, int] | None = None
        self._interval: list[int] | None = None

    def open(self) -> None:
        parent = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(parent):
            raise FileNotFoundError(f"folder {parent!r} does not exist")
        self._dir = tempfile.TemporaryDirectory(prefix=".tectum-npz-", dir=parent)

    def write(self, packet: Packet) -> None:
        if self._dir is None:
            self.open()
        assert self._dir is not None
        if isinstance(packet, EventPacket):
            self._write_events(packet, self._dir.name)
        elif isinstance(packet, SamplePacket) and not isinstance(packet, ResultPacket):
            s = self._samples.get(packet.kind)
            if s is None:
                s = self._samples[packet.kind] = _Samples(self._dir.name, type(packet), packet.t_start)
                self._check_names()
            s.write(packet)

    def _write_events(self, packet: EventPacket, folder: str) -> None:
        if self._sensor is None:
            self._sensor = packet.sensor
            self._interval = [packet.t_start, packet.t_end]
            for name in packet.column_names:
                a = packet[name]
                self._events[name] = _Member(folder, name, a.dtype, a.shape[1:])
            self._check_names()
        elif packet.sensor != self._sensor:
            raise ValueError(f"sensor size changed from {self._sensor} to {packet.sensor}")
        elif set(packet.column_names) != set(self._events):
            raise ValueError(f"columns changed from {sorted(self._events)} to {sorted(packet.column_names)}")
        assert self._interval is not None
        self._interval[1] = packet.t_end
        for name, m in self._events.items():
            m.append(packet[name])

    def _check_names(self) -> None:
        """An event column named like a sample stream's array would be read back as part of that stream."""
        for name in self._events:
            for kind in self._samples:
                if name.startswith(str(kind) + "_"):
                    raise ValueError(f"npz: event column {name!r} would be taken for a field of the {kind} stream")

    def close(self) -> None:
        if self._dir is None:
            return
        try:
            tmp = os.path.join(self._dir.name, "out.npz")
            mode = zipfile.ZIP_DEFLATED if self.compress else zipfile.ZIP_STORED
            with zipfile.ZipFile(tmp, "w", mode, allowZip64=True) as zf:
                for m in self._events.values():
                    m.store(zf)
                if self._sensor is not None:
                    zf.writestr("sensor.npy", _npy_bytes(np.array(self._sensor, np.int64)))
                    zf.writestr("interval.npy", _npy_bytes(np.array(self._interval, np.int64)))
                elif not self._samples:  # nothing was written: an empty, valid event file
                    for name, dt in (("t", np.int64), ("x", np.uint16), ("y", np.uint16), ("p", np.int8)):
                        zf.writestr(name + ".npy", _npy_bytes(np.empty(0, dt)))
                for s in self._samples.values():
                    s.store(zf)
            os.replace(tmp, self.path)
        finally:
            self._cleanup()

    def abort(self) -> None:
        self._cleanup()

    def _cleanup(self) -> None:
        for m in self._events.values():
            m.f.close()
        for s in self._samples.values():
            s.close()
        self._events, self._samples = {}, {}
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None


def _finish_npy(f: IO[bytes], dtype: np.dtype, shape: tuple[int, ...]) -> None:
    header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape}
    f.flush()
    f.seek(0)
    body = repr(header).encode("latin1")
    pre = b"\x93NUMPY\x01\x00"
    pad = _HEADER - len(pre) - 2 - len(body) - 1
    if pad < 0:
        raise ValueError("npy header too long")
    hdr = body + b" " * pad + b"\n"
    f.write(pre + len(hdr).to_bytes(2, "little") + hdr)
    f.flush()


def _npy_bytes(a: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def write_npz(path: str, packet: Packet) -> None:
    """Write one packet to ``path`` (convenience for tests and scripts)."""
    s = NpzSink(path)
    s.open()
    s.write(packet)
    s.close()
