"""Rendering events into images at a set frame rate (event time).

:class:`Renderer` keeps, per pixel, the time and polarity of its newest
event (state arrays updated by a numba kernel) and draws a frame every
``1e6 / fps`` µs of event time: ``polarity`` mode colours pixels that fired
during the last frame period by polarity, ``time_surface`` mode shows every
pixel's recency, ``exp(-(t - t_last) / tau)``, tinted by polarity.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numba import njit

from tectum import EventPacket

__all__ = ["Renderer", "BACKGROUND", "ON_COLOUR", "OFF_COLOUR"]

#: BGR colours (OpenCV order) of the background and of ON / OFF events.
BACKGROUND = (40, 40, 40)
ON_COLOUR = (255, 180, 40)  # light blue
OFF_COLOUR = (40, 60, 255)  # red
Mode = Literal["polarity", "time_surface"]


@njit(cache=True)
def update_last(last_t: np.ndarray, last_p: np.ndarray, t: np.ndarray, x: np.ndarray, y: np.ndarray,
                p: np.ndarray) -> None:
    """Write each event's time (µs) and polarity into its pixel."""
    for i in range(t.shape[0]):
        last_t[y[i], x[i]] = t[i]
        last_p[y[i], x[i]] = p[i]


@njit(cache=True)
def draw(last_t: np.ndarray, last_p: np.ndarray, now: np.int64, window_us: np.int64, tau_us: float,
         surface: bool, bg: np.ndarray, on: np.ndarray, off: np.ndarray, out: np.ndarray) -> None:
    """Fill ``out`` (H, W, 3) uint8 for the frame ending at ``now`` µs."""
    h, w = last_t.shape
    for r in range(h):
        for c in range(w):
            lt = last_t[r, c]
            col = on if last_p[r, c] > 0 else off
            if surface:
                a = np.exp(-(now - lt) / tau_us) if lt >= 0 and lt <= now else 0.0
            else:
                a = 1.0 if lt >= now - window_us and lt >= 0 else 0.0
            for k in range(3):
                out[r, c, k] = np.uint8(bg[k] + a * (col[k] - bg[k]))


class Renderer:
    """Frames of ``sensor`` (width, height) pixels at ``fps`` frames per
    second of event time; ``tau_us`` is the time-surface decay in µs."""

    def __init__(self, sensor: tuple[int, int], fps: float = 30.0, mode: Mode = "polarity",
                 tau_us: float = 30_000.0, max_frames_per_packet: int = 1000) -> None:
        if fps <= 0 or tau_us <= 0:
            raise ValueError("fps and tau_us must be > 0")
        if mode not in ("polarity", "time_surface"):
            raise ValueError(f"mode must be polarity or time_surface, got {mode!r}")
        w, h = sensor
        self.sensor, self.mode, self.tau_us = (w, h), mode, float(tau_us)
        self.period_us = max(1, int(round(1e6 / fps)))
        self.last_t = np.full((h, w), -1, np.int64)
        self.last_p = np.zeros((h, w), np.int8)
        self.next_t: int | None = None
        self.max_frames = max_frames_per_packet
        self._colours = [np.array(c, np.float64) for c in (BACKGROUND, ON_COLOUR, OFF_COLOUR)]
        self.frames = 0

    def render(self, now: int) -> np.ndarray:
        """The frame for the period ending at ``now`` µs (H, W, 3) BGR uint8."""
        h, w = self.last_t.shape
        out = np.empty((h, w, 3), np.uint8)
        bg, on, off = self._colours
        draw(self.last_t, self.last_p, np.int64(now), np.int64(self.period_us), self.tau_us,
             self.mode == "time_surface", bg, on, off, out)
        self.frames += 1
        return out

    def add(self, pkt: EventPacket) -> list[tuple[int, np.ndarray]]:
        """Take a packet; return the frames whose period ended within it, as
        (time µs, image). Long gaps yield at most ``max_frames_per_packet``."""
        if self.next_t is None:
            self.next_t = pkt.t_start + self.period_us
        out: list[tuple[int, np.ndarray]] = []
        t = pkt.t
        i = 0
        if pkt.t_end - self.next_t > self.max_frames * self.period_us:  # skip ahead over a gap
            skip = (pkt.t_end - self.next_t) // self.period_us - self.max_frames
            self.next_t += int(skip) * self.period_us
        while self.next_t <= pkt.t_end:
            j = int(np.searchsorted(t, self.next_t, side="left"))
            update_last(self.last_t, self.last_p, t[i:j], pkt.x[i:j], pkt.y[i:j], pkt.p[i:j])
            i = j
            out.append((self.next_t, self.render(self.next_t)))
            self.next_t += self.period_us
        update_last(self.last_t, self.last_p, t[i:], pkt.x[i:], pkt.y[i:], pkt.p[i:])
        return out
