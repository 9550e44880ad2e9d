"""``map.high_pass``: log intensity from events alone by a per-pixel
high-pass filter (Scheerlinck, Barnes, Mahony, "Continuous-time intensity
estimation using event cameras", ACCV 2018).

Each event adds its contrast to its pixel's log-intensity estimate (direct
integration, ``+c_on`` / ``-c_off``), and the estimate leaks back to 0 at
the rate ``alpha`` (rad/s, the filter's cut-off): ``dL/dt = E(t) - α L``.
Plain integration (``alpha = 0``) drifts without bound from noise and
contrast mismatch; the leak forgets it, at the price of the static (DC)
content: a pixel that sees no event for a few ``1/α`` reads 0. What remains
is the log intensity minus its recent (``~1/α``) average at that pixel, so
the filter shows the scene well while the camera moves over it.

Maps: per window a :class:`tectum.MapPacket` sample with ``image`` (H, W
float32 log intensity, every pixel decayed to the sample's time) and
``confidence`` (``exp(-α age)`` of the pixel's latest event, 0 where none
came). Windows follow :mod:`tectum.plugins.repr._window`'s rules: time
windows ``[t0 + kW, t0 + (k + 1) W)`` (``t0`` the stream's start) stamped
``end - 1`` and emitted once the watermark reaches their end, or every
``count`` events stamped at the last; with ``partial`` the unfinished last
window is emitted at end of stream, stamped at the stream's end, when
events came in it. Or maps at given instants (``at_us``: the timestamps of
reference frames, as EVREAL scores reconstructions), each holding the
events up to and including its µs. The state depends on the events only, and a
map on its time only: the output is the same however the stream is split.

Cost: one ``exp`` and two cell updates per event (numba: about 150 Mev/s
per core for the kernel, 90-110 Mev/s for the operator with a 346x260 map
every 10 ms, CPU time in ``tectum bench map``), plus one vectorised pass
over the image per map (0.3 ms at 346x260). Memory: 12
bytes per pixel of state (1.1 MB at 346x260) plus 8 bytes per pixel per map.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np

from tectum import EventPacket, Kind, MapPacket, Operator, Packet, Port, concat

from ._integrate import integrate_events, new_state, read_map

__all__ = ["HighPass"]

_EMIT, _FRAME = 0, 1  # action kinds; at one position and time a map comes before a frame


class HighPass(Operator):
    """Log-intensity maps from events by a per-pixel leaky integrator (high-pass filter, Scheerlinck et al. 2018).

    Parameters
    ----------
    alpha:
        Cut-off of the high-pass filter, rad/s: the estimate forgets with
        time constant ``1/alpha`` s. Default 15 (2.4 Hz, 67 ms of memory):
        long enough for a moving camera to sweep many texels over a pixel,
        short enough to forget the drift of noise and of thresholds that
        differ from ``c_on``/``c_off`` (measured on the simulator's rotation
        and 6-DoF scenes: best Pearson at 6-10 rad/s without sensor noise,
        at 20-30 with a DAVIS-like one; 15 is within 0.03 of both); 0 is
        plain integration.
    c_on:
        Contrast of an ON event, log-intensity units (> 0: the sensor's ON
        threshold, about 0.1-0.5 for DAVIS sensors).
    c_off:
        Contrast of an OFF event (> 0; the event subtracts it).
    window_us:
        Time windows of this many µs (default 10 000 when ``count`` is not given).
    count:
        Or a map every ``count`` events.
    partial:
        Emit the unfinished last window at end of stream when it holds events.
    at_us:
        Or maps at these instants (µs, increasing) instead of windows;
        those past the stream's end come at its end.
    """

    name = "map.high_pass"
    inputs = {"events": Port(Kind.EVENTS, doc="the events to integrate")}
    produces = (Kind.MAPS,)

    #: For the conformance check: short windows over the 40 ms stream.
    conformance_params = {"window_us": 4000, "alpha": 20.0}
    #: Maps carry ``confidence`` (the decay factor of each pixel's latest event).
    with_confidence: ClassVar[bool] = True

    def __init__(self, alpha: float = 15.0, c_on: float = 0.2, c_off: float = 0.2,
                 window_us: int | None = None, count: int | None = None, partial: bool = True,
                 at_us: tuple[int, ...] = ()) -> None:
        if not (math.isfinite(alpha) and alpha >= 0):
            raise ValueError(f"alpha must be a finite rate >= 0 rad/s, got {alpha}")
        if not (c_on > 0 and c_off > 0 and math.isfinite(c_on) and math.isfinite(c_off)):
            raise ValueError(f"c_on and c_off must be finite and > 0, got {c_on}, {c_off}")
        if sum(v is not None for v in (window_us, count, at_us or None)) > 1:
            raise ValueError("give one of window_us, count and at_us")
        self.at = np.asarray(at_us, np.int64)
        if self.at.ndim != 1 or (self.at.size > 1 and not np.all(np.diff(self.at) > 0)):
            raise ValueError("at_us must be increasing times (µs)")
        self._k = 0  # the next of self.at
        if window_us is None and count is None and not self.at.size:
            window_us = 10_000
        if (count is not None and count < 1) or (window_us is not None and window_us < 1):
            raise ValueError("window_us and count must be >= 1")
        self.alpha, self.c_on, self.c_off = float(alpha), float(c_on), float(c_off)
        self.window_us, self.count, self.partial = window_us, count, bool(partial)
        self._a = self.alpha * 1e-6  # per µs
        self.D: np.ndarray | None = None          # log intensity minus the base, (H, W) float32
        self.t_last: np.ndarray | None = None     # last update per pixel, (H, W) int64 µs
        self.base = np.empty((0, 0), np.float32)  # L_F: none (0) for the high-pass filter
        self._end: int | None = None  # time mode: end of the current window (µs)
        self._n = 0                   # events in the current window
        self._last = 0                # time of the latest event (µs)
        self._out = 0                 # watermark of the map stream (µs)
        self.counts = {"events": 0, "maps": 0}

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """Bars moving over a 48x36 sensor with noise, 40 ms."""
        from tectum.sources.pattern import PatternSource

        ev = concat(list(PatternSource(sensor="48x36", duration_us=40_000, noise_hz=20.0, speed=300.0).packets()))
        return {"events": ev}

    def warmup(self) -> None:
        D, tl = new_state((2, 2))
        z = np.zeros(2, np.uint16)
        integrate_events(np.arange(2, dtype=np.int64), z, z, np.ones(2, np.int8), D, tl, 1e-6, 0.1, 0.1)
        read_map(D, tl, self.base, 3, 1e-6, np.empty_like(D), np.empty_like(D))

    # -- input --------------------------------------------------------------------
    def process_ports(self, ports: Mapping[str, Packet]) -> list[MapPacket]:
        first = next(iter(ports.values()))
        t0, t1 = first.t_start, first.t_end
        if self._end is None:
            self._out = min(t0, int(self.at[0])) if self.at.size else t0
            self._end = t0 + (self.window_us or 0)
        ev = ports.get("events")
        if ev is not None:
            assert isinstance(ev, EventPacket)
            self._ensure_state(ev.sensor)
        else:
            ev = None
        t = ev.t if ev is not None else np.empty(0, np.int64)
        actions = self._map_cuts(t, t1) + self._frame_cuts(ports, t)
        actions.sort(key=lambda a: (a[0], a[1], a[2]))
        stamps = [a[3] for a in actions if a[2] == _EMIT]
        image, conf = self._allocate(len(stamps))
        pos = m = 0
        for idx, _key, what, arg in actions:
            self._integrate(ev, pos, idx)
            pos = idx
            if what == _EMIT:
                read_map(self.D, self.t_last, self.base, arg, self._a, image[m], conf[m])
                m += 1
            else:
                self._apply_frame(ports, arg)
        self._integrate(ev, pos, len(t))
        if len(t):
            self._last = int(t[-1])
        return [self._packet(stamps, image, conf, t1)]

    def finish(self) -> list[MapPacket]:
        if self.at.size:
            late = [int(v) for v in self.at[self._k:]] if self.D is not None else []
            self._k = self.at.size
        elif self.partial and self._n and self.D is not None:
            late = [self._out]  # the stream's end: every event is before it
            self._n = 0
        else:
            late = []
        if not late:
            return []
        image, conf = self._allocate(len(late))
        for m, stamp in enumerate(late):
            read_map(self.D, self.t_last, self.base, stamp, self._a, image[m], conf[m])
        return [self._packet(late, image, conf, late[-1] + 1)]

    # -- hooks for map.complementary -------------------------------------------------
    def _frame_cuts(self, ports: Mapping[str, Packet], t: np.ndarray) -> list[tuple[int, int, int, int]]:
        """Frames to apply within this batch, as ``(event index, time, _FRAME, frame index)``."""
        return []

    def _apply_frame(self, ports: Mapping[str, Packet], k: int) -> None:
        raise NotImplementedError

    # -- windows ----------------------------------------------------------------------
    def _map_cuts(self, t: np.ndarray, t1: int) -> list[tuple[int, int, int, int]]:
        """The maps due in a batch ending at ``t1`` with event times ``t``:
        ``(event index, key, _EMIT, stamp)``; a map holds what came before
        ``key`` µs (``stamp + 1``). Updates the window counters."""
        out: list[tuple[int, int, int, int]] = []
        n = len(t)
        if self.at.size:
            while self._k < self.at.size and self.at[self._k] < t1 and self.D is not None:
                v = int(self.at[self._k])
                out.append((int(np.searchsorted(t, v, side="right")), v + 1, _EMIT, v))
                self._k += 1
            return out
        if self.count is None:
            w = int(self.window_us)  # type: ignore[arg-type]
            i0 = 0
            assert self._end is not None
            while self._end <= t1:
                e = self._end
                j = int(np.searchsorted(t, e, side="left"))
                self._n += j - i0
                if self.D is not None:  # no map before the sensor size is known
                    out.append((j, e, _EMIT, e - 1))
                self._n, i0 = 0, j
                self._end = e + w
            self._n += n - i0
            return out
        c = int(self.count)
        j = c - self._n
        while j <= n:
            out.append((j, int(t[j - 1]) + 1, _EMIT, int(t[j - 1])))
            j += c
        self._n = (self._n + n) % c if n else self._n
        return out

    # -- state ---------------------------------------------------------------------------
    def _ensure_state(self, sensor: tuple[int, int]) -> None:
        if self.D is None:
            self.D, self.t_last = new_state(sensor)
        elif (self.D.shape[1], self.D.shape[0]) != tuple(sensor):
            raise ValueError(f"{self.name}: sensor size changed from {self.D.shape[1]}x{self.D.shape[0]} "
                             f"to {sensor[0]}x{sensor[1]}")

    def _integrate(self, ev: EventPacket | None, i: int, j: int) -> None:
        if ev is None or j <= i:
            return
        integrate_events(ev.t[i:j], ev.x[i:j], ev.y[i:j], ev.p[i:j], self.D, self.t_last, self._a,
                         self.c_on, self.c_off)
        self.counts["events"] += j - i

    def _allocate(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``n`` maps' ``image`` and ``confidence`` arrays (n, H, W) float32."""
        h, w = self.D.shape if self.D is not None else (0, 0)
        return np.empty((n, h, w), np.float32), np.empty((n, h, w), np.float32)

    def _packet(self, stamps: Sequence[int], image: np.ndarray, conf: np.ndarray, t_end: int) -> MapPacket:
        t0 = self._out
        self._out = max(t_end, self._out)
        self.counts["maps"] += len(stamps)
        fields = {"image": image, "confidence": conf} if self.with_confidence else {"image": image}
        return MapPacket(np.array(stamps, np.int64), t_start=t0, t_end=self._out, **fields)
