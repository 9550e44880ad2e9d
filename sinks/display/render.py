"""Rendering events into images at a set frame rate (event time).

:class:`Renderer` keeps, per pixel, the time and polarity of its newest
event (state arrays updated by a numba kernel) and draws a frame every
``1e6 / fps`` µs of event time: ``polarity`` mode colours pixels that fired
during the last frame period by polarity, ``time_surface`` mode shows every
pixel's recency, ``exp(-(t - t_last) / tau)``, tinted by polarity.

With optical flow columns ``vx``, ``vy`` (px/s) on the events,
``flow_wheel`` colours each pixel that fired in the last period by its
newest flow's direction (hue: angle, 0 = +x = red, counter-clockwise in
image coordinates with y down) and speed (saturation, full at
``flow_max_px_s``); ``flow_arrows`` draws the polarity picture with one
arrow per ``arrow_step`` px cell: the mean flow of the cell's pixels that
fired, ``arrow_scale_s`` seconds of motion long. Tracks (a ResultPacket
whose items are ``(id, x, y)`` tuples or dicts with those keys) are drawn
as polylines of their last ``track_points`` positions in every mode.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import cv2
import numpy as np
from numba import njit

from tectum import EventPacket, ResultPacket

__all__ = ["Renderer", "flow_wheel_legend", "BACKGROUND", "ON_COLOUR", "OFF_COLOUR", "TRACK_COLOUR"]

#: BGR colours (OpenCV order) of the background and of ON / OFF events.
BACKGROUND = (40, 40, 40)
ON_COLOUR = (255, 180, 40)  # light blue
OFF_COLOUR = (40, 60, 255)  # red
Mode = Literal["polarity", "time_surface", "flow_wheel", "flow_arrows"]
MODES = ("polarity", "time_surface", "flow_wheel", "flow_arrows")
TRACK_COLOUR = (60, 255, 60)  # green


@njit(cache=True)
def update_flow(vx_map: np.ndarray, vy_map: np.ndarray, x: np.ndarray, y: np.ndarray, vx: np.ndarray,
                vy: np.ndarray) -> None:
    """Write each event's flow (px/s) into its pixel (NaN flows are skipped)."""
    for i in range(x.shape[0]):
        if vx[i] == vx[i] and vy[i] == vy[i]:
            vx_map[y[i], x[i]] = vx[i]
            vy_map[y[i], x[i]] = vy[i]


@njit(cache=True)
def hsv_bgr(h: float, s: float, v: float) -> tuple[float, float, float]:
    """HSV (hue in [0, 1)) to B, G, R in [0, 1]."""
    i = int(h * 6.0) % 6
    f = h * 6.0 - math.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    if i == 0:
        r, g, b = v, t, p
    elif i == 1:
        r, g, b = q, v, p
    elif i == 2:
        r, g, b = p, v, t
    elif i == 3:
        r, g, b = p, q, v
    elif i == 4:
        r, g, b = t, p, v
    else:
        r, g, b = v, p, q
    return b, g, r


@njit(cache=True)
def draw_wheel(last_t: np.ndarray, vx_map: np.ndarray, vy_map: np.ndarray, now: np.int64, window_us: np.int64,
               vmax: float, bg: np.ndarray, out: np.ndarray) -> None:
    """Colour-wheel flow picture of the pixels that fired in the last period."""
    h, w = last_t.shape
    for r in range(h):
        for c in range(w):
            lt = last_t[r, c]
            vx, vy = vx_map[r, c], vy_map[r, c]
            if lt < 0 or lt < now - window_us or vx != vx:
                for k in range(3):
                    out[r, c, k] = np.uint8(bg[k])
                continue
            ang = math.atan2(-vy, vx)  # y grows downwards: counter-clockwise on screen
            hue = (ang / (2 * math.pi)) % 1.0
            sat = min(1.0, math.sqrt(vx * vx + vy * vy) / vmax)
            b, g, rr = hsv_bgr(hue, sat, 1.0)
            out[r, c, 0] = np.uint8(round(b * 255))
            out[r, c, 1] = np.uint8(round(g * 255))
            out[r, c, 2] = np.uint8(round(rr * 255))


