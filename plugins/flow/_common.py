"""What every flow operator shares: the per-polarity surface of active events
(SAE), the output columns, and the base class."""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, Operator

__all__ = ["NEVER", "new_sae", "store_gradient_flow", "gradient_flow", "FlowOperator"]

#: Timestamp of a pixel that never fired (far in the past, no overflow on t - NEVER).
NEVER = np.iinfo(np.int64).min // 4


def new_sae(sensor: tuple[int, int]) -> np.ndarray:
    """A surface of active events: (2, H, W) int64 µs, index 0 = OFF, 1 = ON."""
    w, h = sensor
    return np.full((2, h, w), NEVER, np.int64)


@njit(cache=True, nogil=True, inline="always")
def _flow(ok, gx, gy, rms, max_rms, min_speed, max_speed):  # type: ignore[no-untyped-def]
    """(vx, vy, ok): ``1e6 g / |g|^2`` px/s from the time-surface gradient
    ``(gx, gy)`` µs/px if ``ok``, the residual RMS (µs) is at most
    ``max_rms`` times the time per pixel ``|g|`` and the speed is in
    ``[min_speed, max_speed]``; else NaN and invalid."""
    ok = ok and rms <= max_rms * np.sqrt(gx * gx + gy * gy)
    g2 = gx * gx + gy * gy
    if ok and g2 > 0.0:
        ok = min_speed <= 1e6 / np.sqrt(g2) <= max_speed
    else:
        ok = False
    if ok:
        return 1e6 * gx / g2, 1e6 * gy / g2, True
    return np.nan, np.nan, False


@njit(cache=True, nogil=True, inline="always")
def store_gradient_flow(i, ok, gx, gy, min_speed, max_speed, vx, vy, valid):  # type: ignore[no-untyped-def]
    """Write event ``i``'s normal flow from the time-surface gradient
    ``(gx, gy)`` µs/px: ``1e6 g / |g|^2`` px/s if ``ok`` and the speed is in
    ``[min_speed, max_speed]``, else NaN and invalid."""
    vx[i], vy[i], valid[i] = _flow(ok, gx, gy, 0.0, np.inf, min_speed, max_speed)


@njit(cache=True, nogil=True)
def gradient_flow(ok, gx, gy, rms, max_rms, min_speed, max_speed):  # type: ignore[no-untyped-def]
    """:func:`_flow` not inlined, on purpose: kernels compiled with
    fast-math call it and get exactly the IEEE results of plain code."""
    return _flow(ok, gx, gy, rms, max_rms, min_speed, max_speed)


class FlowOperator(Operator):
    """Base of the flow operators: writes ``vx``/``vy`` (px/s, float32, NaN
    where invalid) and ``valid`` (bool) under configurable names, so input
    that already carries truth columns named ``vx``/``vy`` can keep them."""

    #: "normal" (component along the local edge normal) or "full" flow; a
    #: class default that an operator with both modes sets per instance.
    flow_type: str = "normal"

    def _set_outputs(self, out_vx: str, out_vy: str, out_valid: str) -> None:
        names = (out_vx, out_vy, out_valid)
        if len(set(names)) != 3 or any(n in ("t", "x", "y", "p") or not n for n in names):
            raise ValueError(f"output column names must be distinct and not t/x/y/p, got {names}")
        self.out_vx, self.out_vy, self.out_valid = names

    def _emit(self, packet: EventPacket, vx: np.ndarray, vy: np.ndarray, valid: np.ndarray) -> EventPacket:
        return packet.with_columns(**{self.out_vx: vx, self.out_vy: vy, self.out_valid: valid})

    @staticmethod
    def _alloc(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.bool_)
