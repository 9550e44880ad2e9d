"""HDF5 event files (``h5py``, the ``hdf5`` extra; ``hdf5plugin`` for Blosc).

Layouts:

* DSEC: ``events/{t,x,y,p}`` (t uint32 µs relative to ``t_offset``, p 0/1),
  ``ms_to_idx`` (index of the first event at or after each millisecond,
  relative time) and ``t_offset`` (µs, added to ``t`` and reported).
  ``ms_to_idx`` makes a time range a seek.
* MVSEC-style: one ``(N, 4)`` float dataset of ``x, y, t (s), p (-1/1)``
  (e.g. ``davis/left/events``), found by name ending in ``events``.

The sensor size is read from the ``sensor`` attribute (written by the tectum
sink), else the option, else the coordinates' extent (a pass over x/y).

Sample streams that the tectum sink writes beside DSEC events (one group per
kind: ``/frames``, ``/imu``, ``/triggers``, ``/poses`` ...; see
:mod:`tectum.sinks.files.hdf5`) come back interleaved with the events.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from tectum import Kind, Packet, interleave

from ._common import EventAssembler, FileSource
from ._hdf5_blocks import BlockReader, chunk_bytes, open_file
from ._hdf5_samples import sample_groups, sample_streams

__all__ = ["Hdf5Source"]


def _whole(a: np.ndarray, hi: int, lo: int = 0) -> np.ndarray:
    """Which values of ``a`` are whole numbers in ``[lo, hi]``."""
    if a.dtype.kind == "b":
        return np.ones(a.shape, np.bool_)
    if a.dtype.kind in "iu":
        info = np.iinfo(a.dtype)
        if info.min >= lo and info.max <= hi:
            return np.ones(a.shape, np.bool_)
        return (a >= lo) & (a <= hi)
    if a.dtype.kind == "f":  # below hi + 1 as a float: 2**63 - 1 rounds up to 2**63
        with np.errstate(invalid="ignore"):
            return np.isfinite(a) & (a >= lo) & (a < float(hi) + 1) & (a == np.round(a))
    return np.zeros(a.shape, np.bool_)


def _mvsec_rows(a: np.ndarray) -> np.ndarray:
    """Rows of an MVSEC ``(N, 4)`` array (x, y, t s, p) that are events:
    whole coordinates within uint16, a finite time within int64 µs, a
    finite polarity."""
    if a.dtype.kind not in "iuf":
        return np.zeros(a.shape[0], np.bool_)
    with np.errstate(invalid="ignore"):
        return (_whole(a[:, 0], 0xFFFF) & _whole(a[:, 1], 0xFFFF) & np.isfinite(a[:, 2])
                & (np.abs(a[:, 2]) < 9.2e12) & np.isfinite(a[:, 3]))


def _h5py() -> Any:
    try:
        import h5py
    except ImportError:
        raise ImportError("HDF5 files need h5py: pip install 'tectum[hdf5]'") from None
    try:
        import hdf5plugin  # noqa: F401  (registers Blosc, Zstd... filters)
    except ImportError:
        pass
    return h5py


class Hdf5Source(FileSource):
    """Events from DSEC-layout (and MVSEC-style) HDF5 files."""

    name = "hdf5"
    format = "hdf5"
    extensions = (".h5", ".hdf5")
    produces = tuple(k for k in Kind if k != Kind.RESULTS)  # the kinds registered when this module is imported

    @classmethod
    def kinds_for(cls, arg: str, params: Mapping[str, Any]) -> tuple[Kind, ...]:
        """Events and the sample streams the file holds (its groups)."""
        try:
            with _h5py().File(arg, "r") as h:
                return (Kind.EVENTS, *(k for k, _ in sample_groups(h)))
        except (OSError, ImportError):
            return cls.produces  # opening will say what is wrong

    def __init__(self, path: str, **kw: Any) -> None:
        super().__init__(path, **kw)
        self._reader = BlockReader(self, None)

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"\x89HDF\r\n\x1a\n")

    def _file(self) -> Any:
        h5py = _h5py()
        try:
            if os.path.getsize(self.path) == 0:
                self._fail("empty file: no HDF5 superblock, no events", 0)
            h, past = open_file(h5py, self.path)
        except OSError as e:
            self._fail(f"not a readable HDF5 file: {e}", 0)
        self._files += [h] if past is None else [h, past]  # the file object closes after the file
        self._reader = BlockReader(self, past)
        return h

    def _packets(self) -> Iterator[Packet]:
        """The packets; HDF5 errors from deep inside (damaged metadata, a
        dataset past the end of a truncated file) become FormatErrors."""
        try:
            yield from self._layouts()
        except (OSError, KeyError, RuntimeError) as e:
            past = self._reader.past
            self._fail(f"the HDF5 structure cannot be read ({e}): {self._reader.why()}",
                       None if past is None else past.real)

    def _layouts(self) -> Iterator[Packet]:
        h = self._file()
        if "events" in h and hasattr(h["events"], "keys") and all(k in h["events"] for k in "txyp"):  # a group
            off = int(h["t_offset"][()]) if "t_offset" in h and not self.apply_t0 else 0
            yield from interleave(self._dsec(h), sample_streams(h, self, off))
            return
        ds = self._mvsec(h)
        if ds is None:
            self._fail("no DSEC events/{t,x,y,p} group nor an (N, 4) events dataset")
        yield from self._mvsec_events(h, ds)

    def _sensor_of(self, h: Any, x: Any, y: Any) -> tuple[int, int]:
        found = None
        for obj in (h, h.get("events")):
            if obj is not None and "sensor" in obj.attrs:
                s = obj.attrs["sensor"]
                found = (int(s[0]), int(s[1]))
        s = self._sensor(found)
        if s is not None:
            return s
        w = hh = 1
        step = max(1, self.chunk_bytes // 2)
        for i in range(0, x.shape[0], step):
            (xs, ys), keep = self._reader.read([x, y], i, min(x.shape[0], i + step), count=False)
            ok = _whole(xs, 0xFFFF) & _whole(ys, 0xFFFF) & (True if keep is None else keep)
            if ok.any():
                w = max(w, int(np.max(xs[ok])) + 1)
                hh = max(hh, int(np.max(ys[ok])) + 1)
        return self._sensor_guessed((w, hh))

    def _dsec(self, h: Any) -> Iterator[Packet]:
        ev = h["events"]
        t, x, y, p = ev["t"], ev["x"], ev["y"], ev["p"]
        n = t.shape[0]
        if not (x.shape[0] == y.shape[0] == p.shape[0] == n):
            self._fail(f"events/t,x,y,p have different lengths {t.shape[0]}, {x.shape[0]}, {y.shape[0]}, {p.shape[0]}")
        off = int(h["t_offset"][()]) if "t_offset" in h else 0
        self.t0_offset = off
        add = off if self.apply_t0 else 0
        sensor = self._sensor_of(h, x, y)
        start = 0
        if self.t_start_us is not None and "ms_to_idx" in h:
            ms = (self.t_start_us - add) // 1000
            m2i = h["ms_to_idx"]
            if ms >= m2i.shape[0]:
                start = n
            elif ms > 0:
                start = int(m2i[ms])
        asm = EventAssembler(self, sensor, offset=add)
        step = max(1, self.chunk_bytes // 8)
        for i in range(start, n, step):
            j = min(n, i + step)
            (tt, xx, yy, pp), keep = self._reader.read([t, x, y, p], i, j)
            keep = self._values(i, keep, (t, tt, _whole(tt, (1 << 63) - 1, -(1 << 63))), (x, xx, _whole(xx, 0xFFFF)),
                                (y, yy, _whole(yy, 0xFFFF)), (p, pp, _whole(pp, 1)))
            if keep is not None:
                tt, xx, yy, pp = tt[keep], xx[keep], yy[keep], pp[keep]
            yield from asm.push(tt.astype(np.int64), xx.astype(np.uint16), yy.astype(np.uint16),
                                np.where(pp > 0, 1, -1).astype(np.int8), i)
            if self.t_end_us is not None and asm.last_t is not None and asm.last_t >= self.t_end_us:
                break
        yield from asm.finish()

    def _mvsec(self, h: Any) -> Any:
        found = []

        def visit(name: str, obj: Any) -> None:
            if name.split("/")[-1] == "events" and getattr(obj, "ndim", 0) == 2 and obj.shape[1] == 4:
                found.append(obj)

        h.visititems(visit)
        return found[0] if found else None

    def _mvsec_events(self, h: Any, ds: Any) -> Iterator[Packet]:
        n = ds.shape[0]
        step = max(1, self.chunk_bytes // 32)
        sensor = self._sensor(None)
        if sensor is None:
            w = hh = 1
            for i in range(0, n, step):
                (a,), keep = self._reader.read([ds], i, min(n, i + step), count=False)
                ok = _mvsec_rows(a) & (True if keep is None else keep)
                if ok.any():
                    w, hh = max(w, int(a[ok, 0].max()) + 1), max(hh, int(a[ok, 1].max()) + 1)
            sensor = self._sensor_guessed((w, hh))
        asm = EventAssembler(self, sensor)
        for i in range(0, n, step):
            (a,), keep = self._reader.read([ds], i, min(n, i + step))
            keep = self._values(i, keep, (ds, a, _mvsec_rows(a)))
            if keep is not None:
                a = a[keep]
            t = np.round(a[:, 2].astype(np.float64) * 1e6).astype(np.int64)  # float32 times: µs in double
            yield from asm.push(t, a[:, 0].astype(np.uint16), a[:, 1].astype(np.uint16),
                                np.where(a[:, 3] > 0, 1, -1).astype(np.int8), i)
        yield from asm.finish()

    def _values(self, i: int, keep: np.ndarray | None,
                *checks: tuple[Any, np.ndarray, np.ndarray]) -> np.ndarray | None:
        """Rows from ``i`` whose values are out of range (each check: a
        dataset, its values, the mask of good ones): a FormatError naming
        the first, or with ``skip_bad`` dropped and counted; the rows to
        keep (None: all)."""
        good = np.ones_like(checks[0][2]) if keep is None else keep.copy()
        for d, vals, ok in checks:
            bad = good & ~ok
            if bad.any():
                k = np.flatnonzero(bad)
                at = chunk_bytes(d, i + int(k[0]))[0]
                if not self.skip_bad:
                    self._fail(f"{d.name}: row {i + int(k[0])} holds {vals[k[0]].tolist()!r}, out of range", at)
                self._note_skip(at, chunk_bytes(d, i + int(k[-1]))[0], int(k.shape[0]))
                good &= ok
        return None if good.all() else good
