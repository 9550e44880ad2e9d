"""N-MNIST / N-Caltech101 binary files (``.bin``; Orchard et al. 2015, the
datasets tonic reads as ``NMNIST``, ``NCALTECH101``).

Each event is 40 bits, big-endian (the dataset page): bits 39-32 x, bits
31-24 y (pixels, top-left origin as the ATIS recorded them), bit 23 polarity
(1 ON, 0 OFF), bits 22-0 time (µs). A record with ``y = 240`` (a row the
ATIS does not have) is a time-overflow marker: the dataset authors'
Python reader (event-Python's ``eventvision``, which tonic follows) adds
2^13 µs to every later time and drops the record; tectum does the same and
counts the markers (``time_overflow_records`` in :attr:`NmnistSource.counts`).

The format has no header and no magic number: a file is taken for N-MNIST
by its ``.bin`` extension, and one whose size is not a multiple of 5 bytes
is refused (or, with ``skip_bad``, its last partial record skipped). The
sensor is not stored: 34x34 (N-MNIST) by default, ``sensor=WxH`` for the
others: for N-Caltech101 a size covering all its samples (the dataset states
none and tonic leaves it unset; each file's own largest x and y are not the
sensor, and would give every sample a different size).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
from numba import njit

from tectum import Kind, Packet

from ._common import EventAssembler, FileSource

__all__ = ["NmnistSource", "decode_nmnist", "RECORD", "OVERFLOW_Y", "OVERFLOW_US", "DEFAULT_SENSOR"]

#: Bytes per event.
RECORD = 5
#: The y of a time-overflow record, and the time it adds to later events (µs).
OVERFLOW_Y = 240
OVERFLOW_US = 1 << 13
#: N-MNIST's sensor (the digits' 34x34 crop of the ATIS).
DEFAULT_SENSOR = (34, 34)


@njit(cache=True, nogil=True)
def decode_nmnist(rec, state, t, x, y, p, where):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Decode 5-byte records ``rec`` (n, 5) uint8. ``state``: 0 time added by
    the overflow records so far (µs), 1 overflow records seen, 2 file offset
    of ``rec[0]``. Returns the events written."""
    add = state[0]
    k = 0
    for i in range(rec.shape[0]):
        if rec[i, 1] == OVERFLOW_Y:
            add += OVERFLOW_US
            state[1] += 1
            continue
        b2 = np.int64(rec[i, 2])
        t[k] = ((b2 & 0x7F) << 16 | np.int64(rec[i, 3]) << 8 | np.int64(rec[i, 4])) + add
        x[k] = rec[i, 0]
        y[k] = rec[i, 1]
        p[k] = 1 if b2 & 0x80 else -1
        where[k] = state[2] + RECORD * i
        k += 1
    state[0] = add
    return k


class NmnistSource(FileSource):
    """Events from N-MNIST / N-Caltech101 ``.bin`` files (layout in the
    module docstring; ``sensor=`` for datasets other than N-MNIST)."""

    name = "nmnist"
    format = "nmnist"
    extensions = (".bin",)
    produces = (Kind.EVENTS,)

    def __init__(self, path: str, **kw: Any) -> None:
        super().__init__(path, **kw)
        self.overflow_records = 0
        #: The sensor (the option, else N-MNIST's 34x34).
        self.sensor = self.sensor_opt or DEFAULT_SENSOR
        w, h = self.sensor
        if w > 256 or h > OVERFLOW_Y:
            raise ValueError(f"sensor {w}x{h}: N-MNIST stores 8-bit x and y < {OVERFLOW_Y}")

    @property
    def counts(self) -> dict[str, int]:
        """:attr:`FileSource.counts` and the time-overflow records read."""
        return {**super().counts, "time_overflow_records": self.overflow_records}

    @counts.setter
    def counts(self, value: dict[str, int]) -> None:
        raise AttributeError("NmnistSource.counts is read-only")

    def _packets(self) -> Iterator[Packet]:
        f = self._open()
        size = f.seek(0, 2)
        end = size - size % RECORD
        if end < size:
            if not self.skip_bad:
                self._fail(f"{size} bytes is not a whole number of 5-byte N-MNIST events ({size % RECORD} "
                           "left over): truncated, or not an N-MNIST file (the format has no magic number; "
                           "a .bin file is taken for N-MNIST by its extension)", end)
            self._note_skip(end, size - 1, 1)
        sensor = self.sensor
        f.seek(0)
        state = np.zeros(3, np.int64)
        asm = EventAssembler(self, sensor)
        step = max(RECORD, self.chunk_bytes // RECORD * RECORD)
        pos = 0
        while pos < end:
            buf = f.read(min(step, end - pos))
            rec = np.frombuffer(buf, np.uint8).reshape(-1, RECORD)
            m = rec.shape[0]
            t, x, y = np.empty(m, np.int64), np.empty(m, np.uint16), np.empty(m, np.uint16)
            p, where = np.empty(m, np.int8), np.empty(m, np.int64)
            state[2] = pos
            n = decode_nmnist(rec, state, t, x, y, p, where)
            self.overflow_records = int(state[1])
            if self.sensor_opt is None and not self.skip_bad:
                self._within_default_sensor(x[:n], y[:n], where[:n])
            yield from asm.push(t[:n], x[:n], y[:n], p[:n], pos, where[:n])
            pos += len(buf)
            if self.t_end_us is not None and asm.last_t is not None and asm.last_t >= self.t_end_us:
                break
        yield from asm.finish()

    def _within_default_sensor(self, x: np.ndarray, y: np.ndarray, where: np.ndarray) -> None:
        """An event past 34x34 with no ``sensor=`` given: most likely a file
        of another dataset, so the error says what to give."""
        out = (x >= DEFAULT_SENSOR[0]) | (y >= DEFAULT_SENSOR[1])
        if out.any():
            i = int(np.flatnonzero(out)[0])
            self._fail(f"event ({int(x[i])}, {int(y[i])}) lies outside N-MNIST's 34x34 sensor: give sensor=WxH "
                       "for N-Caltech101 and the other datasets", int(where[i]))
