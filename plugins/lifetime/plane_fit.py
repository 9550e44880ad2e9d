"""``lifetime.plane_fit``: event lifetime (Mueggler et al., ICRA 2015).

The lifetime of an event is the time its edge takes to travel one pixel,
``1 / |normal speed|`` = the magnitude of the time-surface gradient (µs/px).
Per polarity, the surface of active events around the event is fitted with
a plane (the robust fit of :mod:`tectum.plugins.flow._plane`, standing in for
the paper's RANSAC: it starts from the youngest points and rejects outliers
by a data-driven threshold), then the estimate is regularised: when the
pixel one step back along the motion has a fresh lifetime, the result is
``(1 - regularise) * fit + regularise * neighbour``.

Optional output: every ``frame_us`` µs a lifetime-augmented event frame
(FramePacket, (1, H, W) int8): each pixel shows the polarity of its latest
event whose lifetime has not ended at the frame time (0 elsewhere); the
frame at time T holds the events before T and is emitted once the watermark
reaches T.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, FramePacket, Kind, Operator, same_sensor
from tectum.plugins.flow._common import NEVER
from tectum.plugins.flow._plane import SPAN, crossing_time, new_surface, plane_fit, plane_scratch, rel_time

__all__ = ["PlaneFitLifetime", "lifetime_kernel"]


@njit(cache=True, nogil=True)
def lifetime_kernel(t, x, y, p, sae, base, last, burst_us, life, radius, window_us,  # type: ignore[no-untyped-def]
                    robust_k, floor_us, min_points, max_rms, min_life, max_life, regularise, out, until, pol, frame_t,
                    frame_us, frames):
    """Per event: lifetime (µs, NaN if invalid) into ``out``; ``sae`` the
    padded surface relative to ``base[0]`` (see
    :func:`tectum.plugins.flow._plane.new_surface`); ``life`` (2, H, W)
    float64 stores each pixel's last lifetime; with ``burst_us > 0``,
    ``last`` (H, W) int64 holds each pixel's last event time signed by its
    polarity (0 = none) and an event of the same crossing is fitted at the
    crossing's first time (see :class:`PlaneFitLifetime`). With ``frame_us > 0`` also
    renders frames at ``frame_t[0], frame_t[0] + frame_us, ...`` before the
    first event at or after each; returns how many were written to ``frames``."""
    scr = plane_scratch(radius)
    _, h, w = life.shape
    nf = 0
    for i in range(t.shape[0]):
        k = 1 if p[i] > 0 else 0
        xi, yi = np.int64(x[i]), np.int64(y[i])
        while frame_us > 0 and t[i] >= frame_t[0]:
            _render(until, pol, frame_t[0], frames[nf])
            nf += 1
            frame_t[0] += frame_us
        ti = crossing_time(sae, last, burst_us, window_us, k, xi, yi, radius, t[i], rel_time(sae, base, t[i]))
        sae[yi + radius, xi + radius, k] = ti
        a, b, _, rms, ok = plane_fit(sae, k, xi, yi, ti, radius, window_us, 3, 0.0, True, robust_k, floor_us,
                                        min_points, scr)
        tau = np.sqrt(a * a + b * b)
        if ok:
            ok = tau > 0.0 and rms <= max_rms * tau
        if ok:
            # neighbour one pixel back along the motion (the normal is (a, b)/tau)
            nx = xi - np.int64(np.round(a / tau))
            ny = yi - np.int64(np.round(b / tau))
            if 0 <= nx < w and 0 <= ny < h and regularise > 0.0:
                prev = life[k, ny, nx]
                if ti - np.int64(sae[ny + radius, nx + radius, k]) <= window_us and np.isfinite(prev):
                    tau = (1.0 - regularise) * tau + regularise * prev
            ok = min_life <= tau <= max_life
        if ok:
            out[i] = tau
            life[k, yi, xi] = tau
            until[yi, xi] = t[i] + np.int64(np.ceil(tau))
            pol[yi, xi] = p[i]
        else:
            out[i] = np.nan
            life[k, yi, xi] = np.nan
    return nf


@njit(cache=True, nogil=True)
def _render(until, pol, tf, frame):  # type: ignore[no-untyped-def]
    h, w = until.shape
    for r in range(h):
        for c in range(w):
            frame[r, c] = pol[r, c] if until[r, c] > tf else 0


class PlaneFitLifetime(Operator):
    """Event lifetime (µs) by local plane fitting, Mueggler et al. (2015).

    Output column ``out`` (default ``lifetime``): µs, NaN where no reliable
    plane (invalid). Parameters: ``radius`` (px), ``window_us`` (µs),
    ``robust_k``, ``floor_us`` (µs), ``min_points``, ``max_rms`` (fraction
    of the lifetime), ``min_life_us``/``max_life_us``, ``regularise`` (0..1,
    weight of the neighbour's lifetime), ``frame_us`` (µs, 0 = no frames),
    ``burst_us`` (µs, 0 = off): as in ``flow.plane_fit``, an event that
    follows its pixel's previous event of the same polarity within
    ``burst_us`` belongs to the same edge crossing; the surface keeps the
    crossing's first time and the event gets the lifetime fitted there (a
    blurred edge firing several events per pixel otherwise makes the
    surface lag and the lifetime come out too short).
    """

    name = "lifetime.plane_fit"
    consumes = (Kind.EVENTS,)
    produces = (Kind.EVENTS, Kind.FRAMES)

    def __init__(self, radius: int = 3, window_us: int = 30_000, robust_k: float = 3.0, floor_us: float = 300.0,
                 min_points: int = 6, max_rms: float = 1.0, min_life_us: float = 50.0,
                 max_life_us: float = 1_000_000.0, regularise: float = 0.5, frame_us: int = 0, burst_us: int = 0,
                 out: str = "lifetime") -> None:
        if radius < 1 or not 0 < window_us < SPAN // 2 or min_points < 3 or not 0 <= regularise <= 1 or frame_us < 0:
            raise ValueError(f"need radius >= 1, 0 < window_us < {SPAN // 2}, min_points >= 3, "
                             "0 <= regularise <= 1, frame_us >= 0")
        if burst_us < 0:
            raise ValueError("need burst_us >= 0")
        self.burst_us = int(burst_us)
        if out in ("t", "x", "y", "p") or not out:
            raise ValueError(f"bad output column name {out!r}")
        self.radius, self.window_us, self.robust_k, self.floor_us = int(radius), int(window_us), robust_k, floor_us
        self.min_points, self.max_rms, self.regularise = int(min_points), float(max_rms), float(regularise)
        self.min_life, self.max_life = float(min_life_us), float(max_life_us)
        self.frame_us, self.out = int(frame_us), out
        self.sae: np.ndarray | None = None
        self._sensor = (0, 0)  # (width, height) px the surface was made for
        self.frame_t = np.zeros(1, np.int64)

    def _frames_until(self, upto: int) -> int:
        """How many frame times are at or before the watermark ``upto`` (µs)."""
        if not self.frame_us or upto < self.frame_t[0]:
            return 0
        return int((upto - self.frame_t[0]) // self.frame_us) + 1

    def memory_us(self) -> int | None:
        """Points older than ``window_us`` are left out of the fit (time
        sharding). ``regularise`` blends in a neighbour's last lifetime,
        however old, and ``burst_us`` keeps a crossing's first event while
        its pixel fires, and ``frame_us`` frames count from the first packet:
        with any of them the memory has no bound (None)."""
        return None if (self.regularise or self.burst_us or self.frame_us) else self.window_us

    def process(self, packet: EventPacket) -> list[EventPacket | FramePacket]:
        w, h = packet.sensor
        if self.sae is None:
            self.sae = new_surface(packet.sensor, self.radius)
            self.base = np.array([packet.t_start], np.int64)
            self.last = np.zeros((h, w) if self.burst_us else (1, 1), np.int64)
            self.life = np.full((2, h, w), np.nan)
            self.until = np.full((h, w), NEVER, np.int64)
            self.pol = np.zeros((h, w), np.int8)
            if self.frame_us:
                self.frame_t[0] = -(-packet.t_start // self.frame_us) * self.frame_us
            self._sensor = packet.sensor
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        # frames due inside this packet or at its watermark (events before T are all in)
        n_frames = self._frames_until(packet.t_end)
        frames = np.zeros((n_frames, h, w), np.int8)
        t0 = int(self.frame_t[0])
        out = np.empty(len(packet), np.float64)
        nf = lifetime_kernel(packet.t, packet.x, packet.y, packet.p, self.sae, self.base, self.last, self.burst_us,
                             self.life, self.radius, self.window_us, self.robust_k, self.floor_us, self.min_points,
                             self.max_rms, self.min_life, self.max_life, self.regularise, out, self.until, self.pol,
                             self.frame_t, self.frame_us, frames)
        while nf < n_frames:  # frames at or before the watermark with no later event in this packet
            _render(self.until, self.pol, self.frame_t[0], frames[nf])
            nf += 1
            self.frame_t[0] += self.frame_us
        result: list[EventPacket | FramePacket] = [packet.with_columns(**{self.out: out})]
        if n_frames:
            ft = t0 + self.frame_us * np.arange(n_frames, dtype=np.int64)
            result.append(FramePacket(ft, images=frames, t_start=int(ft[0]), t_end=int(ft[-1]) + 1))
        return result
