"""``flow.plane_fit``: normal flow from local plane fits on the surface of
active events (Benosman et al., TNNLS 2014), with a robust variant in the
spirit of Rueckauer & Delbruck (2016). See :mod:`tectum.plugins.flow._plane`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, same_sensor

from ._common import FlowOperator, gradient_flow
from ._plane import FASTMATH, SPAN, crossing_time, new_surface, plane_fit_at, plane_scratch, rel_time

__all__ = ["PlaneFit", "plane_flow_kernel"]


@njit(cache=True, nogil=True, fastmath=FASTMATH)
def plane_flow_kernel(t, x, y, p, sae, base, last, burst_us, radius, window_us, n_iter, reject_us, robust, robust_k,  # type: ignore[no-untyped-def]
                      floor_us, min_points, max_rms, min_speed, max_speed, vx, vy, valid):
    """Per event: update the surface ``sae`` (relative to ``base[0]``, see
    :func:`tectum.plugins.flow._plane.new_surface`) then fit; normal flow
    (px/s) or NaN + invalid.

    ``max_rms`` bounds the inliers' residual RMS as a fraction of the time
    the edge takes to cross one pixel (a noisy fit is not reported).
    With ``burst_us > 0``, ``last`` (H, W) int64 holds each pixel's last event
    time, signed by its polarity (0 = none); see :class:`PlaneFit`.
    Compiled with the fit's fast-math flags (the fit inlined here vectorises
    only under them); the flow itself comes from plain code
    (:func:`gradient_flow`, not inlined)."""
    scr = plane_scratch(radius)
    for i in range(t.shape[0]):
        k = 1 if p[i] > 0 else 0
        xi, yi = np.int64(x[i]), np.int64(y[i])
        tref = crossing_time(sae, last, burst_us, window_us, k, xi, yi, radius, t[i], rel_time(sae, base, t[i]))
        sae[yi + radius, xi + radius, k] = tref
        a, b, _, rms, ok = plane_fit_at(sae, k, xi, yi, tref, radius, window_us, n_iter, reject_us, robust,
                                        robust_k, floor_us, min_points, scr)
        # the residual RMS must stay under max_rms times the time per pixel
        fx, fy, ok = gradient_flow(ok, a, b, rms, max_rms, min_speed, max_speed)
        vx[i], vy[i], valid[i] = fx, fy, ok


class PlaneFit(FlowOperator):
    """Normal flow (px/s) from a plane fitted to the recent events around each event.

    Output: **normal flow** in ``out_vx``/``out_vy``, NaN where ``out_valid``
    is false.

    Parameters: ``radius`` (px; 2 = the 5x5 neighbourhood of the paper),
    ``window_us`` (µs) how old a neighbour may be, ``n_iter`` outlier
    rejection rounds (0 = plain least squares), ``reject_us`` the fixed
    rejection distance (µs) of the original method, ``robust`` to use the
    data-driven threshold instead (``robust_k`` MADs, at least ``floor_us``
    µs), ``min_points`` inliers needed, ``max_rms`` the largest inlier RMS
    residual as a fraction of the time per pixel, ``min_speed``/``max_speed``
    (px/s). ``burst_us`` (µs, 0 = off): a pixel often fires several events
    of the same polarity as one edge crosses it (a blurred edge, several
    contrast thresholds); the surface of *last* events then lags behind the
    edge and the speed comes out too high. With ``burst_us > 0`` an event
    that follows the pixel's previous event (same polarity) within
    ``burst_us`` belongs to the same crossing: the surface keeps the
    crossing's first time and the event gets the flow fitted at it. State:
    an int32 surface of both polarities' last times, relative to a base
    (see :mod:`tectum.plugins.flow._plane`), and H x W int64 of last events
    with ``burst_us``.
    """

    name = "flow.plane_fit"
    flow_type = "normal"

    def __init__(self, radius: int = 2, window_us: int = 30_000, n_iter: int = 3, reject_us: float = 1500.0,
                 robust: bool = False, robust_k: float = 3.0, floor_us: float = 300.0, min_points: int = 6,
                 max_rms: float = 1.0, min_speed: float = 1.0, max_speed: float = 20_000.0, burst_us: int = 0,
                 out_vx: str = "vx", out_vy: str = "vy", out_valid: str = "valid") -> None:
        if radius < 1 or not 0 < window_us < SPAN // 2 or n_iter < 0 or min_points < 3:
            raise ValueError(f"need radius >= 1, 0 < window_us < {SPAN // 2}, n_iter >= 0, min_points >= 3")
        if not 0 <= min_speed < max_speed or reject_us <= 0 or robust_k <= 0 or floor_us < 0 or max_rms <= 0:
            raise ValueError("need 0 <= min_speed < max_speed and positive thresholds")
        self.radius, self.window_us, self.n_iter = int(radius), int(window_us), int(n_iter)
        self.reject_us, self.robust = float(reject_us), bool(robust)
        self.robust_k, self.floor_us, self.min_points = float(robust_k), float(floor_us), int(min_points)
        self.max_rms, self.min_speed, self.max_speed = float(max_rms), float(min_speed), float(max_speed)
        if burst_us < 0:
            raise ValueError("need burst_us >= 0")
        self.burst_us = int(burst_us)
        self._set_outputs(out_vx, out_vy, out_valid)
        self.sae: np.ndarray | None = None
        self._sensor = (0, 0)  # (width, height) px the surface was made for

    def memory_us(self) -> int | None:
        """Points older than ``window_us`` are left out of the fit (time
        sharding); with ``burst_us`` a crossing's first event is kept for as
        long as its pixel keeps firing, so the memory has no bound (None)."""
        return None if self.burst_us else self.window_us

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.sae is None:
            self.sae = new_surface(packet.sensor, self.radius)
            self.base = np.array([packet.t_start], np.int64)
            w, h = self._sensor = packet.sensor
            self.last = np.zeros((h, w) if self.burst_us else (1, 1), np.int64)
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        vx, vy, valid = self._alloc(len(packet))
        plane_flow_kernel(packet.t, packet.x, packet.y, packet.p, self.sae, self.base, self.last, self.burst_us,
                          self.radius, self.window_us, self.n_iter, self.reject_us, self.robust, self.robust_k,
                          self.floor_us, self.min_points, self.max_rms, self.min_speed, self.max_speed, vx, vy, valid)
        return [self._emit(packet, vx, vy, valid)]
