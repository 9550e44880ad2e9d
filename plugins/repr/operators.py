"""The ``repr`` operators: events in, :class:`tectum.FramePacket` out, one
frame per window (see :mod:`tectum.plugins.repr._window` for the slicing
rules shared by all). Parameters: ``window_us`` (µs) or ``count`` (events),
``partial`` (emit the last unfinished window). Memory: one state image
(stated per class) plus the frames emitted."""

from __future__ import annotations

import numpy as np

from . import functional as F
from . import kernels as K
from ._window import Windowed

__all__ = ["EventFrame", "Accumulate", "CountImage", "TimeSurface", "Sae", "VoxelGrid", "Color"]


class _Image(Windowed):
    """A per-window image that starts at zero and is reset after each frame."""

    shape_tail: tuple[int, ...] = ()
    dtype: type = np.int32

    def _start(self, sensor: tuple[int, int]) -> None:
        self.state: np.ndarray = np.zeros((sensor[1], sensor[0], *self.shape_tail), self.dtype)
        self._block: np.ndarray | None = None  # frames of the packet being sliced, and the window after
        self._slot = 0  # the block's next free frame

    def _reserve(self, n: int) -> None:
        """A packet that completes ``n`` >= 2 windows gets one zeroed block
        of ``n + 1`` frames: each window accumulates in its own slice, which
        becomes its frame, so the packet's frames are the block itself
        (no copy when they are stacked, and a page of a sparse frame is only
        touched where events land). The window in progress moves in."""
        if n < 2:
            return
        block = np.zeros((n + 1, *self.state.shape), self.state.dtype)
        if self._n:
            block[0] = self.state
        self.state, self._block, self._slot = block[0], block, 1

    def _frame(self, t0: int, t1: int) -> np.ndarray:
        out = self.state  # the accumulator becomes the frame; a fresh one takes over
        if self._block is not None and self._slot < len(self._block):
            self.state = self._block[self._slot]
            self._slot += 1
        else:
            self._block = None
            self.state = np.zeros(out.shape, out.dtype)  # calloc: cheaper than zeros_like's fill
        return out

    def _stack(self, images: list[np.ndarray]) -> np.ndarray:
        b = self._block
        if b is not None and len(images) < len(b) and all(im.ctypes.data == b[i].ctypes.data
                                                         for i, im in enumerate(images)):
            return b[:len(images)]  # the block's first frames, in order: no copy
        return super()._stack(images)


class EventFrame(_Image):
    """Histogram per polarity: (H, W, 2) int32 counts per window, channel 0
    OFF, 1 ON. State: 8 x W x H bytes."""

    name = "repr.event_frame"
    shape_tail = (2,)

    def _add(self, t, x, y, p) -> None:  # type: ignore[no-untyped-def]
        K.histogram_kernel(x, y, p, self.state)


class Accumulate(_Image):
    """Signed accumulation: (H, W) int32 sum of polarities per window.
    State: 4 x W x H bytes."""

    name = "repr.accumulate"

    def _add(self, t, x, y, p) -> None:  # type: ignore[no-untyped-def]
        K.signed_kernel(x, y, p, self.state)


class CountImage(_Image):
    """Event count image: (H, W) int32 events per pixel per window.
    State: 4 x W x H bytes."""

    name = "repr.count"

    def _add(self, t, x, y, p) -> None:  # type: ignore[no-untyped-def]
        K.count_kernel(x, y, self.state)


class Color(_Image):
    """Polarity colour rendering: RGB (H, W, 3) uint8 per window, each pixel
    in the colour of its latest event's polarity (``on``/``off``, hex
    ``#rrggbb``) or ``background``. State: W x H bytes."""

    name = "repr.color"
    dtype = np.int8

    def __init__(self, window_us: int | None = None, count: int | None = None, partial: bool = True,
                 on: str = "#ffffff", off: str = "#3c78ff", background: str = "#000000") -> None:
        self._init_window(window_us, count, partial)
        self.colors = (on, off, background)
        F.render_polarity(np.zeros((1, 1), np.int8), *self.colors)  # validate now

    def _add(self, t, x, y, p) -> None:  # type: ignore[no-untyped-def]
        K.last_polarity_kernel(x, y, p, self.state)

    def _frame(self, t0: int, t1: int) -> np.ndarray:
        out = F.render_polarity(self.state, *self.colors)
        self.state[...] = 0
        return out


