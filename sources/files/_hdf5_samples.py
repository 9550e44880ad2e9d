"""The sample streams of a tectum HDF5 file: one group per kind beside the
DSEC events (``/frames``, ``/imu``, ``/triggers``, ``/poses`` ...: ``t``
int64 µs absolute, one dataset per field, attributes ``kind``, ``t_start``,
``t_end``; the layout is in :mod:`tectum.sinks.files.hdf5`), read a chunk
of rows at a time."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from tectum import FormatError, Kind, SamplePacket, packet_class

if TYPE_CHECKING:
    from ._common import FileSource

__all__ = ["sample_groups", "sample_streams"]

_STEP_BYTES = 1 << 24  # bytes of one stream read at a time


def sample_groups(h: Any) -> list[tuple[Kind, Any]]:
    """The top-level groups of ``h`` that hold a sample stream (a ``kind``
    attribute and a ``t`` dataset), as ``(kind, group)``."""
    out = []
    for name in h:
        g = h.get(name)
        kind = getattr(g, "attrs", {}).get("kind")
        if isinstance(kind, bytes):
            kind = kind.decode()
        if isinstance(kind, str) and kind not in ("events", "results") and "t" in g:
            out.append((Kind(kind), g))
    return out


def sample_streams(h: Any, src: FileSource, offset: int) -> list[Iterator[SamplePacket]]:
    """A packet iterator per sample stream of ``h``, in time order, tiling
    the stream's interval, clipped to the source's ``[t_start_us,
    t_end_us)``; ``offset`` (µs) is subtracted from the stored absolute
    times (the file's ``t_offset`` when the source does not apply it)."""
    return [_packets(kind, g, src, offset) for kind, g in sample_groups(h)]


def _packets(kind: Kind, g: Any, src: FileSource, offset: int) -> Iterator[SamplePacket]:
    from tectum.sources.npz import _tiles

    try:
        cls = packet_class(kind)
    except KeyError as e:
        raise FormatError(f"group {g.name!r}: {e.args[0]}", path=src.path) from None
    assert issubclass(cls, SamplePacket)
    t = g["t"]
    names = [k for k in g if k != "t"]
    n = t.shape[0]
    for k in names:
        if g[k].shape[:1] != (n,):
            raise FormatError(f"{g.name}/{k} has shape {g[k].shape}, {g.name}/t has {n} rows", path=src.path)
    interval = None
    if "t_start" in g.attrs and "t_end" in g.attrs:
        interval = (int(g.attrs["t_start"]) - offset, int(g.attrs["t_end"]) - offset)
    row = 8 + sum(g[k].dtype.itemsize * int(np.prod(g[k].shape[1:], dtype=np.int64)) for k in names)
    at = 0

    def read(k: int) -> dict[str, np.ndarray]:
        nonlocal at
        rows = {name: g[name][at:at + k] for name in names}
        rows["t"] = np.asarray(t[at:at + k], np.int64) - offset
        at += k
        return rows

    lo, hi = src.t_start_us, src.t_end_us
    for rows, t0, t1 in _tiles(read, n, max(1, _STEP_BYTES // row), interval):
        if hi is not None and t0 >= hi:
            return
        t_rows = rows.pop("t")
        try:
            pkt = cls(t_rows, t_start=t0, t_end=t1, **rows)
        except Exception as e:
            raise FormatError(f"{g.name}: {e}", path=src.path) from None
        yield from _clip(pkt, lo, hi)
    if n == 0 and interval:  # a stream of ticks only
        yield from _clip(cls.empty(*interval), lo, hi)


def _clip(pkt: SamplePacket, lo: int | None, hi: int | None) -> Iterator[SamplePacket]:
    a = pkt.t_start if lo is None else max(pkt.t_start, lo)
    b = pkt.t_end if hi is None else min(pkt.t_end, hi)
    if (a, b) == (pkt.t_start, pkt.t_end):
        yield pkt
    elif a < b:
        yield pkt.slice_time(a, b)
