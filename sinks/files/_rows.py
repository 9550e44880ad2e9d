"""The base of the sinks that write one sample stream as rows (CSV, TUM,
PLY): the temporary file and rename of :class:`FileSink`, and one column
layout for the whole file.

The layout (:func:`tectum.tables.layout`) comes from the first packet with
samples (or, for a stream without any, from the kind's required fields).
Later packets must fit it: an optional float field they lack is NaN in
their rows (as :func:`tectum.concat` joins them); a field the layout lacks,
or a missing field that cannot be NaN, is a ValueError naming it.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from tectum import Kind, Packet, SamplePacket, packet_class
from tectum.tables import Group, float_text, layout, us_text

from ._common import FileSink

__all__ = ["SampleFileSink"]


class SampleFileSink(FileSink):
    """Subclasses set :attr:`kind` (or ``self.kind``) and implement
    :meth:`_head` (write the header once the layout is known) and
    :meth:`_rows`; :meth:`_layout` may narrow the fields stored."""

    kind: Kind
    consumes: ClassVar[tuple[Kind, ...]] = ()

    def __init__(self, path: str) -> None:
        super().__init__(path)
        self.groups: list[Group] | None = None
        self.cls: type[SamplePacket] | None = None
        #: Samples written.
        self.rows = 0

    def _other(self, packet: Packet) -> None:
        if packet.kind != self.kind or not len(packet):
            return
        assert isinstance(packet, SamplePacket)
        if self.groups is None:
            self._start(type(packet), dict(packet.data))
        self._rows(packet.t, self._fit(packet))
        self.rows += len(packet)

    def _start(self, cls: type[SamplePacket], data: dict[str, np.ndarray]) -> None:
        self.cls = cls
        self.groups = self._layout(cls, data)
        self._head()

    def _layout(self, cls: type[SamplePacket], data: dict[str, np.ndarray]) -> list[Group]:
        return layout(cls, data)

    def _fit(self, packet: SamplePacket) -> dict[str, np.ndarray]:
        """The packet's fields in the file's layout."""
        assert self.groups is not None and self.cls is not None
        out = {}
        for g in self.groups:
            a = packet.data.get(g.field)
            if a is None:
                spec = self.cls.fields.get(g.field)
                if spec is None or not spec.optional or g.dtype.kind != "f":
                    raise ValueError(f"{self.format}: field {g.field!r} is missing from a packet at "
                                     f"t={int(packet.t[0])} µs, and only optional float fields may be (NaN)")
                a = np.full((len(packet),) if g.width is None else (len(packet), g.width), np.nan, g.dtype)
            elif a.dtype != g.dtype or a.shape[1:] != (() if g.width is None else (g.width,)):
                raise ValueError(f"{self.format}: field {g.field!r} changes from {g.dtype} to {a.dtype} "
                                 f"{a.shape[1:]} per sample at t={int(packet.t[0])} µs")
            out[g.field] = a
        known = {g.field for g in self.groups}
        new = [f for f in packet.data if f not in known]
        if new:
            raise ValueError(f"{self.format}: field(s) {new} first appear at t={int(packet.t[0])} µs, after the "
                             "file's columns were written (they come from the first packet with samples)")
        return out

    def _empty(self) -> None:
        """No packet with samples came: the header of the kind's required fields."""
        if self.groups is None:
            cls = packet_class(self.kind)
            assert issubclass(cls, SamplePacket)
            self._start(cls, dict(cls.empty(0).data))

    def _head(self) -> None:
        raise NotImplementedError

    def _rows(self, t: np.ndarray, data: dict[str, np.ndarray]) -> None:
        raise NotImplementedError

    def _put(self, text: str) -> None:
        assert self.f is not None
        self.f.write(text.encode("ascii"))


def text_rows(t: np.ndarray, data: dict[str, np.ndarray], groups: list[Group], sep: str, time_digits: int = 0,
              time_last: bool = False) -> str:
    """Rows of text: the time (:func:`tectum.tables.us_text` with
    ``time_digits``: 0 integer µs, 6 seconds), then (or, with
    ``time_last``, before it) every column of ``groups``: integers as they
    are, floats as :func:`tectum.tables.float_text`; ``sep`` between."""
    cols: list[list[str]] = []
    for g in groups:
        a = data[g.field]
        fmt = str if a.dtype.kind in "biu" else float_text
        block = a.reshape(len(t), -1).astype(np.int64 if a.dtype.kind == "b" else a.dtype)
        for j in range(block.shape[1]):
            cols.append([fmt(v) for v in block[:, j].tolist()])
    times = [us_text(v, time_digits) for v in t.tolist()]
    cols = [*cols, times] if time_last else [times, *cols]
    return "".join(sep.join(row) + "\n" for row in zip(*cols))
