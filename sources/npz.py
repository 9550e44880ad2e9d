"""Read ``.npz`` recordings with named arrays, in bounded-memory chunks.

Layout (as written by :class:`tectum.sinks.npz.NpzSink`, and readable with
plain ``numpy.load``):

* events: one array per column, ``t`` (µs), ``x``, ``y``, ``p`` and any
  extra per-event column (``vx``, ``vy``, ``noise`` ...), plus ``sensor`` =
  ``[width, height]`` and ``interval`` = ``[t_start, t_end]`` in µs. Files
  from elsewhere without ``sensor`` get it from the ``sensor`` option or,
  failing that, from the largest coordinates;
* the ground truth ``tectum simulate --out FILE`` writes beside the events
  (``FILE.truth.npz``, no events): its ``pose_*``, ``aps_*`` and ``imu_*``
  series are the poses, frames and IMU streams;
* sample streams: for a registered kind ``KIND`` (``frames``, ``maps``,
  ``imu``, ``poses``, ...), ``KIND_t`` (int64 µs) marks the stream, each
  ``KIND_FIELD`` array (first axis over the samples) is a field and
  ``KIND_interval`` = ``[t_start, t_end]`` µs its interval (frames:
  ``frames_t``, ``frames_images`` ``(N, H, W[, C])``; maps: ``maps_t``,
  ``maps_image``, ``maps_depth``, ``maps_confidence``, ``maps_K``,
  ``maps_pose``).

A file may hold events, sample streams or both. The sample streams come
interleaved with the events (:func:`tectum.interleave`): before each event
packet, every sample stream up to that packet's ``t_end`` (a sample packet
straddling it is split there, an empty part included, so a stream's
watermark keeps up with the events); after the last event packet, the
rest. Without events, the sample streams' packets come in the order of
their ends. Each stream is read a chunk of rows at a time.
"""

from __future__ import annotations

import zipfile
from collections.abc import Callable, Container, Iterator, Mapping
from typing import IO, Any

import numpy as np

from tectum import EventPacket, FormatError, Kind, Packet, SamplePacket, Source, interleave, packet_class

__all__ = ["NpzSource", "read_npz"]

_UNITS = {"s": 1_000_000, "ms": 1000, "us": 1, "ns": 0.001}
_META = ("sensor", "interval")
_SAMPLE_BYTES = 1 << 24  # bytes of one sample stream read at a time
#: the ground truth ``tectum simulate --out FILE`` writes to ``FILE.truth.npz``
#: (:class:`tectum.sources.simulate.truth.Truth`): its series that are
#: streams, by their prefix there (the dense ``frame_*`` maps, ``feature_*``,
#: ``camera``, ``seed`` ... are left to ``numpy.load``)
_TRUTH_SERIES = {Kind.POSES: "pose_", Kind.FRAMES: "aps_", Kind.IMU: "imu_"}


class _Column:
    """A streaming reader of one ``.npy`` member of a zip archive."""

    def __init__(self, zf: zipfile.ZipFile, member: str, path: str) -> None:
        self.name = member[:-4]
        self.f: IO[bytes] = zf.open(member)
        try:
            npy = np.lib.format
            version = npy.read_magic(self.f)
            read_header = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
            shape, fortran, dtype = read_header(self.f)
        except (ValueError, OSError, EOFError) as e:
            raise FormatError(f"column {self.name!r} is not a valid .npy array: {e}", path=path) from None
        if dtype.hasobject:
            raise FormatError(f"column {self.name!r} holds Python objects; refusing to unpickle", path=path)
        if fortran and len(shape) > 1:
            raise FormatError(f"column {self.name!r} is Fortran-ordered", path=path)
        self.shape, self.dtype, self.path = shape, dtype, path
        self.row = dtype.itemsize * int(np.prod(shape[1:], dtype=np.int64))

    @property
    def rows(self) -> int:
        return int(self.shape[0]) if self.shape else 0

    def read(self, n: int) -> np.ndarray:
        want = n * self.row
        buf = self.f.read(want)
        if len(buf) != want:
            raise FormatError(f"column {self.name!r} is truncated", path=self.path)
        return np.frombuffer(buf, dtype=self.dtype).reshape((n, *self.shape[1:]))

    def read_all(self) -> np.ndarray:
        return self.read(self.shape[0] if self.shape else 1).reshape(self.shape)


