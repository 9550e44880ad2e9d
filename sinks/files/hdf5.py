"""HDF5 writer in the DSEC layout (``h5py``, the ``hdf5`` extra), with every
sample stream beside the events.

Events, as DSEC has them: ``events/{t,x,y,p}`` (t uint32 µs relative to
``t_offset``, x/y uint16, p uint8 0/1), ``ms_to_idx`` (first event index at
or after each millisecond of relative time) and ``t_offset`` (int64 µs: the
first event packet's start), plus a ``sensor`` attribute ``[width, height]``.

Sample streams (frames, IMU, triggers, poses, maps ... any registered kind
but ``results``, whose Python objects no file holds): one group per kind,
named after it (``/frames``, ``/imu``, ``/triggers``, ``/poses``), with

* ``t``: int64 µs, absolute (``t_offset`` is not subtracted);
* one dataset per field, its first axis over the samples, shape ``(N,
  *sample shape)`` (``frames/images`` ``(N, H, W[, C])``, ``frames/exposure_start``
  ``(N,)``, ``imu/accel`` and ``imu/gyro`` ``(N, 3)``, ``imu/temperature``,
  ``triggers/channel``, ``triggers/value``, ``poses/position`` ``(N, 3)``,
  ``poses/orientation`` ``(N, 4)`` x, y, z, w ...), with a ``unit``
  attribute where the kind declares one;
* attributes ``kind`` (the stream kind) and ``t_start``, ``t_end`` (µs: the
  interval the stream covers, which may reach past its last sample).

An optional float field missing from part of a stream is NaN there (as
:func:`tectum.concat` joins packets); within a stream a field keeps its
dtype and sample shape (frames of one size). :class:`tectum.sources.files.hdf5.Hdf5Source`
reads the groups back beside the events; other HDF5 readers see plain
datasets (``h5py.File(p)["imu/gyro"][:]``).

Every dataset is chunked along its first axis and compressed alike:
``compression`` is ``gzip`` (default: level 1 after HDF5's byte shuffle,
which every HDF5 reader has; 2.4x faster to write than level 4 and a fifth
smaller), ``lzf`` (h5py and PyTables only) or ``none``. Event chunks hold
``chunk_events`` events; sample chunks about 1 MiB (at least one sample)."""

from __future__ import annotations

import os
from typing import Any, ClassVar

import numpy as np

from tectum import EventPacket, Kind, Packet, ResultPacket, SamplePacket, Sink

from ._common import count_unwritten, discard, temp_beside

__all__ = ["Hdf5Sink"]

_CHUNK_BYTES = 1 << 20  # bytes per chunk of a sample dataset
_RESERVED = frozenset({"events", "ms_to_idx", "t_offset"})  # names of the DSEC layout


class Hdf5Sink(Sink):
    """Events and sample streams to a DSEC-layout HDF5 file (see the module
    docstring for the layout)."""

    name = "hdf5"
    format = "hdf5"
    title = "HDF5"
    holds = "every stream but results (Python objects)"
    extensions = (".h5", ".hdf5")
    stores_sensor = True
    consumes: ClassVar[tuple[Kind, ...]] = (Kind.ANY,)

    def __init__(self, path: str, compression: str = "gzip", chunk_events: int = 1 << 16) -> None:
        if compression not in ("gzip", "lzf", "none"):
            raise ValueError("compression must be gzip, lzf or none")
        self.path = os.fspath(path)
        self.compression = None if compression == "none" else compression
        self.chunk_events = chunk_events
        self.h: Any = None
        self._tmp: str | None = None
        self.n = 0
        self.t_offset: int | None = None
        self.m2i: list[int] = []
        self.sensor: tuple[int, int] | None = None
        self._streams: dict[Kind, _Stream] = {}
        #: What came and was not stored, by kind (results).
        self.not_written: dict[str, int] = {}

    def _opts(self) -> dict[str, Any]:
        opts: dict[str, Any] = {"compression": self.compression, "shuffle": self.compression is not None}
        if self.compression == "gzip":
            opts["compression_opts"] = 1
        return opts

    def open(self) -> None:
        from tectum.sources.files.hdf5 import _h5py

        h5py = _h5py()
        fd, self._tmp = temp_beside(self.path, ".h5.part")
        os.close(fd)
        self.h = h5py.File(self._tmp, "w")
        g = self.h.create_group("events")
        for name, dt in (("t", "u4"), ("x", "u2"), ("y", "u2"), ("p", "u1")):
            g.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dt, chunks=(self.chunk_events,),
                             **self._opts())

    def write(self, packet: Packet) -> None:
        if self.h is None:
            self.open()
        if isinstance(packet, EventPacket):
            self._events(packet)
        elif isinstance(packet, SamplePacket) and not isinstance(packet, ResultPacket):
            s = self._streams.get(packet.kind)
            if s is None:
                if packet.kind in _RESERVED:
                    raise ValueError(f"hdf5: a stream of kind {packet.kind!r} would take the name of the "
                                     "DSEC layout's dataset")
                s = self._streams[packet.kind] = _Stream(self.h.create_group(str(packet.kind)), type(packet),
                                                         packet.t_start, self._opts())
            s.write(packet)
        else:
            count_unwritten(self.not_written, packet)

    def _events(self, packet: EventPacket) -> None:
        if self.sensor is None:
            self.sensor = packet.sensor
            self.t_offset = packet.t_start
        elif packet.sensor != self.sensor:
            raise ValueError(f"sensor size changed from {self.sensor} to {packet.sensor}")
        k = len(packet)
        if not k:
            return
        assert self.t_offset is not None
        rel = packet.t - self.t_offset
        if rel[-1] >= 1 << 32:
            raise ValueError("DSEC time is uint32 µs: the recording spans more than 71 minutes")
        g = self.h["events"]
        for name, a in (("t", rel), ("x", packet.x), ("y", packet.y), ("p", (packet.p > 0))):
            d = g[name]
            d.resize((self.n + k,))
            d[self.n:] = a
        # ms_to_idx[ms] = first index with rel >= 1000 * ms, for every ms up to the last event
        last_ms = int(rel[-1]) // 1000
        ms = np.arange(len(self.m2i), last_ms + 1, dtype=np.int64)
        self.m2i.extend((self.n + np.searchsorted(rel, ms * 1000, side="left")).tolist())
        self.n += k

    def close(self) -> None:
        if self.h is None:
            self.open()
        try:
            self.h.create_dataset("ms_to_idx", data=np.asarray(self.m2i, np.uint64))
            self.h.create_dataset("t_offset", data=np.int64(self.t_offset or 0))
            if self.sensor:
                self.h.attrs["sensor"] = np.asarray(self.sensor, np.int64)
            for s in self._streams.values():
                s.finish()
            self.h.close()
            self.h = None
            assert self._tmp is not None
            os.replace(self._tmp, self.path)
            self._tmp = None
        finally:
            self.abort()

    def abort(self) -> None:
        if self.h is not None:
            try:
                self.h.close()
            except Exception:
                pass
            self.h = None
        discard(self._tmp)
        self._tmp = None


