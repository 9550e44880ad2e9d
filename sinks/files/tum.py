"""Poses to TUM trajectory files (``.tum``): one line ``t tx ty tz qx qy
qz qw`` per pose after a ``# t[s] tx ty tz qx qy qz qw`` comment, space
separated; ``t`` in seconds with 6 decimals (exactly the integer µs), the
other numbers with the fewest digits that read back to the same float64.
Velocities a pose stream may carry have no column in the format and are not
written. Rows a tracker flags ``lost`` (a prediction, not a measurement) are
left out and counted in :attr:`TumSink.not_written` (``tectum run`` says so);
CSV and npz sinks keep them with the flag.
:class:`tectum.sources.files.tum.TumSource` reads the file back."""

from __future__ import annotations

import numpy as np

from tectum import Kind, Packet, PosePacket, SamplePacket
from tectum.tables import Group, layout

from ._rows import SampleFileSink, text_rows

__all__ = ["TumSink"]


class TumSink(SampleFileSink):
    """Poses (position m, orientation quaternion x y z w) to a TUM file."""

    name = "tum"
    format = "tum"
    title = "TUM"
    extensions = (".tum",)
    holds = "measured poses only, not the rows a tracker flags lost"
    consumes = (Kind.POSES,)
    kind = Kind.POSES

    def __init__(self, path: str) -> None:
        super().__init__(path)
        #: Poses that came and were not written (flagged ``lost``), by kind.
        self.not_written: dict[str, int] = {}

    def _other(self, packet: Packet) -> None:
        lost = packet.data.get("lost") if isinstance(packet, SamplePacket) and packet.kind == self.kind else None
        if lost is not None and lost.any():
            assert isinstance(packet, SamplePacket)
            n = int(np.count_nonzero(lost))
            self.not_written[str(self.kind)] = self.not_written.get(str(self.kind), 0) + n
            packet = packet.take(np.flatnonzero(~lost.astype(bool)))
        super()._other(packet)

    def _layout(self, cls: type[SamplePacket], data: dict[str, np.ndarray]) -> list[Group]:
        return layout(PosePacket, {f: data[f] for f in ("position", "orientation")})

    def _fit(self, packet: SamplePacket) -> dict[str, np.ndarray]:
        return {"position": packet.data["position"], "orientation": packet.data["orientation"]}

    def _head(self) -> None:
        self._put("# t[s] tx ty tz qx qy qz qw\n")

    def _rows(self, t: np.ndarray, data: dict[str, np.ndarray]) -> None:
        assert self.groups is not None
        self._put(text_rows(t, data, self.groups, " ", time_digits=6))
