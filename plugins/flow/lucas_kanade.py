"""``flow.lucas_kanade``: event-based Lucas-Kanade (after Benosman et al., 2012).

Each pixel keeps its last ``K`` events (time, polarity). For an event at
time t, the signed event counts of each pixel around it in two consecutive
windows, ``C1`` over (t - dt, t] and ``C2`` over (t - 2 dt, t - dt], are two
samples of the brightness change image, which translates with the scene.
The brightness-constancy equation on them, ``Ix vx + Iy vy + It = 0`` with
``I = (C1 + C2) / 2`` differentiated by central differences and
``It = (C1 - C2) / dt``, is solved by least squares over the
(2 radius + 1)^2 neighbourhood (the structure tensor ``A``).

Output ``mode``:

* ``"normal"``: the flow along the dominant gradient direction (eigenvector
  of ``A``), valid where that direction is well measured: **normal flow**.
* ``"full"``: the 2-D solution, valid only where ``A`` is well conditioned
  (smallest / largest eigenvalue >= ``min_cond``; corners and texture, not
  straight edges): **full flow**.

Either way an event is invalid unless the fitted flow explains at least
``min_explained`` of the temporal change (pure noise does not) and the speed
is within ``[min_speed, max_speed]`` px/s.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numba import njit

from tectum import EventPacket, same_sensor

from ._common import NEVER, FlowOperator

__all__ = ["LucasKanade", "lucas_kanade_kernel"]

K_RING = 4


@njit(cache=True, nogil=True, inline="always")
def _counts(ring_t, ring_p, yy, xx, ti, dt_us):  # type: ignore[no-untyped-def]
    c1 = 0.0
    c2 = 0.0
    for q in range(ring_t.shape[2]):
        age = ti - ring_t[yy, xx, q]
        if age < dt_us:
            c1 += ring_p[yy, xx, q]
        elif age < 2 * dt_us:
            c2 += ring_p[yy, xx, q]
    return c1, c2


@njit(cache=True, nogil=True)
def lucas_kanade_kernel(t, x, y, p, ring_t, ring_p, head, radius, dt_us, full, min_cond, min_grad, min_explained,  # type: ignore[no-untyped-def]
                        min_speed, max_speed, c1, c2, vx, vy, valid):
    """Per event: push it into the per-pixel rings (``ring_t`` (H, W, K)
    int64 µs, ``ring_p`` (H, W, K) int8, ``head`` (H, W) int64), then solve
    the local Lucas-Kanade system; ``c1``/``c2`` are (2 radius + 3)^2 scratch."""
    h, w, kk = ring_t.shape
    side = 2 * radius + 3
    for i in range(t.shape[0]):
        xi, yi, ti = np.int64(x[i]), np.int64(y[i]), t[i]
        hd = head[yi, xi]
        ring_t[yi, xi, hd] = ti
        ring_p[yi, xi, hd] = p[i]
        head[yi, xi] = (hd + 1) % kk
        for a in range(side):
            for b in range(side):
                yy, xx = yi + a - radius - 1, xi + b - radius - 1
                if 0 <= yy < h and 0 <= xx < w:
                    u1, u2 = _counts(ring_t, ring_p, yy, xx, ti, dt_us)
                else:
                    u1, u2 = 0.0, 0.0
                c1[a, b] = u1
                c2[a, b] = u2
        sxx = sxy = syy = sxt = syt = stt = 0.0
        for a in range(1, side - 1):
            for b in range(1, side - 1):
                ix = 0.25 * (c1[a, b + 1] + c2[a, b + 1] - c1[a, b - 1] - c2[a, b - 1])
                iy = 0.25 * (c1[a + 1, b] + c2[a + 1, b] - c1[a - 1, b] - c2[a - 1, b])
                it = (c1[a, b] - c2[a, b]) / dt_us
                sxx += ix * ix
                sxy += ix * iy
                syy += iy * iy
                sxt += ix * it
                syt += iy * it
                stt += it * it
        # eigen-decomposition of the 2x2 structure tensor
        tr = sxx + syy
        disc = np.sqrt(max(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0.0))
        l1 = 0.5 * tr + disc
        l2 = 0.5 * tr - disc
        ok = l1 > min_grad and stt > 0.0
        ux = uy = 0.0
        if ok and full:
            ok = l2 >= min_cond * l1
            if ok:
                det = sxx * syy - sxy * sxy
                ux = -(syy * sxt - sxy * syt) / det
                uy = -(sxx * syt - sxy * sxt) / det
        elif ok:
            # dominant gradient direction (unit eigenvector of l1)
            if abs(sxy) > 1e-12 * tr:
                ex, ey = l1 - syy, sxy
            elif sxx >= syy:
                ex, ey = 1.0, 0.0
            else:
                ex, ey = 0.0, 1.0
            en = np.sqrt(ex * ex + ey * ey)
            ex, ey = ex / en, ey / en
            s = -(ex * sxt + ey * syt) / l1
            ux, uy = s * ex, s * ey
        if ok:
            # share of the temporal change the flow explains
            res = stt + 2.0 * (ux * sxt + uy * syt) + ux * ux * sxx + 2.0 * ux * uy * sxy + uy * uy * syy
            ok = 1.0 - res / stt >= min_explained
        if ok:
            speed = 1e6 * np.sqrt(ux * ux + uy * uy)
            ok = min_speed <= speed <= max_speed
        if ok:
            vx[i] = 1e6 * ux
            vy[i] = 1e6 * uy
        else:
            vx[i] = np.nan
            vy[i] = np.nan
        valid[i] = ok


class LucasKanade(FlowOperator):
    """Event-based Lucas-Kanade flow (px/s); see the module docstring.

    ``mode="normal"`` (default) gives **normal flow**, ``mode="full"`` gives
    **full flow** where the neighbourhood is textured enough. Parameters:
    ``radius`` (px), ``dt_us`` (µs) the length of each of the two count
    windows, ``min_cond``, ``min_grad`` (structure-tensor eigenvalue, counts^2),
    ``min_explained`` (0..1), ``min_speed``/``max_speed`` (px/s). State:
    the last 4 events of every pixel (H x W x 4 x 9 bytes).
    """

    name = "flow.lucas_kanade"
    flow_type = "normal"

    def __init__(self, radius: int = 2, dt_us: int = 5_000, mode: Literal["normal", "full"] = "normal",
                 min_cond: float = 0.2, min_grad: float = 1.0, min_explained: float = 0.5,
                 min_speed: float = 1.0, max_speed: float = 20_000.0,
                 out_vx: str = "vx", out_vy: str = "vy", out_valid: str = "valid") -> None:
        if radius < 1 or dt_us <= 0 or mode not in ("normal", "full"):
            raise ValueError("need radius >= 1, dt_us > 0, mode 'normal' or 'full'")
        if not 0 <= min_speed < max_speed or min_cond < 0 or min_grad < 0:
            raise ValueError("need 0 <= min_speed < max_speed and non-negative thresholds")
        self.radius, self.dt_us, self.mode = int(radius), int(dt_us), mode
        self.flow_type = mode
        self.min_cond, self.min_grad, self.min_explained = float(min_cond), float(min_grad), float(min_explained)
        self.min_speed, self.max_speed = float(min_speed), float(max_speed)
        self._set_outputs(out_vx, out_vy, out_valid)
        self.ring_t: np.ndarray | None = None
        self._sensor = (0, 0)  # (width, height) px the rings were made for

    def memory_us(self) -> int:
        """Only events of the last two windows, ``2 dt_us``, are counted
        (time sharding)."""
        return 2 * self.dt_us

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.ring_t is None:
            w, h = self._sensor = packet.sensor
            self.ring_t = np.full((h, w, K_RING), NEVER, np.int64)
            self.ring_p = np.zeros((h, w, K_RING), np.int8)
            self.head = np.zeros((h, w), np.int64)
            side = 2 * self.radius + 3
            self._c1, self._c2 = np.empty((side, side)), np.empty((side, side))
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        vx, vy, valid = self._alloc(len(packet))
        lucas_kanade_kernel(packet.t, packet.x, packet.y, packet.p, self.ring_t, self.ring_p, self.head,
                            self.radius, self.dt_us, self.mode == "full", self.min_cond, self.min_grad,
                            self.min_explained, self.min_speed, self.max_speed, self._c1, self._c2, vx, vy, valid)
        return [self._emit(packet, vx, vy, valid)]