class _Stream:
    """A sample stream's arrays, read a chunk of rows at a time (at most
    ``_SAMPLE_BYTES``) into packets that tile the stream's interval; the
    rows of a chunk's last timestamp wait for the next chunk."""

    def __init__(self, kind: Kind, t: _Column, fields: dict[str, _Column], interval: tuple[int, int] | None,
                 scale: float, path: str) -> None:
        cls = packet_class(kind)
        assert issubclass(cls, SamplePacket)
        self.cls, self.t, self.fields, self.path, self.scale = cls, t, fields, path, scale
        self.interval = interval
        self.step = max(1, _SAMPLE_BYTES // (8 + sum(c.row for c in fields.values())))

    def packets(self) -> Iterator[SamplePacket]:
        def read(k: int) -> dict[str, np.ndarray]:
            rows = {n: c.read(k) for n, c in self.fields.items()}
            rows["t"] = _to_us(self.t.read(k), self.scale)
            return rows

        for rows, t0, t1 in _tiles(read, self.t.rows, self.step, self.interval):
            yield self._packet(rows.pop("t"), rows, t0, t1)
        if self.t.rows == 0 and self.interval:  # a stream of ticks only
            yield self.cls.empty(*self.interval)

    def _packet(self, t: np.ndarray, data: dict[str, np.ndarray], t_start: int, t_end: int) -> SamplePacket:
        try:
            return self.cls(t, t_start=t_start, t_end=t_end, **data)
        except Exception as e:
            raise FormatError(f"{self.cls.kind} stream: {e}", path=self.path) from None


class NpzSource(Source):
    """Events and sample streams from a ``.npz`` file with named arrays
    (see the module docstring for the layout).

    Parameters
    ----------
    path:
        The file.
    chunk_events:
        Events per packet read (memory stays bounded by this).
    sensor:
        ``"WIDTHxHEIGHT"`` for files that do not store it.
    time_unit:
        Unit of ``t`` (and ``KIND_t``) in files from elsewhere: ``s``,
        ``ms``, ``us`` or ``ns``.
    """

    name = "npz"
    extensions = (".npz",)
    produces = tuple(k for k in Kind if k != Kind.RESULTS)  # the kinds registered when this module is imported

    def __init__(self, path: str, chunk_events: int = 1 << 20, sensor: str | None = None,
                 time_unit: str = "us") -> None:
        if time_unit not in _UNITS:
            raise ValueError(f"time_unit must be one of {list(_UNITS)}")
        if chunk_events < 1:
            raise ValueError("chunk_events must be >= 1")
        self.path = path
        self.chunk_events = chunk_events
        self.sensor_opt = _parse_size(sensor) if sensor else None
        self.time_unit = time_unit
        self._zf: zipfile.ZipFile | None = None

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head[:4] == b"PK\x03\x04" and b".npy" in head[:200]

    @classmethod
    def kinds_for(cls, arg: str, params: Mapping[str, Any]) -> tuple[Kind, ...]:
        """The streams the archive holds, from its member names."""
        try:
            with zipfile.ZipFile(arg) as zf:
                names = {m[:-4] for m in zf.namelist() if m.endswith(".npy")}
        except (zipfile.BadZipFile, OSError):
            return cls.produces  # opening will say what is wrong
        found = [k for k in cls.produces if k != Kind.EVENTS and _prefix(k, names) + "t" in names]
        return (Kind.EVENTS, *found) if "t" in names or not found else tuple(found)

    def _open(self) -> tuple[dict[str, _Column], tuple[int, int] | None, tuple[int, int] | None, int,
                             list[_Stream]]:
        try:
            self._zf = zf = zipfile.ZipFile(self.path)
        except (zipfile.BadZipFile, OSError) as e:
            raise FormatError(f"not a readable .npz archive: {e}", path=self.path) from None
        members = [m for m in zf.namelist() if m.endswith(".npy")]
        cols = {m[:-4]: _Column(zf, m, self.path) for m in members}
        streams = self._streams(cols)
        missing = [c for c in ("t", "x", "y", "p") if c not in cols]
        if missing and (len(missing) < 4 or not streams):
            raise FormatError(f"missing column(s) {missing}; has {sorted(cols)}", path=self.path)
        if not missing:
            sensor, interval, n = self._event_meta(cols)
        else:
            sensor, interval, n = None, None, 0
            for name in list(cols):
                if name in _META:
                    cols.pop(name)
        return cols, sensor, interval, n, streams

    def _streams(self, cols: dict[str, _Column]) -> list[_Stream]:
        """Take the sample streams' arrays (``KIND_t`` and ``KIND_*``) out of
        ``cols``; in an archive without events also the simulator's ground
        truth series (:data:`_TRUTH_SERIES`)."""
        out = []
        scale = _UNITS[self.time_unit]
        for kind in sorted(Kind, key=len, reverse=True):  # angular_velocity_t before a kind named angular
            pre = _prefix(kind, cols)
            if kind in (Kind.EVENTS, Kind.RESULTS) or pre + "t" not in cols:
                continue
            t = cols.pop(pre + "t")
            iv = cols.pop(pre + "interval").read_all().astype(np.int64).ravel() if pre + "interval" in cols else None
            fields = {name[len(pre):]: cols.pop(name) for name in [c for c in cols if c.startswith(pre)]}
            for name, c in fields.items():
                if c.rows != t.rows or not c.shape:
                    raise FormatError(f"array {pre + name!r} has shape {c.shape}, {pre + 't'!r} has {t.rows} rows",
                                      path=self.path)
            if t.dtype.kind == "f" and self.time_unit == "us":
                raise FormatError(f"{pre + 't'!r} is floating point: say its unit with time_unit", path=self.path)
            interval = (int(iv[0]), int(iv[1])) if iv is not None and iv.shape[0] == 2 else None
            out.append(_Stream(kind, t, fields, interval, scale, self.path))
        return sorted(out, key=lambda s: list(Kind).index(s.cls.kind))

    def _event_meta(self, cols: dict[str, _Column]) -> tuple[tuple[int, int], tuple[int, int] | None, int]:
        n = cols["t"].rows
        for name, c in cols.items():
            if name in _META:
                continue
            if not c.shape or c.shape[0] != n:
                raise FormatError(f"column {name!r} has shape {c.shape}, 't' has {n} rows", path=self.path)
        interval = None
        if "interval" in cols:
            iv = cols.pop("interval").read_all().astype(np.int64).ravel()
            interval = (int(iv[0]), int(iv[1]))
        if "sensor" in cols:
            s = cols.pop("sensor").read_all().ravel()
            sensor = (int(s[0]), int(s[1]))
        elif self.sensor_opt:
            sensor = self.sensor_opt
        else:
            sensor = self._infer_sensor(n)
        if self.sensor_opt and self.sensor_opt != sensor:
            raise FormatError(f"file says sensor {sensor}, option says {self.sensor_opt}", path=self.path)
        return sensor, interval, n

    def _infer_sensor(self, n: int) -> tuple[int, int]:
        with zipfile.ZipFile(self.path) as zf:
            xs = _Column(zf, "x.npy", self.path)
            ys = _Column(zf, "y.npy", self.path)
            w = h = 0
            left = n
            while left:
                k = min(left, self.chunk_events)
                xa, ya = xs.read(k), ys.read(k)
                w, h = max(w, int(xa.max()) + 1), max(h, int(ya.max()) + 1)
                left -= k
        return max(w, 1), max(h, 1)

    def info(self) -> dict[str, Any]:
        """The keys of :meth:`tectum.sources.files.FileSource.info` (what
        ``tectum info`` prints), plus ``interval`` and ``columns``; reads
        only the time arrays. First and last times are the events', or
        with no events the sample streams'."""
        cols, sensor, interval, n, streams = self._open()
        try:
            first, last = self._span(cols["t"] if n else None, self.chunk_events)
            counts = {"events": n} if sensor is not None else {}
            for s in streams:
                counts[str(s.cls.kind)] = s.t.rows
                if not n:
                    a, b = self._span(s.t, s.step)
                    first = a if first is None or (a is not None and a < first) else first
                    last = b if last is None or (b is not None and b > last) else last
        finally:
            self.close()
        dur = last - first if first is not None and last is not None else 0
        return {"format": "npz", "path": self.path, "sensor": sensor, "events": n, "t_first_us": first,
                "t_last_us": last, "duration_us": dur, "rate_mev_s": n / dur if dur > 0 else 0.0,
                "streams": counts, "t0_offset_us": 0, "skipped_events": 0,
                "interval": interval, "columns": sorted(cols)}

    def _span(self, t: _Column | None, step: int) -> tuple[int | None, int | None]:
        first = last = None
        left = t.rows if t is not None else 0
        while left:
            assert t is not None
            k = min(left, step)
            left -= k
            ts = _to_us(t.read(k), _UNITS[self.time_unit])
            first = int(ts[0]) if first is None else first
            last = int(ts[-1])
        return first, last

    def packets(self) -> Iterator[Packet]:
        cols, sensor, interval, n, streams = self._open()
        try:
            samples = [s.packets() for s in streams]
            if sensor is not None:
                yield from interleave(self._chunks(cols, sensor, interval, n), samples)
            else:
                yield from _by_end(samples)
        finally:
            self.close()

    def _chunks(self, cols: dict[str, _Column], sensor: tuple[int, int],
                interval: tuple[int, int] | None, n: int) -> Iterator[EventPacket]:
        scale = _UNITS[self.time_unit]
        if cols["t"].dtype.kind == "f" and self.time_unit == "us":
            raise FormatError("'t' is floating point: say its unit with time_unit (s, ms, us, ns)",
                              path=self.path)

        def read(k: int) -> dict[str, np.ndarray]:
            rows = {c: a.read(k) for c, a in cols.items()}
            rows["t"] = _to_us(rows["t"], scale)
            return rows

        for rows, t0, t1 in _tiles(read, n, self.chunk_events, interval):
            yield self._packet(rows, sensor, t0, t1)
        if n == 0 and interval:
            yield EventPacket.empty(sensor, interval[0], interval[1])

    def _packet(self, chunk: dict[str, np.ndarray], sensor: tuple[int, int], t0: int, t1: int) -> EventPacket:
        try:
            return EventPacket.from_arrays(
                chunk["t"], chunk["x"], chunk["y"], chunk["p"], sensor=sensor, t_start=t0, t_end=t1,
                columns={c: v for c, v in chunk.items() if c not in ("t", "x", "y", "p")}, validate=False,
            )
        except Exception as e:
            raise FormatError(str(e), path=self.path) from None

    def close(self) -> None:
        if self._zf is not None:
            self._zf.close()
            self._zf = None


def _prefix(kind: Kind, names: Container[str]) -> str:
    """The prefix of ``kind``'s arrays among the archive's ``names``:
    ``KIND_``, or in an archive without events and without ``KIND_t`` the
    simulator's ground-truth prefix (:data:`_TRUTH_SERIES`)."""
    own = f"{kind}_"
    truth = _TRUTH_SERIES.get(kind)
    return truth if truth is not None and own + "t" not in names and "t" not in names else own


def _tiles(read: Callable[[int], dict[str, np.ndarray]], n: int, step: int,
           interval: tuple[int, int] | None) -> Iterator[tuple[dict[str, np.ndarray], int, int]]:
    """Rows of arrays read ``step`` at a time (``read(k)``: the next ``k``
    rows of each, ``t`` in µs) as consecutive pieces ``(rows, t_start,
    t_end)`` tiling ``interval`` (default: first time to last time + 1 µs);
    the rows of a read's last timestamp wait for the next read, so a
    timestamp is never split."""
    start = interval[0] if interval else None
    carry: dict[str, np.ndarray] | None = None
    left = n
    while left:
        k = min(left, step)
        left -= k
        rows = read(k)
        if carry is not None:
            rows = {c: np.concatenate([carry[c], v]) for c, v in rows.items()}
            carry = None
        t = rows["t"]
        if left:  # the last timestamp's run may go on in the next read: hold it
            i = int(np.searchsorted(t, t[-1], side="left"))
            carry = {c: v[i:] for c, v in rows.items()}
            if i == 0:
                continue
            rows, t_end = {c: v[:i] for c, v in rows.items()}, int(t[i])
        else:
            t_end = interval[1] if interval else int(t[-1]) + 1
        t_start = start if start is not None else int(t[0])
        yield rows, t_start, t_end
        start = t_end


def _by_end(pieces: list[Iterator[SamplePacket]]) -> Iterator[SamplePacket]:
    """The packets of several streams merged by their ends (watermarks),
    holding one packet per stream (a recording without events)."""
    head = [next(g, None) for g in pieces]
    while True:
        live = [(q.t_end, i) for i, q in enumerate(head) if q is not None]
        if not live:
            return
        i = min(live)[1]
        yield head[i]  # type: ignore[misc]
        head[i] = next(pieces[i], None)


def _to_us(t: np.ndarray, scale: float) -> np.ndarray:
    if scale == 1:
        return t.astype(np.int64)
    return np.round(t.astype(np.float64) * scale).astype(np.int64)


def _parse_size(s: str) -> tuple[int, int]:
    try:
        w, h = s.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise ValueError(f"sensor size {s!r} is not WIDTHxHEIGHT") from None


def read_npz(path: str, **kw: Any) -> EventPacket:
    """The events of the file as one packet (convenience for tests and
    scripts; sample streams are left out)."""
    from tectum import concat

    src = NpzSource(path, **kw)
    pkts = [q for q in src.packets() if isinstance(q, EventPacket)]
    return concat(pkts)
