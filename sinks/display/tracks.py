"""Feature tracks (:class:`tectum.TrackPacket`, ``tracker.features``) in
the display sinks.

Each track is drawn as its trail, the positions of its last ``trail_us``
µs as a polyline, and a circle at its newest position, in a colour of its
own (the id's hue, fixed by the id); a track not updated for ``trail_us``
is no longer drawn. Over events, the tracks are drawn on each event frame
at the frame's time. A stream of tracks alone (a sink fed only by
``tracker.features``) is drawn on a dark canvas, a frame per ``1e6 / fps``
µs of track time; the canvas covers the tracks of the first frame with a
margin of a quarter of their extent (the tracker's own border) and keeps
that size.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from tectum import TrackPacket

__all__ = ["TrackOverlay", "TrackFrames", "track_colour"]

#: Background of a canvas of tracks alone (BGR).
CANVAS = (24, 24, 24)


def track_colour(track_id: int) -> tuple[int, int, int]:
    """A saturated BGR colour for a track id (golden-angle hues: neighbours differ)."""
    hue = int((track_id * 137.508) % 180)
    bgr = cv2.cvtColor(np.array([[[hue, 220, 255]]], np.uint8), cv2.COLOR_HSV2BGR)[0, 0]
    return int(bgr[0]), int(bgr[1]), int(bgr[2])


class TrackOverlay:
    """The recent positions of every track, drawn over an image (see the module doc)."""

    def __init__(self, trail_us: int = 100_000) -> None:
        if trail_us < 1:
            raise ValueError(f"trail_us must be >= 1, got {trail_us}")
        self.trail_us = int(trail_us)
        self.trails: dict[int, list[tuple[int, float, float]]] = {}

    def add(self, pkt: TrackPacket) -> None:
        """Take a packet of track rows (t µs, id, x, y px)."""
        for t, i, x, y in zip(pkt.t.tolist(), pkt.id.tolist(), pkt.x.tolist(), pkt.y.tolist()):
            self.trails.setdefault(int(i), []).append((int(t), float(x), float(y)))

    def draw(self, img: np.ndarray, now: int) -> np.ndarray:
        """Draw the tracks' trails up to ``now`` µs onto ``img`` (BGR, in place); returns it."""
        t0 = now - self.trail_us
        for i in list(self.trails):
            pts = self.trails[i]
            while pts and pts[0][0] < t0:
                pts.pop(0)
            if not pts:
                del self.trails[i]
                continue
            shown = [(x, y) for t, x, y in pts if t <= now]
            if not shown:
                continue
            colour = track_colour(i)
            if len(shown) >= 2:
                line = np.round(np.array(shown) * 4).astype(np.int32)  # 2 bits of sub-pixel precision
                cv2.polylines(img, [line], False, colour, 1, cv2.LINE_8, shift=2)
            x, y = shown[-1]
            cv2.circle(img, (int(round(x * 4)), int(round(y * 4))), 12, colour, 1, cv2.LINE_8, shift=2)
        return img


class TrackFrames:
    """Frames of tracks alone, at ``fps`` per second of track time (see the module doc)."""

    def __init__(self, fps: float = 30.0, trail_us: int = 100_000) -> None:
        if not (fps > 0 and math.isfinite(fps)):
            raise ValueError(f"fps must be > 0, got {fps}")
        self.period_us = max(1, int(round(1e6 / fps)))
        self.overlay = TrackOverlay(trail_us)
        self.size: tuple[int, int] | None = None  # (w, h) px
        self.next_t: int | None = None

    def add(self, pkt: TrackPacket) -> list[tuple[int, np.ndarray]]:
        """Take a packet; return the frames whose period ended within it, as (time µs, image)."""
        if self.next_t is None:
            self.next_t = pkt.t_start + self.period_us
        out: list[tuple[int, np.ndarray]] = []
        t = pkt.t
        i = 0
        while self.next_t <= pkt.t_end:
            j = int(np.searchsorted(t, self.next_t, side="left"))
            self._take(pkt, i, j)
            i = j
            if self.size is not None:
                w, h = self.size
                canvas = np.empty((h, w, 3), np.uint8)
                canvas[:] = CANVAS
                out.append((self.next_t, self.overlay.draw(canvas, self.next_t)))
            self.next_t += self.period_us
        self._take(pkt, i, len(t))
        return out

    def _take(self, pkt: TrackPacket, i: int, j: int) -> None:
        if j <= i:
            return
        part = pkt.take(np.arange(i, j))
        assert isinstance(part, TrackPacket)
        self.overlay.add(part)
        if self.size is None:
            x, y = part.x, part.y
            pad_x = max(8.0, 0.25 * float(x.max() - x.min()))
            pad_y = max(8.0, 0.25 * float(y.max() - y.min()))
            self.size = (int(math.ceil(float(x.max()) + pad_x)) + 1, int(math.ceil(float(y.max()) + pad_y)) + 1)
