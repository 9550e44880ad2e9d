"""Read ``.npz`` event files with named columns, in bounded-memory chunks.

Layout (as written by :class:`tectum.sinks.npz.NpzSink`, and readable with
plain ``numpy.load``): one array per column, ``t`` (µs), ``x``, ``y``, ``p``
and any extra per-event column (``vx``, ``vy``, ``noise`` ...), plus
``sensor`` = ``[width, height]`` and ``interval`` = ``[t_start, t_end]`` in
µs. Files from elsewhere without ``sensor`` get it from the ``sensor``
option or, failing that, from the largest coordinates.
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterator
from typing import IO, Any

import numpy as np

from tectum import EventPacket, FormatError, Source

__all__ = ["NpzSource", "read_npz"]

_UNITS = {"s": 1_000_000, "ms": 1000, "us": 1, "ns": 0.001}
_META = ("sensor", "interval")


class _Column:
    """A streaming reader of one ``.npy`` member of a zip archive."""

    def __init__(self, zf: zipfile.ZipFile, member: str, path: str) -> None:
        self.name = member[:-4]
        self.f: IO[bytes] = zf.open(member)
        try:
            version = np.lib.format.read_magic(self.f)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read_header(self.f)
        except (ValueError, OSError, EOFError) as e:
            raise FormatError(f"column {self.name!r} is not a valid .npy array: {e}", path=path) from None
        if dtype.hasobject:
            raise FormatError(f"column {self.name!r} holds Python objects; refusing to unpickle", path=path)
        if fortran and len(shape) > 1:
            raise FormatError(f"column {self.name!r} is Fortran-ordered", path=path)
        self.shape, self.dtype, self.path = shape, dtype, path
        self.row = dtype.itemsize * int(np.prod(shape[1:], dtype=np.int64))

    def read(self, n: int) -> np.ndarray:
        want = n * self.row
        buf = self.f.read(want)
        if len(buf) != want:
            raise FormatError(f"column {self.name!r} is truncated", path=self.path)
        return np.frombuffer(buf, dtype=self.dtype).reshape((n, *self.shape[1:]))

    def read_all(self) -> np.ndarray:
        return self.read(self.shape[0] if self.shape else 1).reshape(self.shape)


class NpzSource(Source):
    """Events from a ``.npz`` file with named columns.

    Parameters
    ----------
    path:
        The file.
    chunk_events:
        Events per packet read (memory stays bounded by this).
    sensor:
        ``"WIDTHxHEIGHT"`` for files that do not store it.
    time_unit:
        Unit of ``t`` in files from elsewhere: ``s``, ``ms``, ``us`` or ``ns``.
    """

    name = "npz"
    extensions = (".npz",)

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

    def _open(self) -> tuple[dict[str, _Column], tuple[int, int], tuple[int, int] | None, int]:
        try:
            self._zf = zf = zipfile.ZipFile(self.path)
        except (zipfile.BadZipFile, OSError) as e:
            raise FormatError(f"not a readable .npz archive: {e}", path=self.path) from None
        members = [m for m in zf.namelist() if m.endswith(".npy")]
        cols = {m[:-4]: _Column(zf, m, self.path) for m in members}
        missing = [c for c in ("t", "x", "y", "p") if c not in cols]
        if missing:
            raise FormatError(f"missing column(s) {missing}; has {sorted(cols)}", path=self.path)
        n = cols["t"].shape[0] if cols["t"].shape else 0
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
        return cols, sensor, interval, n

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
        only the ``t`` column."""
        cols, sensor, interval, n = self._open()
        try:
            first = last = None
            left = n
            while left:
                k = min(left, self.chunk_events)
                left -= k
                t = _to_us(cols["t"].read(k), _UNITS[self.time_unit])
                first = int(t[0]) if first is None else first
                last = int(t[-1])
        finally:
            self.close()
        dur = last - first if first is not None and last is not None else 0
        return {"format": "npz", "path": self.path, "sensor": sensor, "events": n, "t_first_us": first,
                "t_last_us": last, "duration_us": dur, "rate_mev_s": n / dur if dur > 0 else 0.0,
                "streams": {"events": n}, "t0_offset_us": 0, "skipped_events": 0,
                "interval": interval, "columns": sorted(cols)}

    def packets(self) -> Iterator[EventPacket]:
        cols, sensor, interval, n = self._open()
        try:
            yield from self._chunks(cols, sensor, interval, n)
        finally:
            self.close()

    def _chunks(self, cols: dict[str, _Column], sensor: tuple[int, int],
                interval: tuple[int, int] | None, n: int) -> Iterator[EventPacket]:
        scale = _UNITS[self.time_unit]
        if cols["t"].dtype.kind == "f" and self.time_unit == "us":
            raise FormatError("'t' is floating point: say its unit with time_unit (s, ms, us, ns)",
                              path=self.path)
        names = ("t", "x", "y", "p", *(c for c in cols if c not in ("t", "x", "y", "p")))
        start = interval[0] if interval else None
        carry: dict[str, np.ndarray] | None = None
        left = n
        while left:
            k = min(left, self.chunk_events)
            left -= k
            chunk = {c: cols[c].read(k) for c in names}
            chunk["t"] = _to_us(chunk["t"], scale)
            if carry is not None:
                chunk = {c: np.concatenate([carry[c], chunk[c]]) for c in names}
                carry = None
            if left:  # the last timestamp's run may go on in the next chunk: hold it
                t = chunk["t"]
                i = int(np.searchsorted(t, t[-1], side="left"))
                carry = {c: v[i:] for c, v in chunk.items()}
                if i == 0:
                    continue
                chunk = {c: v[:i] for c, v in chunk.items()}
                t_end = int(carry["t"][0])
            else:
                t_end = interval[1] if interval else int(chunk["t"][-1]) + 1
            t_start = start if start is not None else int(chunk["t"][0])
            yield self._packet(chunk, sensor, t_start, t_end)
            start = t_end
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
    """The whole file as one packet (convenience for tests and scripts)."""
    from tectum import concat

    src = NpzSource(path, **kw)
    pkts = list(src.packets())
    return concat(pkts)  # type: ignore[return-value]
