"""``filter.time_window``: keep the events of one time interval."""

from __future__ import annotations

from tectum import EventPacket, Operator

__all__ = ["TimeWindow"]


class TimeWindow(Operator):
    """Keep events with ``start_us <= t < stop_us`` (µs; ``stop_us`` None =
    open-ended). With ``relative`` both are counted from the first packet's
    ``t_start``. Output packets keep their input intervals, so time goes on
    advancing downstream outside the window. State: two integers."""

    name = "filter.time_window"

    def __init__(self, start_us: int = 0, stop_us: int | None = None, relative: bool = False) -> None:
        if stop_us is not None and stop_us < start_us:
            raise ValueError("stop_us must be >= start_us")
        self.start_us, self.stop_us, self.relative = int(start_us), stop_us, bool(relative)
        self._origin: int | None = None

    def memory_us(self) -> int | None:
        """Absolute times: no memory; ``relative`` counts from the stream's
        first packet, which a time shard does not see (None: no sharding)."""
        return None if self.relative else 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self._origin is None:
            self._origin = packet.t_start if self.relative else 0
        t0 = self._origin + self.start_us
        t1 = None if self.stop_us is None else self._origin + int(self.stop_us)
        if packet.t_start >= t0 and (t1 is None or packet.t_end <= t1):
            return [packet]
        part = packet.slice_time(t0, t1)
        return [part.with_interval(packet.t_start, packet.t_end)]
