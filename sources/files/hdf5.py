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

from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from tectum import Kind, Packet, interleave

from ._common import EventAssembler, FileSource
from ._hdf5_samples import sample_groups, sample_streams

__all__ = ["Hdf5Source"]


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

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"\x89HDF\r\n\x1a\n")

    def _file(self) -> Any:
        h5py = _h5py()
        try:
            h = h5py.File(self.path, "r")
        except OSError as e:
            self._fail(f"not a readable HDF5 file: {e}", 0)
        self._files.append(h)
        return h

    def _packets(self) -> Iterator[Packet]:
        h = self._file()
        if "events" in h and all(k in h["events"] for k in "txyp"):
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
            w = max(w, int(np.max(x[i:i + step])) + 1)
            hh = max(hh, int(np.max(y[i:i + step])) + 1)
        return w, hh

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
            pp = np.asarray(p[i:j])
            if pp.size and pp.max() > 1:
                k = int(np.flatnonzero(pp > 1)[0])
                if not self.skip_bad:
                    self._fail(f"event {i + k} has polarity {int(pp[k])}, expected 0/1", None)
            yield from asm.push(np.asarray(t[i:j], np.int64), np.asarray(x[i:j], np.uint16),
                                np.asarray(y[i:j], np.uint16), np.where(pp > 0, 1, -1).astype(np.int8), i)
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
        w = hh = 1
        for i in range(0, n, step):
            a = ds[i:i + step]
            w, hh = max(w, int(a[:, 0].max()) + 1), max(hh, int(a[:, 1].max()) + 1)
        sensor = self._sensor(None) or (w, hh)
        asm = EventAssembler(self, sensor)
        for i in range(0, n, step):
            a = ds[i:i + step]
            t = np.round(a[:, 2] * 1e6).astype(np.int64)
            yield from asm.push(t, a[:, 0].astype(np.uint16), a[:, 1].astype(np.uint16),
                                np.where(a[:, 3] > 0, 1, -1).astype(np.int8), i)
        yield from asm.finish()
