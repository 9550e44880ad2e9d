"""Slicing an event stream into windows for the ``repr`` operators.

Two modes, the same rules for every representation:

* time (``window_us``): windows ``[t0 + k W, t0 + (k + 1) W)`` from the first
  packet's ``t_start`` ``t0``. A window is emitted as soon as the watermark
  (``packet.t_end``) reaches its end, with or without events; its frame is
  stamped with the window's last µs, ``end - 1``.
* count (``count``): every ``count`` events make one window (events sharing a
  timestamp may fall in two windows); the frame is stamped with the time of
  its last event and emitted as soon as that event arrives.

With ``partial`` (default) the unfinished window at end of stream is emitted
too when it holds events (a count window is then stamped at the end of the
stream). Windows depend only on timestamps and counts, never on packet
boundaries: the output is batch invariant.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from tectum import EventPacket, FramePacket, Kind, Operator, same_sensor

__all__ = ["Windowed", "JOIN_BYTES", "JOIN_PIXELS"]

#: the bytes of frames (and swept state) one call may produce when the
#: engine joins packets, and the sensor size (pixels) it assumes, as
#: :meth:`Windowed.join_us` is asked before the first packet says the sensor
#: (346x260 is 90 k, 640x480 307 k pixels). 8 MiB: on the AMD Zen 4 (1 MiB
#: of L2 a core, 32 MiB of L3) the time surface through a pipeline ran 0.88
#: of the engine-free loop at 1 ms packets with one window a call (2 MiB),
#: 0.93 with two and 0.95-0.96 with four (10 ms: 0.91, 0.96, 0.97; idle,
#: 11 interleaved rounds, twice); the earlier machine had measured one best
JOIN_BYTES = 1 << 23
JOIN_PIXELS = 1 << 17


class Windowed(Operator):
    """Base of the ``repr`` operators. Subclasses implement :meth:`_start`
    (allocate state for a sensor), :meth:`_add` (accumulate events, arrays
    are views) and :meth:`_frame` (the image of the window whose events span
    ``[t0, t1]`` µs, then reset per-window state)."""

    consumes = (Kind.EVENTS,)
    produces = (Kind.FRAMES,)

    def __init__(self, window_us: int | None = None, count: int | None = None, partial: bool = True) -> None:
        self._init_window(window_us, count, partial)

    def _init_window(self, window_us: int | None, count: int | None, partial: bool) -> None:
        if window_us is not None and count is not None:
            raise ValueError("give window_us or count, not both")
        if count is None and window_us is None:
            window_us = 10_000
        if (count is not None and count < 1) or (window_us is not None and window_us < 1):
            raise ValueError("window_us and count must be >= 1")
        self.window_us, self.count, self.partial = window_us, count, bool(partial)
        self._sensor: tuple[int, int] | None = None
        self._end = 0          # time mode: end of the current window (µs)
        self._n = 0            # events in the current window
        self._first = 0        # count mode: time of the window's first event
        self._last = 0         # time of the latest event seen
        self._out = 0          # watermark of the frame stream
        # the frames of the packet being sliced, when a subclass puts them in blocks: (times, images) each
        self._pending: list[tuple[np.ndarray, np.ndarray]] | None = None

    def memory_us(self) -> int | None:
        """Time windows: a frame holds its window's events only, so the
        memory is one window (time sharding), on the grid of windows from
        the first packet; count windows depend on every event before them
        (None). Subclasses whose state outlives a window say None."""
        return self.window_us if self.count is None else None

    def window_grid_us(self) -> int:
        return self.window_us if self.count is None and self.window_us else 0

    def join_us(self) -> int | None:
        """Time windows of a subclass that states its frames' bytes per
        pixel (:meth:`_px_bytes`): the span of about :data:`JOIN_BYTES` of
        frames and state (:meth:`_state_px_bytes`) on a sensor of
        :data:`JOIN_PIXELS` (at least one window), so what one call sweeps
        is still in cache when the next call reuses its memory; else None
        (no limit)."""
        px = self._px_bytes()
        if self.count is not None or not self.window_us or px is None:
            return None
        return self.window_us * max(1, JOIN_BYTES // ((px + self._state_px_bytes()) * JOIN_PIXELS))

    def _px_bytes(self) -> int | None:
        """Bytes a frame takes per sensor pixel (None: not stated)."""
        return None

    def _state_px_bytes(self) -> int:
        """Bytes per sensor pixel of state a call sweeps besides its frames
        (a time surface's decayed values: every frame reads all of them)."""
        return 0

    # -- subclass hooks ---------------------------------------------------------
    def _start(self, sensor: tuple[int, int]) -> None:
        raise NotImplementedError

    def _add(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> None:
        raise NotImplementedError

    def _frame(self, t0: int, t1: int) -> np.ndarray:
        raise NotImplementedError

    def _stack(self, images: list[np.ndarray]) -> np.ndarray:
        """The frames of one packet as one (N, ...) array."""
        return images[0][None] if len(images) == 1 else np.stack(images)

    # -- slicing ------------------------------------------------------------------
    def _begin(self, packet: EventPacket) -> None:
        """The first packet: the sensor, the state, the first window."""
        self._sensor = packet.sensor
        self._start(packet.sensor)
        self._out = packet.t_start
        self._end = packet.t_start + (self.window_us or 0)

    def process(self, packet: EventPacket) -> list[FramePacket]:
        if self._sensor is None:
            self._begin(packet)
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        frames: list[tuple[int, np.ndarray]] = []
        if self.count is None:
            self._by_time(packet, frames)
        else:
            self._by_count(packet, frames)
        if packet.t.shape[0]:
            self._last = int(packet.t[-1])
        return self._emit_packets(frames, packet.t_end)

    def _by_time(self, pk: EventPacket, frames: list[tuple[int, np.ndarray]]) -> None:
        w = int(self.window_us)  # type: ignore[arg-type]
        t, pos, n, t_end = pk.t, 0, len(pk), pk.t_end
        last = int(t[-1]) if n else 0
        while self._end <= t_end:
            # every event lies before t_end: no search when the window ends there or after the last event
            j = n if (pos == n or self._end == t_end or last < self._end) else \
                int(np.searchsorted(t, self._end, side="left"))
            self._take(pk, pos, j)
            frames.append((self._end - 1, self._frame(self._end - w, self._end - 1)))
            self._n = 0
            self._end += w
            pos = j
        if pos < n:
            self._take(pk, pos, n)

    def _by_count(self, pk: EventPacket, frames: list[tuple[int, np.ndarray]]) -> None:
        c = int(self.count)  # type: ignore[arg-type]
        pos, n = 0, len(pk)
        while n - pos >= c - self._n:
            j = pos + c - self._n
            self._take(pk, pos, j)
            last = int(pk.t[j - 1])
            frames.append((last, self._frame(self._first, last)))
            self._n = 0
            pos = j
        self._take(pk, pos, n)

    def _take(self, pk: EventPacket, i: int, j: int) -> None:
        if j > i:
            if self._n == 0:
                self._first = int(pk.t[i])
            self._add(pk.t[i:j], pk.x[i:j], pk.y[i:j], pk.p[i:j])
            self._n += j - i

    def _emit_packets(self, frames: list[tuple[int, np.ndarray]], t_end: int) -> list[FramePacket]:
        """The frames one packet completed, as packets: one, or when a
        subclass put them in blocks (``_pending``, in order), one per block
        (no copy), back to back: each but the last ends after its last
        frame's time."""
        blocks, self._pending = self._pending, None
        if not blocks:
            return [self._emit(frames, t_end)]
        last = len(blocks) - 1
        return [self._block_packet(ts, images, t_end if i == last else None) for i, (ts, images) in enumerate(blocks)]

    def _block_packet(self, ts: np.ndarray, images: np.ndarray, t_end: int | None) -> FramePacket:
        """Frames ``images`` stamped ``ts`` (µs, in order, after the last
        packet's) as the next packet, without a copy; it ends at the
        watermark ``t_end`` (None: just after its last frame, when more
        blocks of the same input packet follow)."""
        t0 = self._out
        self._out = end = int(ts[-1]) + 1 if t_end is None else (t_end if t_end > t0 else t0)
        # built here from times in order inside [t0, end) and frames of the stream's dtype
        # and shape: the checks FramePacket() would repeat hold by construction
        return cast(FramePacket, FramePacket._trusted(ts, {"images": images}, t0, end))

    def _emit(self, frames: list[tuple[int, np.ndarray]], t_end: int) -> FramePacket:
        t0 = self._out
        self._out = max(t_end, self._out)
        if not frames:
            return FramePacket(np.empty(0, np.int64), images=np.empty((0, 0, 0)), t_start=t0, t_end=self._out)
        ts = np.array([f[0] for f in frames], np.int64)
        images = self._stack([f[1] for f in frames])
        return FramePacket(ts, images=images, t_start=t0, t_end=self._out)

    def finish(self) -> list[FramePacket]:
        if not (self.partial and self._n and self._sensor is not None):
            return []
        if self.count is None:
            stamp, image = self._end - 1, self._frame(self._end - self.window_us, self._end - 1)  # type: ignore[operator]
        else:
            stamp, image = max(self._last, self._out), self._frame(self._first, self._last)
        self._n = 0
        return self._emit_packets([(stamp, image)], stamp + 1)

    def describe(self) -> dict[str, Any]:
        """The slicing parameters (for logs and sinks)."""
        return {"window_us": self.window_us, "count": self.count, "partial": self.partial}
