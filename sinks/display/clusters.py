"""Moving-object clusters (:class:`tectum.ClusterPacket`, ``tracker.clusters``)
in the display sinks.

Over each event frame, every cluster's newest row at or before the frame's
time is drawn as its box (``width`` x ``height`` px about its centre), its
velocity as a line from the centre (where it will be in ``lead_us``) and its
id, in the id's colour (the hues of :func:`.tracks.track_colour`); a cluster
without a row for ``hold_us`` µs is no longer drawn. A sink fed clusters
alone (``tectum run ... --op tracker.clusters --sink http://...``) draws
their centres' trails on a canvas, as tracks alone are drawn
(:func:`as_tracks`, :class:`.tracks.TrackFrames`).
"""

from __future__ import annotations

import cv2
import numpy as np

from tectum import ClusterPacket, TrackPacket

from .tracks import track_colour

__all__ = ["ClusterOverlay", "as_tracks"]


def as_tracks(pkt: ClusterPacket) -> TrackPacket:
    """The clusters' centres as track rows (``quality`` = mass where given)."""
    extra = {"quality": pkt.data["mass"]} if "mass" in pkt.data else {}
    return TrackPacket(pkt.t, id=pkt["id"], x=pkt["x"], y=pkt["y"], t_start=pkt.t_start, t_end=pkt.t_end, **extra)


class ClusterOverlay:
    """The newest row of every cluster, drawn over an image (see the module doc)."""

    def __init__(self, hold_us: int = 30_000, lead_us: int = 50_000) -> None:
        if hold_us < 1 or lead_us < 0:
            raise ValueError(f"need hold_us >= 1 and lead_us >= 0, got {hold_us}, {lead_us}")
        self.hold_us, self.lead_us = int(hold_us), int(lead_us)
        self.rows: dict[int, list[tuple[int, float, float, float, float, float, float]]] = {}

    def add(self, pkt: ClusterPacket) -> None:
        """Take a packet of cluster rows (t µs, id, x, y, vx, vy, width, height)."""
        n = len(pkt)
        nan = np.full(n, np.nan)
        cols = [pkt.data.get(k, nan) for k in ("vx", "vy", "width", "height")]
        for t, i, x, y, vx, vy, w, h in zip(pkt.t.tolist(), pkt["id"].tolist(), pkt["x"].tolist(), pkt["y"].tolist(),
                                            *(c.tolist() for c in cols)):
            self.rows.setdefault(int(i), []).append((int(t), x, y, vx, vy, w, h))

    def draw(self, img: np.ndarray, now: int) -> np.ndarray:
        """Draw the clusters as of ``now`` µs onto ``img`` (BGR, in place); returns it."""
        for i in list(self.rows):
            rows = self.rows[i]
            while len(rows) > 1 and rows[1][0] <= now:  # keep the newest row at or before now
                rows.pop(0)
            t, x, y, vx, vy, w, h = rows[0]
            if t > now:
                continue
            if now - t > self.hold_us:
                del self.rows[i]
                continue
            colour = track_colour(i)
            w = w if np.isfinite(w) else 8.0
            h = h if np.isfinite(h) else 8.0
            p0 = (int(round((x - w / 2) * 4)), int(round((y - h / 2) * 4)))
            p1 = (int(round((x + w / 2) * 4)), int(round((y + h / 2) * 4)))
            cv2.rectangle(img, p0, p1, colour, 1, cv2.LINE_8, shift=2)
            if np.isfinite(vx) and np.isfinite(vy):
                lead = self.lead_us * 1e-6
                cv2.line(img, (int(round(x * 4)), int(round(y * 4))),
                         (int(round((x + vx * lead) * 4)), int(round((y + vy * lead) * 4))), colour, 1, cv2.LINE_8,
                         shift=2)
            cv2.putText(img, str(i), (int(x - w / 2), max(8, int(y - h / 2) - 2)), cv2.FONT_HERSHEY_PLAIN, 0.7,
                        colour, 1, cv2.LINE_AA)
        return img
