"""``filter.hot_pixel``: learn which pixels fire far too often, then mask them."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numba import njit

from tectum import EventPacket, Operator, same_sensor

from ._state import select

__all__ = ["HotPixel", "count_kernel", "hot_pixels", "mask_kernel"]


@njit(cache=True, nogil=True)
def count_kernel(x, y, counts):  # type: ignore[no-untyped-def]
    """Add one to ``counts[y, x]`` (int64, (H, W)) per event."""
    for i in range(x.shape[0]):
        counts[y[i], x[i]] += 1


@njit(cache=True, nogil=True)
def mask_kernel(x, y, masked, keep):  # type: ignore[no-untyped-def]
    """``keep[i]`` = not ``masked[y[i], x[i]]``; returns the number kept."""
    n = 0
    for i in range(x.shape[0]):
        ok = not masked[y[i], x[i]]
        keep[i] = ok
        n += ok
    return n


def hot_pixels(counts: np.ndarray, factor: float, min_events: int) -> np.ndarray:
    """The hot pixels of a count map: those with at least ``min_events``
    events and more than ``factor`` times the mean count of the pixels that
    fired at all. Returns a bool (H, W) map."""
    active = counts[counts > 0]
    if active.size == 0:
        return np.zeros(counts.shape, np.bool_)
    limit = max(float(min_events), factor * float(active.mean()))
    return (counts >= min_events) & (counts > limit)


class HotPixel(Operator):
    """Hot-pixel filter: count events per pixel during the first
    ``learn_us`` µs of the stream (from the first packet's start), then
    mask for good every pixel with at least ``min_events`` events and more
    than ``factor`` times the mean count of the active pixels.

    During learning, events pass (``learning="pass"``, no added latency) or
    are dropped (``learning="drop"``). After learning, :attr:`hot` holds the
    (H, W) bool mask and :attr:`hot_list` the ``(x, y)`` pixels.

    State: one int64 count and one bool per pixel: 9 x W x H bytes.
    """

    name = "filter.hot_pixel"

    def __init__(self, learn_us: int = 1_000_000, factor: float = 10.0, min_events: int = 5,
                 learning: Literal["pass", "drop"] = "pass") -> None:
        if learn_us < 0 or factor <= 0 or min_events < 1:
            raise ValueError("need learn_us >= 0, factor > 0 and min_events >= 1")
        if learning not in ("pass", "drop"):
            raise ValueError("learning must be 'pass' or 'drop'")
        self.learn_us, self.factor, self.min_events = int(learn_us), float(factor), int(min_events)
        self.learning = learning
        self.counts: np.ndarray | None = None
        self.hot: np.ndarray | None = None
        self._learn_end: int | None = None
        self._sensor = (0, 0)  # (width, height) the state was made for

    @property
    def learned(self) -> bool:
        return self.hot is not None

    @property
    def hot_list(self) -> list[tuple[int, int]]:
        """The masked pixels as ``(x, y)``, empty while learning."""
        if self.hot is None:
            return []
        ys, xs = np.nonzero(self.hot)
        return [(int(a), int(b)) for a, b in zip(xs, ys)]

    def memory_us(self) -> None:
        """It learns the hot pixels from the stream's first ``learn_us``
        and masks them for good: every later event depends on that start."""
        return None

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.counts is None:
            w, h = self._sensor = packet.sensor
            self.counts = np.zeros((h, w), np.int64)
            self._learn_end = packet.t_start + self.learn_us
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        out = []
        if self.hot is None:
            assert self._learn_end is not None
            head, packet = packet.split_at(self._learn_end)
            count_kernel(head.x, head.y, self.counts)
            out.append(head if self.learning == "pass" else select(head, np.zeros(len(head), np.bool_)))
            if packet.t_end <= self._learn_end and len(packet) == 0:
                return out
            self.hot = hot_pixels(self.counts, self.factor, self.min_events)
        keep = np.empty(len(packet), np.bool_)
        mask_kernel(packet.x, packet.y, self.hot, keep)
        out.append(select(packet, keep))
        return out
