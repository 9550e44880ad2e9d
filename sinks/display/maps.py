"""Pictures of maps (:class:`tectum.MapPacket`) for the display sinks.

* A log-intensity ``image``: grey, stretched between the 1st and 99th
  percentiles of its finite pixels (log intensity is known only up to an
  offset and a scale, so absolute levels mean nothing).
* A ``depth`` map (m): a colour map of inverse depth (near: warm, far:
  cool), stretched between the 2nd and 98th percentiles of its finite
  depths, with a legend bar on the right labelled in metres.

Pixels without a value (NaN) are drawn in a neutral colour the picture's
values never take: slate blue among grey levels (:data:`UNKNOWN_COLOUR`),
grey among the colour map's saturated colours (:data:`UNKNOWN_DEPTH_COLOUR`).
"""

from __future__ import annotations

import cv2
import numpy as np

from tectum import MapPacket

__all__ = ["UNKNOWN_COLOUR", "UNKNOWN_DEPTH_COLOUR", "intensity_picture", "depth_picture", "map_picture", "map_caption"]

#: BGR colour of log-intensity pixels without a value.
UNKNOWN_COLOUR = (120, 80, 60)
#: BGR colour of depth pixels without a value.
UNKNOWN_DEPTH_COLOUR = (72, 72, 72)
#: Width of the depth legend, px.
LEGEND_W = 64


def _stretch(values: np.ndarray, lo_pct: float, hi_pct: float) -> tuple[float, float]:
    lo, hi = (float(v) for v in np.percentile(values, [lo_pct, hi_pct]))
    if not hi > lo:
        hi = lo + 1e-6
    return lo, hi


def intensity_picture(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) BGR uint8 of a log-intensity image (H, W), NaN in :data:`UNKNOWN_COLOUR`."""
    img = np.asarray(image, np.float64)
    ok = np.isfinite(img)
    out = np.empty(img.shape + (3,), np.uint8)
    out[:] = UNKNOWN_COLOUR
    if ok.any():
        lo, hi = _stretch(img[ok], 1, 99)
        grey = np.round(np.clip((img[ok] - lo) / (hi - lo), 0.0, 1.0) * 255).astype(np.uint8)
        out[ok] = grey[:, None]
    return out


def depth_picture(depth: np.ndarray, legend: bool = True) -> np.ndarray:
    """(H, W [+ legend], 3) BGR uint8 of a depth map (H, W) in metres,
    NaN or non-positive in :data:`UNKNOWN_DEPTH_COLOUR`, with a legend bar."""
    d = np.asarray(depth, np.float64)
    ok = np.isfinite(d) & (d > 0)
    h, w = d.shape
    out = np.empty((h, w, 3), np.uint8)
    out[:] = UNKNOWN_DEPTH_COLOUR
    near, far = (0.5, 5.0)
    if ok.any():
        near, far = _stretch(d[ok], 2, 98)
    inv_lo, inv_hi = 1.0 / far, 1.0 / near
    if ok.any():
        s = np.clip((1.0 / d[ok] - inv_lo) / max(inv_hi - inv_lo, 1e-12), 0.0, 1.0)
        lut = _colours(np.round(s * 255).astype(np.uint8))
        out[ok] = lut
    if not legend:
        return out
    return np.hstack([out, _legend(h, near, far)])


def _colours(levels: np.ndarray) -> np.ndarray:
    """Colour-map entries (N, 3) BGR of levels (N,) uint8 (255 = near)."""
    return cv2.applyColorMap(levels.reshape(-1, 1), cv2.COLORMAP_TURBO).reshape(-1, 3)


def _legend(h: int, near: float, far: float) -> np.ndarray:
    """A vertical bar (near at the top) with the depths at its ends and middle, m."""
    bar = np.zeros((h, LEGEND_W, 3), np.uint8)
    bar[:] = (32, 32, 32)
    levels = np.round(np.linspace(255, 0, h)).astype(np.uint8)
    bar[:, 4:16] = _colours(levels)[:, None, :]
    scale = max(0.3, min(0.45, h / 400))
    mid = 2.0 / (1.0 / near + 1.0 / far)  # the bar is linear in inverse depth
    for frac, value in ((0.0, near), (0.5, mid), (1.0, far)):
        y = int(round(frac * (h - 1)))
        y = min(max(y + (10 if frac == 0.0 else 4 if frac == 0.5 else -2), 10), h - 2)
        cv2.putText(bar, f"{value:.3g} m", (19, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (230, 230, 230), 1,
                    cv2.LINE_AA)
    return bar


def map_picture(pkt: MapPacket, i: int = -1) -> np.ndarray:
    """The picture of sample ``i`` of a map packet: its depth when it has a
    finite one, else its log-intensity image."""
    if not len(pkt):
        raise ValueError("map_picture: the map packet has no sample")
    depth = pkt.data.get("depth")
    if depth is not None and np.isfinite(depth[i]).any():
        return depth_picture(depth[i])
    image = pkt.data.get("image")
    if image is not None:
        return intensity_picture(image[i])
    if depth is not None:
        return depth_picture(depth[i])
    raise ValueError("map_picture: the map packet has neither an image nor a depth field")


def map_caption(pkt: MapPacket, i: int = -1) -> str:
    """What :func:`map_picture` shows for sample ``i``, in one sentence."""
    depth = pkt.data.get("depth")
    h, w = map_picture_shape(pkt)
    if depth is not None and np.isfinite(depth[i]).any():
        return (f"Depth map ({w}x{h} px) at t = {int(pkt.t[i]) / 1e6:.3f} s: colour is inverse depth (warm: near, "
                "cool: far, legend in metres); grey: no depth.")
    return (f"Log-intensity map ({w}x{h} px) at t = {int(pkt.t[i]) / 1e6:.3f} s, grey levels stretched between its "
            "1st and 99th percentiles (only differences of log intensity are known); slate blue: never observed.")


def map_picture_shape(pkt: MapPacket) -> tuple[int, int]:
    """(height, width) of the packet's maps."""
    for name in ("depth", "image", "confidence"):
        a = pkt.data.get(name)
        if a is not None:
            return int(a.shape[1]), int(a.shape[2])
    return 0, 0