@njit(cache=True)
def cell_flow(last_t: np.ndarray, vx_map: np.ndarray, vy_map: np.ndarray, now: np.int64, window_us: np.int64,
              step: int, mean: np.ndarray) -> None:
    """Mean flow (px/s) of each ``step``-px cell's pixels that fired in the
    last period: ``mean[cy, cx] = (vx, vy, count)``."""
    mean[:] = 0.0
    h, w = last_t.shape
    for r in range(h):
        for c in range(w):
            lt = last_t[r, c]
            if lt < 0 or lt < now - window_us or vx_map[r, c] != vx_map[r, c]:
                continue
            m = mean[r // step, c // step]
            m[0] += vx_map[r, c]
            m[1] += vy_map[r, c]
            m[2] += 1.0
    for i in range(mean.shape[0]):
        for j in range(mean.shape[1]):
            if mean[i, j, 2] > 0:
                mean[i, j, 0] /= mean[i, j, 2]
                mean[i, j, 1] /= mean[i, j, 2]


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


def flow_wheel_legend(size: int, flow_max_px_s: float) -> np.ndarray:
    """The key to ``flow_wheel`` pictures, (size, size, 3) BGR uint8: each
    pixel of a disc coloured as a flow pointing from the centre to it, full
    speed (``flow_max_px_s``) on the rim; drawn by the same kernel."""
    c = (size - 1) / 2
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    dx, dy = (xx - c) / c, (yy - c) / c
    outside = dx * dx + dy * dy > 1.0
    vx = np.where(outside, np.nan, dx * flow_max_px_s).astype(np.float32)
    vy = np.where(outside, np.nan, dy * flow_max_px_s).astype(np.float32)
    out = np.empty((size, size, 3), np.uint8)
    draw_wheel(np.zeros((size, size), np.int64), vx, vy, np.int64(0), np.int64(1), float(flow_max_px_s),
               np.array(BACKGROUND, np.float64), out)
    return out


class Renderer:
    """Frames of ``sensor`` (width, height) pixels at ``fps`` frames per
    second of event time; ``tau_us`` is the time-surface decay in µs; flow
    modes and tracks as in the module docstring."""

    def __init__(self, sensor: tuple[int, int], fps: float = 30.0, mode: Mode = "polarity",
                 tau_us: float = 30_000.0, max_frames_per_packet: int = 1000, flow_max_px_s: float = 500.0,
                 arrow_step: int = 12, arrow_scale_s: float = 0.02, track_points: int = 64) -> None:
        if fps <= 0 or tau_us <= 0 or flow_max_px_s <= 0 or arrow_step < 2 or arrow_scale_s <= 0 or track_points < 2:
            raise ValueError("fps, tau_us, flow_max_px_s, arrow_scale_s must be > 0; arrow_step, track_points >= 2")
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.flow_max, self.arrow_step, self.arrow_scale = float(flow_max_px_s), arrow_step, arrow_scale_s
        self.track_points = track_points
        self.tracks: dict[Any, list[tuple[float, float]]] = {}
        w, h = sensor
        self.sensor, self.mode, self.tau_us = (w, h), mode, float(tau_us)
        self.period_us = max(1, int(round(1e6 / fps)))
        self.last_t = np.full((h, w), -1, np.int64)
        self.last_p = np.zeros((h, w), np.int8)
        self.vx = np.full((h, w), np.nan, np.float32)
        self.vy = np.full((h, w), np.nan, np.float32)
        self.next_t: int | None = None
        self.max_frames = max_frames_per_packet
        self._colours = [np.array(c, np.float64) for c in (BACKGROUND, ON_COLOUR, OFF_COLOUR)]
        self.frames = 0

    def render(self, now: int) -> np.ndarray:
        """The frame for the period ending at ``now`` µs (H, W, 3) BGR uint8."""
        h, w = self.last_t.shape
        out = np.empty((h, w, 3), np.uint8)
        bg, on, off = self._colours
        if self.mode == "flow_wheel":
            draw_wheel(self.last_t, self.vx, self.vy, np.int64(now), np.int64(self.period_us), self.flow_max, bg, out)
        else:
            draw(self.last_t, self.last_p, np.int64(now), np.int64(self.period_us), self.tau_us,
                 self.mode == "time_surface", bg, on, off, out)
        if self.mode == "flow_arrows":
            self._arrows(out, now)
        for pts in self.tracks.values():
            if len(pts) >= 2:
                cv2.polylines(out, [np.round(np.array(pts)).astype(np.int32)], False, TRACK_COLOUR, 1, cv2.LINE_8)
        self.frames += 1
        return out

    def _arrows(self, out: np.ndarray, now: int) -> None:
        s = self.arrow_step
        h, w = self.last_t.shape
        mean = np.zeros(((h + s - 1) // s, (w + s - 1) // s, 3), np.float64)
        cell_flow(self.last_t, self.vx, self.vy, np.int64(now), np.int64(self.period_us), s, mean)
        for i, j in zip(*np.nonzero(mean[:, :, 2])):
            cx, cy = j * s + s / 2, i * s + s / 2
            dx, dy = mean[i, j, 0] * self.arrow_scale, mean[i, j, 1] * self.arrow_scale
            if dx * dx + dy * dy < 1.0:
                continue
            cv2.arrowedLine(out, (int(cx), int(cy)), (int(round(cx + dx)), int(round(cy + dy))), (255, 255, 255),
                            1, cv2.LINE_AA, tipLength=0.3)

    def add_tracks(self, pkt: ResultPacket) -> None:
        """Take track positions: items ``(id, x, y)`` or dicts with keys
        ``id``, ``x``, ``y`` (px); other items are ignored."""
        for item in pkt.items:
            if isinstance(item, dict) and {"id", "x", "y"} <= item.keys():
                key, x, y = item["id"], item["x"], item["y"]
            elif isinstance(item, (tuple, list)) and len(item) == 3:
                key, x, y = item
            else:
                continue
            pts = self.tracks.setdefault(key, [])
            pts.append((float(x), float(y)))
            del pts[:-self.track_points]

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
            self._update(pkt, i, j)
            i = j
            out.append((self.next_t, self.render(self.next_t)))
            self.next_t += self.period_us
        self._update(pkt, i, len(t))
        return out

    def _update(self, pkt: EventPacket, i: int, j: int) -> None:
        update_last(self.last_t, self.last_p, pkt.t[i:j], pkt.x[i:j], pkt.y[i:j], pkt.p[i:j])
        if self.mode in ("flow_wheel", "flow_arrows") and "vx" in pkt.columns and "vy" in pkt.columns:
            update_flow(self.vx, self.vy, pkt.x[i:j], pkt.y[i:j], pkt.columns["vx"][i:j].astype(np.float32),
                        pkt.columns["vy"][i:j].astype(np.float32))
