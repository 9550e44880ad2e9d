"""Sample streams to CSV (``.csv``): one kind per file.

The file (read back by :class:`tectum.sources.files.samples_csv.CsvSource`)::

    # tectum imu
    t,ax,ay,az,gx,gy,gz
    1000,0.01,-9.81,0.2,0.001,0.002,-0.003

A first line ``# tectum KIND`` (with the dtypes of undeclared fields), a
header row with ``t`` (integer µs) and the flat columns of every field
present (:mod:`tectum.tables`), in declaration order, then undeclared
fields; one row per sample, floats with the fewest digits that read back
to the same float64, so a round trip is exact.

Which stream: the one named by ``kind`` (``out.csv?kind=imu``), else the
only kind with flat fields the pipeline can bring to the sink (known when
it is validated: a run that yields none still writes that header), else
the first such kind that reaches the sink (frames and maps have
images: write them to ``.npz``). Events are written only when nothing else
comes (the RPG CSV layout of :class:`tectum.sinks.files.text.TextSink`,
``t,x,y,p`` in seconds) or when ``kind=events``: until a sample packet
arrives they go to a temporary file of their own, deleted when one does, so
naming the kind spares that work on a recording with both.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from tectum import EventPacket, Kind, Packet, SamplePacket, Sink
from tectum.tables import flat_kinds, kind_line

from ._common import count_unwritten
from ._rows import SampleFileSink, text_rows
from .text import TextSink

__all__ = ["CsvSink", "SampleCsvWriter"]


class SampleCsvWriter(SampleFileSink):
    """Writes one sample kind as CSV (see the module docstring)."""

    format = "csv"

    def __init__(self, path: str, kind: Kind) -> None:
        super().__init__(path)
        self.kind = kind

    def _head(self) -> None:
        assert self.groups is not None and self.cls is not None
        names = ["t", *(c for g in self.groups for c in g.columns)]
        self._put(kind_line(self.kind, self.groups, self.cls) + "\n" + ",".join(names) + "\n")

    def _rows(self, t: np.ndarray, data: dict[str, np.ndarray]) -> None:
        assert self.groups is not None
        self._put(text_rows(t, data, self.groups, ","))


class CsvSink(Sink):
    """One stream to CSV: a sample kind, or events (see the module docstring).

    Parameters
    ----------
    path:
        The output file; replaced atomically when the run ends well.
    kind:
        The stream to write (``imu``, ``poses``, ``tracks`` ..., or
        ``events``); by default the first sample kind that comes, else events.
    columns, time_unit:
        For events: as :class:`tectum.sinks.files.text.TextSink`.
    """

    name = "csv"
    title = "CSV"
    holds = "one stream per file"
    extensions = (".csv",)
    consumes: ClassVar[tuple[Kind, ...]] = (Kind.ANY,)

    def __init__(self, path: str, kind: str | None = None, columns: str = "txyp", time_unit: str = "s") -> None:
        if kind is not None and kind != Kind.EVENTS and kind not in flat_kinds():
            raise ValueError(f"csv: kind {kind!r} is not one a CSV holds (events, {', '.join(flat_kinds())}; "
                             "frames and maps go to .npz)")
        self.path = path
        self.kind = None if kind is None else Kind(kind)
        self.events: TextSink | None = None
        if self.kind in (None, Kind.EVENTS):
            self.events = TextSink(path, columns=columns, time_unit=time_unit)
        self.samples: SampleCsvWriter | None = None
        if self.kind not in (None, Kind.EVENTS):
            self.samples = SampleCsvWriter(path, self.kind)
        #: What came and was not stored (the other streams), by kind.
        self.not_written: dict[str, int] = {}

    @classmethod
    def planned_params(cls, params: dict[str, Any], upstream: frozenset[Kind]) -> dict[str, Any]:
        """At validation, with the kinds of stream that reach the sink: when
        no ``kind`` is given and exactly one flat sample kind comes (say a
        tracker's output), the file holds that one, so a run that yields no
        sample still writes its header (not an events CSV)."""
        flat = [k for k in upstream if k in flat_kinds()]
        if params.get("kind") is None and len(flat) == 1:
            return {**params, "kind": str(flat[0])}
        if params.get("kind") is None and not flat and Kind.EVENTS not in upstream and Kind.ANY not in upstream:
            raise ValueError(f"csv: its input provides only {', '.join(sorted(map(str, upstream)))}: a CSV holds "
                             f"events or one of {', '.join(flat_kinds())} (frames and maps go to .npz)")
        return params

    def open(self) -> None:
        for s in (self.events, self.samples):
            if s is not None:
                s.open()

    def write(self, packet: Packet) -> None:
        if isinstance(packet, EventPacket):
            if self.events is not None:
                self.events.write(packet)
            else:
                self._skip(packet)
            return
        if self.samples is None:
            if self.kind is not None or packet.kind not in flat_kinds():
                self._skip(packet)
                return
            assert isinstance(packet, SamplePacket)
            self.samples = SampleCsvWriter(self.path, packet.kind)
            self.samples.open()
            if self.events is not None:  # a sample stream is what this file holds
                if self.events.count:
                    self.not_written["events"] = self.events.count
                self.events.abort()
                self.events = None
        if packet.kind != self.samples.kind:
            self._skip(packet)
            return
        self.samples.write(packet)

    def _skip(self, packet: Packet) -> None:
        count_unwritten(self.not_written, packet)

    def close(self) -> None:
        for s in (self.samples, self.events):
            if s is not None:
                s.close()

    def abort(self) -> None:
        for s in (self.samples, self.events):
            if s is not None:
                s.abort()