class Sae(Windowed):
    """Surface of active events: (H, W, 2) int64 latest timestamp (µs) per
    pixel and polarity at each window's end (``kernels.NEVER`` where none).
    The surface persists across windows. State: 16 x W x H bytes."""

    name = "repr.sae"

    def memory_us(self) -> None:
        """The surface keeps each pixel's latest time however old: no bound."""
        return None

    def _start(self, sensor: tuple[int, int]) -> None:
        self.sae = np.full((sensor[1], sensor[0], 2), K.NEVER, np.int64)

    def _add(self, t, x, y, p) -> None:  # type: ignore[no-untyped-def]
        K.sae_kernel(t, x, y, p, self.sae)

    def _frame(self, t0: int, t1: int) -> np.ndarray:
        return self.sae.copy()


class TimeSurface(Windowed):
    """Time surface with exponential decay: (H, W, 2) float32
    ``exp(-(t1 - t_last) / tau_us)`` per pixel and polarity, where ``t1``
    is the frame's time (µs), 0 where none. The state is kept in factored
    form (one exp per event, one multiply per pixel per frame; equal to
    the direct formula within float32 rounding). State: 16 x W x H bytes."""

    name = "repr.time_surface"

    def __init__(self, window_us: int | None = None, count: int | None = None, partial: bool = True,
                 tau_us: float = 50_000.0) -> None:
        if tau_us <= 0:
            raise ValueError("tau_us must be > 0")
        self._init_window(window_us, count, partial)
        self.tau_us = float(tau_us)

    def memory_us(self) -> None:
        """The factored state rounds differently from another starting time,
        so a shard's frames would differ in the last bits: no sharding."""
        return None

    def _start(self, sensor: tuple[int, int]) -> None:
        self.v = np.zeros((sensor[1], sensor[0], 2), np.float64)
        self.base = np.zeros(1, np.int64)
        self._based = False

    def _add(self, t, x, y, p) -> None:  # type: ignore[no-untyped-def]
        if not self._based:
            self.base[0] = t[0]
            self._based = True
        K.decay_kernel(t, x, y, p, self.v, self.base, self.tau_us, int(min(40.0 * self.tau_us, 2**62)))

    def _frame(self, t0: int, t1: int) -> np.ndarray:
        out = np.empty(self.v.shape, np.float32)
        K.surface_kernel(self.v, self.base, t1, self.tau_us, out)
        return out


class VoxelGrid(Windowed):
    """Voxel grid: (H, W, bins) float32, each window's polarities spread
    bilinearly over ``bins`` time bins spanning the window (first to last µs
    of a time window; first to last event of a count window). Holds the
    window's events until it closes. State: 13 bytes per buffered event."""

    name = "repr.voxel_grid"

    def __init__(self, window_us: int | None = None, count: int | None = None, partial: bool = True,
                 bins: int = 5) -> None:
        if bins < 1:
            raise ValueError("bins must be >= 1")
        self._init_window(window_us, count, partial)
        self.bins = int(bins)

    def _start(self, sensor: tuple[int, int]) -> None:
        self.shape = (sensor[1], sensor[0], self.bins)
        self.pending: list[tuple[np.ndarray, ...]] = []

    def _add(self, t, x, y, p) -> None:  # type: ignore[no-untyped-def]
        self.pending.append((t, x, y, p))

    def _frame(self, t0: int, t1: int) -> np.ndarray:
        out = np.zeros(self.shape, np.float32)
        for t, x, y, p in self.pending:
            K.voxel_kernel(t, x, y, p, t0, t1, out)
        self.pending = []
        return out
