"""N-MNIST / N-Caltech101 ``.bin`` writer (layout in
:mod:`tectum.sources.files.nmnist`): 5 bytes per event, x, y, polarity and
23-bit time. The format stores no time origin: times are written as they
are when the first event fits the 23-bit field, else from the first
packet's start (kept in :attr:`NmnistSink.t0`). Later times past 2^23 µs are
written as the dataset's readers read them: a time-overflow record
(``y = 240``) adds 2^13 µs to every later time.
The file stores no sensor size (the reader needs ``sensor=`` for anything
but 34x34); x must be below 256 and y below 240.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket
from tectum.sources.files.nmnist import OVERFLOW_US, OVERFLOW_Y, RECORD

from ._common import FileSink

__all__ = ["NmnistSink", "encode_nmnist"]


@njit(cache=True, nogil=True)
def encode_nmnist(t, x, y, p, state, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Records of events (``t`` µs, non-decreasing) into ``out`` (k, 5) uint8,
    with at least ``len(t) + (t[-1] - state[0]) // 8192 + 1`` rows; ``state[0]``
    is the time the overflow records written so far add. Returns the rows."""
    add = state[0]
    k = 0
    for i in range(t.shape[0]):
        while t[i] - add > 0x7FFFFF:
            out[k, 0] = 0
            out[k, 1] = OVERFLOW_Y
            out[k, 2] = 0
            out[k, 3] = 0
            out[k, 4] = 0
            add += OVERFLOW_US
            k += 1
        r = t[i] - add
        out[k, 0] = x[i]
        out[k, 1] = y[i]
        out[k, 2] = (r >> 16) | (0x80 if p[i] > 0 else 0)
        out[k, 3] = (r >> 8) & 0xFF
        out[k, 4] = r & 0xFF
        k += 1
    state[0] = add
    return k


class NmnistSink(FileSink):
    """N-MNIST ``.bin`` writer (``nmnist`` sink name)."""

    name = "nmnist"
    format = "nmnist"
    title = "N-MNIST"
    extensions = (".bin",)

    def _begin(self, packet: EventPacket) -> None:
        assert self.sensor is not None
        w, h = self.sensor
        if w > 256 or h > OVERFLOW_Y:
            raise ValueError(f"N-MNIST stores 8-bit x and y < {OVERFLOW_Y}: sensor {w}x{h} is too large")
        #: The time (µs) the file's 0 stands for.
        self.t0 = self._origin(packet, 1 << 23, "N-MNIST")
        self.state = np.zeros(1, np.int64)

    def _events(self, packet: EventPacket) -> None:
        assert self.f is not None
        t = packet.t - self.t0 if self.t0 else packet.t
        out = np.empty((len(t) + (int(t[-1]) - int(self.state[0])) // OVERFLOW_US + 1, RECORD), np.uint8)
        k = encode_nmnist(t, packet.x, packet.y, packet.p, self.state, out)
        self.f.write(out[:k].tobytes())

    def _empty(self) -> None:
        raise ValueError("N-MNIST: no events were written and the sensor size is unknown")
