"""``filter.spatiotemporal_correlation``: Guo & Delbruck's STCF."""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, Operator, same_sensor

from ._state import padded_timestamps, select

__all__ = ["SpatioTemporalCorrelation", "stcf_kernel"]


@njit(cache=True, nogil=True)
def stcf_kernel(t, x, y, p, last, dt_us, k, by_polarity, keep):  # type: ignore[no-untyped-def]
    """Keep event ``i`` when at least ``k`` of its 8 neighbours fired at or
    after ``t[i] - dt_us``. ``last`` is a ``(C, H + 2, W + 2)`` int64 padded
    map of last event times (µs), updated in place by every event; with
    ``by_polarity`` (C = 2) only neighbours of the same polarity count
    (channel 1 = ON, 0 = OFF). Writes ``keep``; returns the number kept."""
    n = 0
    for i in range(t.shape[0]):
        ti = t[i]
        lim = ti - dt_us
        xx = np.intp(x[i]) + 1
        yy = np.intp(y[i]) + 1
        c = 1 if (by_polarity and p[i] > 0) else 0
        m = last[c]
        # the sum starts from an int: numpy adds two bools as a logical or (as
        # Python, with NUMBA_DISABLE_JIT=1, it would count at most 1)
        s = (
            0 + (m[yy - 1, xx - 1] >= lim) + (m[yy - 1, xx] >= lim) + (m[yy - 1, xx + 1] >= lim)
            + (m[yy, xx - 1] >= lim) + (m[yy, xx + 1] >= lim)
            + (m[yy + 1, xx - 1] >= lim) + (m[yy + 1, xx] >= lim) + (m[yy + 1, xx + 1] >= lim)
        )
        ok = s >= k
        keep[i] = ok
        n += ok
        m[yy, xx] = ti
    return n


class SpatioTemporalCorrelation(Operator):
    """Spatio-temporal correlation filter (Guo & Delbruck, TPAMI 2022): keep
    an event when at least ``k`` of its 8 neighbours fired within the last
    ``dt_us`` µs (inclusive); with ``polarity`` only neighbours of the same
    polarity count. Each neighbour counts once, however often it fired.
    ``k = 1`` without polarity is the background-activity filter.

    Poisson noise of rate ``r`` Hz/px passes with probability
    ``P[Binomial(8, 1 - exp(-r dt)) >= k]`` (rate per polarity with
    ``polarity``).

    Defaults ``dt_us = 10000``, ``k = 2``: 1 % of 2 Hz/px noise passes.

    State: one int64 timestamp per pixel (two with ``polarity``) plus a
    one-pixel border: 8 x C x (W + 2) x (H + 2) bytes.
    """

    name = "filter.spatiotemporal_correlation"

    def __init__(self, dt_us: int = 10_000, k: int = 2, polarity: bool = False) -> None:
        if dt_us < 0:
            raise ValueError("dt_us must be >= 0")
        if not 1 <= k <= 8:
            raise ValueError("k must be in 1..8 neighbours")
        self.dt_us, self.k, self.polarity = int(dt_us), int(k), bool(polarity)
        self.last: np.ndarray | None = None
        self._sensor = (0, 0)  # (width, height) the state was made for

    def memory_us(self) -> int:
        """Only neighbours' times within ``dt_us`` count (time sharding)."""
        return self.dt_us

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.last is None:
            self._sensor = packet.sensor
            self.last = padded_timestamps(packet.sensor, 2 if self.polarity else 1)
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        keep = np.empty(len(packet), np.bool_)
        stcf_kernel(packet.t, packet.x, packet.y, packet.p, self.last, self.dt_us, self.k, self.polarity, keep)
        return [select(packet, keep)]
