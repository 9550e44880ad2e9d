"""The ``repr`` operators: events in, :class:`tectum.FramePacket` out, one
frame per window (see :mod:`tectum.plugins.repr._window` for the slicing
rules shared by all). Parameters: ``window_us`` (µs) or ``count`` (events),
``partial`` (emit the last unfinished window). Memory: one state image
(stated per class) plus the frames emitted."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tectum import EventPacket, FramePacket, same_sensor

from . import functional as F
from . import kernels as K
from ._pool import Block, pool
from ._window import JOIN_PIXELS, Windowed

__all__ = ["EventFrame", "Accumulate", "CountImage", "TimeSurface", "Sae", "VoxelGrid", "Color"]


class _Image(Windowed):
    """A per-window image that starts at zero. One kernel call per block of
    frames accumulates the windows a packet completes, each into its own
    frame (a block is a packet's images, no copy); the window in progress
    lives in a private state image that remembers where it was touched.
    ``dtype``: an integer numpy dtype; values saturate at its limits."""

    shape_tail: tuple[int, ...] = ()
    mode: int = K.COUNT

    def __init__(self, window_us: int | None = None, count: int | None = None, partial: bool = True,
                 dtype: str | type = "int32") -> None:
        self._init_window(window_us, count, partial)
        try:
            self.dtype = np.dtype(dtype)
        except TypeError:
            raise ValueError(f"dtype must be an integer numpy dtype, got {dtype!r}") from None
        if self.dtype.kind not in "iu" or self.dtype.itemsize > 4:
            raise ValueError(f"dtype must be an integer numpy dtype of at most 32 bits, got {self.dtype}")
        if self.mode == K.SIGNED and self.dtype.kind == "u":
            raise ValueError(f"a signed sum needs a signed dtype, got {self.dtype}")
        info = np.iinfo(self.dtype)
        self._vmin, self._vmax = int(info.min), int(info.max)
        self._windows = K.WINDOWS[self.mode]
        self._w = int(self.window_us if count is None else count)  # type: ignore[arg-type]

    def _start(self, sensor: tuple[int, int]) -> None:
        self._shape = (sensor[1], sensor[0], *self.shape_tail)
        frame_bytes = math.prod(self._shape) * self.dtype.itemsize
        # the window in progress (flat) and the indices that left zero in it: made
        # when events first stay in it (:meth:`_state`; a stream cut on the
        # window edges never needs them: no 720 kB zeroed and pushed through the
        # cache per run for nothing)
        self._flat = np.zeros(0, self.dtype)
        self._touched = _NO_TOUCHED
        self._n_touched = np.zeros(1, np.int64)
        self._pool = pool(self._shape, self.dtype, _per_block(frame_bytes), marks=min(frame_bytes // MARK_BYTES, MARKS))
        self._no_frames = Block(np.empty((0, *self._shape), self.dtype), 0)
        self._width = sensor[0]

    def _state(self) -> None:
        """The state image, made now (all zero: nothing was added yet)."""
        self._flat = np.zeros(math.prod(self._shape), self.dtype)
        self._touched = np.empty(self._flat.shape[0], np.int64)

    def process(self, packet: EventPacket) -> list[FramePacket]:
        """The windows ``packet`` completes, in one kernel call per block of
        frames (a block per output packet; :meth:`_run`)."""
        if self._sensor is None:
            self._begin(packet)
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        t = packet.t
        if self.count is None:
            w, end, t_end = self._w, self._end, packet.t_end
            n_win = (t_end - end) // w + 1 if end <= t_end else 0
            self._end = end + n_win * w
            stamps = np.arange(end - 1, self._end - 1, w, dtype=np.int64)  # each window's last µs
            # the first event of each next window: after the last at or before the stamp (times are integers)
            splits = np.empty(n_win, np.int64)
            K.window_splits(t, end - 1, w, splits)
        else:
            c, n = self._w, t.shape[0]
            splits = np.arange(c - self._n, n + 1, c, dtype=np.int64)
            rest = int(splits[-1]) if splits.shape[0] else 0  # the first event of the window left open
            if rest < n and (splits.shape[0] or self._n == 0):
                self._first = int(t[rest])
            stamps = t[splits - 1]
            if n:  # count windows are stamped by events (time windows by their edges: t[-1] is a cache miss)
                self._last = int(t[-1])
        return self._run(packet, splits, stamps)

    def _run(self, pk: EventPacket, splits: np.ndarray, stamps: np.ndarray) -> list[FramePacket]:
        """Windows ending at event indices ``splits`` (stamped ``stamps``, µs)
        from the packet's events, as packets; the rest stays in the state.
        The frames come in blocks of at most :data:`BLOCK_BYTES` (one packet
        each), recycled from a pool once nobody holds them (see
        :mod:`tectum.plugins.repr._pool`): memory still in cache, zeroed
        only where its last frames were written, where fresh pages cost a
        page fault and a zeroing each (a 720 kB frame: more than its 1000
        events at 0.1 Mev/s)."""
        n_win, n = splits.shape[0], pk.t.shape[0]
        held = self._n  # events the state holds: the most any pixel of it counts
        self._n = n - int(splits[-1]) if n_win else self._n + n
        if self._n and not self._flat.shape[0]:  # events stay in the window in progress
            self._state()
        if not n_win:
            if n:
                self._kernel(pk.x, pk.y, pk.p, splits, self._no_frames, held)
            return [self._emit([], pk.t_end)]
        g = self._pool.per_block
        if n_win <= g:  # one block (the usual case: a packet's frames fit in the cache)
            block, images = self._pool.take()  # images: ours until handed out
            self._kernel(pk.x, pk.y, pk.p, splits, block, held)
            return [self._block_packet(stamps, images if n_win == g else images[:n_win], pk.t_end)]
        out: list[FramePacket] = []
        for a in range(0, n_win, g):
            b = min(a + g, n_win)
            block, images = self._pool.take(len(out))
            lo = int(splits[a - 1]) if a else 0
            hi = int(splits[b - 1]) if b < n_win else n
            self._kernel(pk.x[lo:hi], pk.y[lo:hi], pk.p[lo:hi], splits[a:b] - lo, block, held if a == 0 else 0)
            out.append(self._block_packet(stamps[a:b], images if b - a == g else images[:b - a],
                                          pk.t_end if b == n_win else None))
        return out

    def _kernel(self, x: np.ndarray, y: np.ndarray, p: np.ndarray, splits: np.ndarray, frames: Block,
                held: int) -> None:
        """:func:`~tectum.plugins.repr.kernels.windows_kernel` (its mode's
        compiled function) into the first ``len(splits)`` frames of
        ``frames``; ``held``: the events in the state before these."""
        self._windows(self._width, self._vmin, self._vmax, held, x, y, p, splits, self._flat, self._touched,
                      self._n_touched, frames.flat, frames.marks, frames.n_marks)

    def _frame(self, t0: int, t1: int) -> np.ndarray:
        """The window in progress as a new image (the state is zeroed)."""
        out = Block(np.zeros((1, *self._shape), self.dtype), 0)
        self._kernel(_NO_XY, _NO_XY, _NO_P, _ONE_SPLIT, out, self._n)
        return out.images[0]

    def _px_bytes(self) -> int:
        return self.dtype.itemsize * math.prod(self.shape_tail)

    def join_us(self) -> int | None:
        """Time windows: the span of as many windows as a block holds
        (:func:`_per_block`) on a sensor of :data:`JOIN_PIXELS`, so a call
        hands out its frames in one block."""
        if self.count is not None or not self.window_us:
            return None
        return self.window_us * _per_block(self._px_bytes() * JOIN_PIXELS)

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "dtype": str(self.dtype)}


#: the bytes of frames in one block (and packet): about what stays in a
#: core's cache, so the allocator's next block reuses warm memory; at least
#: :data:`MIN_FRAMES` frames though, up to :data:`MAX_BLOCK_BYTES`
BLOCK_BYTES = 1 << 21
#: a block costs about 5 µs whatever it holds (a pool take, a kernel call, a
#: packet to hand on): blocks of 2 int32 x 2 frames of 346x260 (720 kB each)
#: spent more on that than on 1000 events (0.1 Mev/s, 10 ms windows). Eight
#: a block (5.8 MB, in the 32 MB L3 of this AMD Zen 4) took 8.3 -> 5.0 µs a
#: window at 0.1 Mev/s, 40 -> 36 at 2 Mev/s (pipeline CPU time, loaded).
#: Against eight, per round (interleaved, 9 rounds, CPU, load 0.4-1.9): blocks of 4
#: in calls of 4 windows 0.82x at 0.1 Mev/s, 0.90 at 0.5, 0.99 at 5; in
#: calls of 8 windows 0.77, 0.83, 0.95; calls of 16 windows in 2 blocks of
#: 8 0.93, 0.93, 0.99 (a packet out costs the engine ~2-3 us)
MIN_FRAMES = 8
#: the most bytes of frames :data:`MIN_FRAMES` may bring a block to
MAX_BLOCK_BYTES = 1 << 23


def _per_block(frame_bytes: int) -> int:
    """Frames in a block of frames of ``frame_bytes`` bytes: what
    :data:`BLOCK_BYTES` holds, or :data:`MIN_FRAMES` if more, within
    :data:`MAX_BLOCK_BYTES` (at least one)."""
    fb = max(frame_bytes, 1)
    return max(1, min(MAX_BLOCK_BYTES // fb, max(MIN_FRAMES, BLOCK_BYTES // fb)))

#: a recycled frame is zeroed where its last use wrote, one recorded index
#: per event, while it had at most one event per this many bytes of frame
#: and at most :data:`MARKS`; else whole (a memset). Beyond that many random
#: writes, a frame that left the cache zeroes faster by a memset (346x260:
#: uint8 frames up to 1406 events, int32 x 2 up to 2048; CPU time through
#: a pipeline, interleaved medians of 9, loaded). A map of the rows or 1-4 kB
#: spans a frame's last window wrote would zero nothing less: the bench's
#: windows of more than 2048 events (0.1-2 Mev/s) write every row and every
#: 1 kB span of an int32 x 2 frame, and 65-80 % of its 64-byte lines
MARK_BYTES = 64
MARKS = 2048
_NO_XY, _NO_P = np.empty(0, np.uint16), np.empty(0, np.int8)
_NO_TOUCHED = np.empty(0, np.int64)
_ONE_SPLIT = np.zeros(1, np.int64)


class EventFrame(_Image):
    """Histogram per polarity: (H, W, 2) counts per window, channel 0 OFF,
    1 ON; ``dtype`` int32 (default), or ``uint8``/``int16``/... for frames
    4x/2x smaller whose counts saturate at the dtype's maximum. State: one
    frame (8 x W x H bytes in int32) plus 16 bytes per pixel touched."""

    name = "repr.event_frame"
    shape_tail = (2,)
    mode = K.HISTOGRAM


class Accumulate(_Image):
    """Signed accumulation: (H, W) sum of polarities per window, ``dtype``
    int32 (default) or a smaller signed one (saturating). State: 4 x W x H
    bytes in int32."""

    name = "repr.accumulate"
    mode = K.SIGNED


class CountImage(_Image):
    """Event count image: (H, W) events per pixel per window, ``dtype``
    int32 (default) or a smaller one (``uint8``: 1 byte per pixel, counts
    saturate at 255). State: 4 x W x H bytes in int32."""

    name = "repr.count"
    mode = K.COUNT


class Color(Windowed):
    """Polarity colour rendering: RGB (H, W, 3) uint8 per window, each pixel
    in the colour of its latest event's polarity (``on``/``off``, hex
    ``#rrggbb``) or ``background``. State: W x H bytes."""

    name = "repr.color"

    def __init__(self, window_us: int | None = None, count: int | None = None, partial: bool = True,
                 on: str = "#ffffff", off: str = "#3c78ff", background: str = "#000000") -> None:
        self._init_window(window_us, count, partial)
        self.colors = (on, off, background)
        F.render_polarity(np.zeros((1, 1), np.int8), *self.colors)  # validate now

    def _start(self, sensor: tuple[int, int]) -> None:
        self.state = np.zeros((sensor[1], sensor[0]), np.int8)

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
    form, float32 (a table lookup and a multiply per event, an exp per
    64 µs with events, one multiply per pixel per frame; within one float32
    ulp, 1.2e-7 relative, of the direct formula; a
    float64 state, 2x the bytes to scatter into and read, made frames
    15-30% dearer). State: 8 x W x H bytes."""

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
        self.v = np.zeros((sensor[1], sensor[0], 2), np.float32)
        self.base = np.zeros(1, np.int64)
        self._based = False
        self._table = K.decay_table(self.tau_us)
        # frames written whole into recycled blocks (see _Image._run), one packet each
        self._pool = pool(self.v.shape, np.dtype(np.float32), max(1, BLOCK_BYTES // (self.v.size * 4)))
        self._blocks: list[np.ndarray] = []  # the blocks of the packet being sliced
        self._k = 0  # frames in the last one

    def _px_bytes(self) -> int:
        return 8  # float32 x 2

    def _state_px_bytes(self) -> int:
        return 8  # self.v, float32 x 2: one window a call (two: 0.84 against 0.90 of the plain loop, loaded)

    def _add(self, t, x, y, p) -> None:  # type: ignore[no-untyped-def]
        if not self._based:
            self.base[0] = t[0]
            self._based = True
        K.decay_kernel(t, x, y, p, self.v, self.base, self.tau_us, int(min(40.0 * self.tau_us, 2**62)), self._table)

    def _frame(self, t0: int, t1: int) -> np.ndarray:
        if not self._blocks or self._k == self._pool.per_block:
            self._blocks.append(self._pool.take()[1])
            self._k = 0
        out = self._blocks[-1][self._k]
        self._k += 1
        K.surface_kernel(self.v, self.base, t1, self.tau_us, out)
        return out

    def _emit_packets(self, frames: list[tuple[int, np.ndarray]], t_end: int) -> list[FramePacket]:
        """The blocks :meth:`_frame` wrote, one packet each (the last holds
        only the frames written in it)."""
        blocks, self._blocks = self._blocks, []
        if blocks:
            g = self._pool.per_block
            ts = np.array([f[0] for f in frames], np.int64)
            self._pending = [(ts[i * g:(i + 1) * g], b[:len(ts) - i * g]) for i, b in enumerate(blocks)]
        return super()._emit_packets(frames, t_end)


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
