"""``filter.refractory``: a per-pixel refractory period."""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, Operator, same_sensor

from ._state import NEVER, select

__all__ = ["Refractory", "refractory_kernel"]


@njit(cache=True, nogil=True)
def refractory_kernel(t, x, y, last, period_us, keep):  # type: ignore[no-untyped-def]
    """Mark in ``keep`` the events at least ``period_us`` after the last kept
    event of their pixel; ``last`` (H, W) int64 is the per-pixel state, updated
    in place. Returns the number kept."""
    n = 0
    for i in range(t.shape[0]):
        yy, xx = y[i], x[i]
        if t[i] - last[yy, xx] >= period_us:
            last[yy, xx] = t[i]
            keep[i] = True
            n += 1
        else:
            keep[i] = False
    return n


class Refractory(Operator):
    """Drop events that come less than ``period_us`` µs after the last *kept*
    event of the same pixel (dropped events do not extend the period).

    State: one int64 timestamp per pixel (8 bytes x width x height).
    """

    name = "filter.refractory"

    def __init__(self, period_us: int = 1000) -> None:
        if period_us < 0:
            raise ValueError("period_us must be >= 0")
        self.period_us = int(period_us)
        self.last: np.ndarray | None = None
        self._sensor = (0, 0)  # (width, height) the state was made for

    def memory_us(self) -> None:
        """Whether an event is kept depends on the last kept one, which
        depends on the one kept before it: a chain of events closer than
        ``period_us`` reaches back without bound."""
        return None

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.last is None:
            w, h = self._sensor = packet.sensor
            self.last = np.full((h, w), NEVER, np.int64)
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        keep = np.empty(len(packet), np.bool_)
        refractory_kernel(packet.t, packet.x, packet.y, self.last, self.period_us, keep)
        return [select(packet, keep)]
