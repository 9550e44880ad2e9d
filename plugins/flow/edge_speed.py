"""``flow.edge_speed``: normal flow by time of flight between neighbouring pixels.

The simplest method. For each event, the time the edge took to travel from
a 4-neighbour to this pixel (same polarity, surface of active events) gives
the gradient of the time surface along x and y: a one-sided difference with
the neighbour that fired within ``window_us``, or, when both did (an edge
along that axis), a central difference if their ages agree within
``tolerance_us`` (else the event is inconsistent: noise). A one-sided
time of flight must be confirmed by the pixel two steps back, which the edge
passed about twice as long ago. The normal flow is ``g / |g|^2`` (``g`` in µs/px).
An event is invalid when an axis has no recent neighbour or the speed is
outside ``[min_speed, max_speed]`` px/s.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, same_sensor

from ._common import FlowOperator, new_sae, store_gradient_flow

__all__ = ["EdgeSpeed", "edge_speed_kernel"]


@njit(cache=True, nogil=True, inline="always")
def _axis_slope(sae, k, xi, yi, ti, dx, dy, w, h, window_us, tolerance_us):  # type: ignore[no-untyped-def]
    """dT/ds (µs/px) along (dx, dy) at (xi, yi); (slope, ok). Both neighbours
    can only be older than this event if the edge runs along the axis, so
    then their ages must agree within ``tolerance_us``."""
    xa, ya, xb, yb = xi - dx, yi - dy, xi + dx, yi + dy
    back = ti - sae[k, ya, xa] if 0 <= xa < w and 0 <= ya < h else window_us + 1
    fwd = ti - sae[k, yb, xb] if 0 <= xb < w and 0 <= yb < h else window_us + 1
    okb, okf = back <= window_us, fwd <= window_us
    if okb and okf:
        return 0.5 * (back - fwd), abs(back - fwd) <= tolerance_us
    if okb:
        return float(back), _steady(sae, k, xi - 2 * dx, yi - 2 * dy, ti, back, w, h, tolerance_us)
    if okf:
        return -float(fwd), _steady(sae, k, xi + 2 * dx, yi + 2 * dy, ti, fwd, w, h, tolerance_us)
    return 0.0, False


@njit(cache=True, nogil=True, inline="always")
def _steady(sae, k, x2, y2, ti, tof, w, h, tolerance_us):  # type: ignore[no-untyped-def]
    """A moving edge reached the pixel two steps back about twice the time
    of flight ago (to ``tolerance_us`` plus a quarter of it); noise rarely does."""
    if not (0 <= x2 < w and 0 <= y2 < h):
        return True
    return abs((ti - sae[k, y2, x2]) - 2 * tof) <= tolerance_us + 0.25 * tof


@njit(cache=True, nogil=True)
def edge_speed_kernel(t, x, y, p, sae, window_us, tolerance_us, min_speed, max_speed, vx, vy, valid):  # type: ignore[no-untyped-def]
    """Per event: update ``sae`` (2, H, W) and write the normal flow (px/s)
    into ``vx``/``vy`` (NaN when invalid) and ``valid``."""
    _, h, w = sae.shape
    for i in range(t.shape[0]):
        k = 1 if p[i] > 0 else 0
        xi, yi, ti = np.int64(x[i]), np.int64(y[i]), t[i]
        sae[k, yi, xi] = ti
        gx, okx = _axis_slope(sae, k, xi, yi, ti, 1, 0, w, h, window_us, tolerance_us)
        gy, oky = _axis_slope(sae, k, xi, yi, ti, 0, 1, w, h, window_us, tolerance_us)
        store_gradient_flow(i, okx and oky, gx, gy, min_speed, max_speed, vx, vy, valid)


class EdgeSpeed(FlowOperator):
    """Normal flow (px/s) by time of flight between 4-neighbours.

    Output: **normal flow** in ``out_vx``/``out_vy`` (default ``vx``/``vy``),
    NaN where ``out_valid`` is false. Parameters: ``window_us`` (µs) how old a
    neighbour's last event may be; ``tolerance_us`` (µs) how far the two
    neighbours' ages may differ when both are recent (an edge along the
    axis); ``min_speed``/``max_speed`` (px/s) the
    range of speeds reported. State: 2 x H x W int64 timestamps.
    """

    name = "flow.edge_speed"
    flow_type = "normal"

    def __init__(self, window_us: int = 20_000, tolerance_us: int = 1000, min_speed: float = 1.0,
                 max_speed: float = 20_000.0,
                 out_vx: str = "vx", out_vy: str = "vy", out_valid: str = "valid") -> None:
        if window_us <= 0 or not 0 <= min_speed < max_speed:
            raise ValueError("need window_us > 0 and 0 <= min_speed < max_speed")
        self.window_us, self.min_speed, self.max_speed = int(window_us), float(min_speed), float(max_speed)
        self.tolerance_us = int(tolerance_us)
        self._set_outputs(out_vx, out_vy, out_valid)
        self.sae: np.ndarray | None = None
        self._sensor = (0, 0)  # (width, height) px the surface was made for

    def memory_us(self) -> int:
        """Neighbours older than ``window_us`` count as silent, and the pixel
        two steps back is checked for an age of about twice the time of
        flight: at most ``2.25 window_us + tolerance_us`` (time sharding)."""
        return (9 * self.window_us) // 4 + self.tolerance_us + 1

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.sae is None:
            self.sae = new_sae(packet.sensor)
            self._sensor = packet.sensor
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        vx, vy, valid = self._alloc(len(packet))
        edge_speed_kernel(packet.t, packet.x, packet.y, packet.p, self.sae, self.window_us, self.tolerance_us,
                          self.min_speed, self.max_speed, vx, vy, valid)
        return [self._emit(packet, vx, vy, valid)]
