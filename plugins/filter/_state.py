"""Per-pixel state shared by the neighbourhood filters."""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket

__all__ = ["NEVER", "padded_timestamps", "select", "compact_kernel"]

#: The timestamp (µs) of a pixel that has never fired: far in the past, yet
#: ``t - NEVER`` cannot overflow int64.
NEVER = np.iinfo(np.int64).min // 2


def padded_timestamps(sensor: tuple[int, int], channels: int = 1) -> np.ndarray:
    """A ``(channels, H + 2, W + 2)`` int64 map of last timestamps (µs), all
    :data:`NEVER`, with a one-pixel border so kernels can read the 8
    neighbours of any pixel without bounds checks (pixel ``(x, y)`` lives at
    ``[c, y + 1, x + 1]``)."""
    w, h = sensor
    return np.full((channels, h + 2, w + 2), NEVER, np.int64)


@njit(cache=True, nogil=True)
def compact_kernel(t, x, y, p, keep, ot, ox, oy, op, idx, want_idx):  # type: ignore[no-untyped-def]
    """Copy the events where ``keep`` to the front of ``ot, ox, oy, op``
    (one branch-free pass; outputs need one spare slot) and, with
    ``want_idx``, their input indices to ``idx``; returns how many."""
    n = 0
    for i in range(t.shape[0]):
        ot[n] = t[i]
        ox[n] = x[i]
        oy[n] = y[i]
        op[n] = p[i]
        if want_idx:
            idx[n] = i
        n += keep[i]
    return n


def select(packet: EventPacket, keep: np.ndarray) -> EventPacket:
    """``packet.select(keep)`` for a bool mask, faster: the base columns are
    compacted in one numba pass and extra columns gathered by index
    (numpy's boolean indexing rescans the mask per column). Returns
    ``packet`` itself when every event is kept."""
    m = len(packet)
    cols = packet.columns
    ot, ox, oy = np.empty(m + 1, np.int64), np.empty(m + 1, np.uint16), np.empty(m + 1, np.uint16)
    op, idx = np.empty(m + 1, np.int8), np.empty(m + 1 if cols else 1, np.intp)
    n = compact_kernel(packet.t, packet.x, packet.y, packet.p, keep, ot, ox, oy, op, idx, bool(cols))
    if n == m:
        return packet
    return EventPacket._trusted(ot[:n], ox[:n], oy[:n], op[:n], packet.sensor, packet.t_start, packet.t_end,
                                {k: v[idx[:n]] for k, v in cols.items()}, packet.checked)