class _Stream:
    """The group of one sample stream: ``t`` and one growing dataset per
    field, made when a field first comes with samples."""

    def __init__(self, group: Any, cls: type[SamplePacket], t_start: int, opts: dict[str, Any]) -> None:
        self.g, self.cls, self.opts = group, cls, opts
        self.rows = 0
        self.interval = [t_start, t_start]
        self._dataset("t", np.dtype(np.int64), ()).attrs["unit"] = "µs"
        self.fields: list[str] = []
        group.attrs["kind"] = str(cls.kind)

    def _dataset(self, name: str, dtype: np.dtype, shape: tuple[int, ...]) -> Any:
        row = max(1, dtype.itemsize * int(np.prod(shape, dtype=np.int64)))
        chunk = (max(1, min(1 << 16, _CHUNK_BYTES // row)), *shape)
        return self.g.create_dataset(name, shape=(0, *shape), maxshape=(None, *shape), dtype=dtype, chunks=chunk,
                                     **self.opts)

    def write(self, pkt: SamplePacket) -> None:
        self.interval[1] = pkt.t_end
        n = len(pkt)
        if not n:  # empty ticks never decide a field's dtype or shape
            return
        for name, a in pkt.data.items():
            if name not in self.fields:
                d = self._dataset(name, a.dtype, a.shape[1:])
                spec = self.cls.fields.get(name)
                if spec is not None and spec.unit:
                    d.attrs["unit"] = spec.unit
                self.fields.append(name)
                if self.rows:
                    self._append(name, self._missing(name, self.rows))  # a new field: NaN for the rows before
        for name in self.fields:
            self._append(name, pkt.data[name] if name in pkt.data else self._missing(name, n))
        self._append("t", pkt.t)
        self.rows += n

    def _append(self, name: str, a: np.ndarray) -> None:
        d = self.g[name]
        if a.dtype != d.dtype or a.shape[1:] != d.shape[1:]:
            raise ValueError(f"hdf5: {self.cls.kind}/{name} changes from {d.dtype} {d.shape[1:]} to {a.dtype} "
                             f"{a.shape[1:]} per sample")
        k = d.shape[0]
        d.resize((k + a.shape[0], *d.shape[1:]))
        d[k:] = a

    def _missing(self, name: str, n: int) -> np.ndarray:
        d = self.g[name]
        spec = self.cls.fields.get(name)
        if spec is None or not spec.optional or d.dtype.kind != "f":
            raise ValueError(f"hdf5: {self.cls.kind} field {name!r} is in some packets of the stream and not in "
                             "others (only optional float fields may be; their missing rows are NaN)")
        return np.full((n, *d.shape[1:]), np.nan, d.dtype)

    def finish(self) -> None:
        self.g.attrs["t_start"], self.g.attrs["t_end"] = np.int64(self.interval[0]), np.int64(self.interval[1])
