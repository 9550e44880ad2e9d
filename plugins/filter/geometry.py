"""Geometric filters: ``filter.roi`` (crop), ``filter.flip``,
``filter.rotate`` and ``filter.downsample``.

All are stateless (no memory beyond their outputs). Known flow columns
``vx``/``vy`` (px/s) are transformed with the pixels; other extra columns
are carried along unchanged.
"""

from __future__ import annotations

import math

import numpy as np

from tectum import EventPacket, Operator

from ._state import select

__all__ = ["Roi", "Flip", "Rotate", "Downsample", "remap"]


def remap(packet: EventPacket, x: np.ndarray, y: np.ndarray, sensor: tuple[int, int],
          keep: np.ndarray | None = None, vx: np.ndarray | None = None,
          vy: np.ndarray | None = None) -> EventPacket:
    """``packet`` with new coordinates ``x``, ``y`` (one per input event) on a
    sensor of ``sensor`` (w, h) pixels, keeping the events where ``keep``;
    ``vx``/``vy`` replace those columns when given."""
    cols = dict(packet.columns)
    if vx is not None:
        cols["vx"] = vx
    if vy is not None:
        cols["vy"] = vy
    t, p = packet.t, packet.p
    if keep is not None:
        t, p, x, y = t[keep], p[keep], x[keep], y[keep]
        cols = {k: v[keep] for k, v in cols.items()}
    return EventPacket(t, x.astype(np.uint16), y.astype(np.uint16), p, sensor=sensor,
                       t_start=packet.t_start, t_end=packet.t_end, columns=cols)


def _flow(packet: EventPacket) -> tuple[np.ndarray, np.ndarray] | None:
    if "vx" in packet.columns and "vy" in packet.columns:
        return packet.columns["vx"], packet.columns["vy"]
    return None


class Roi(Operator):
    """Region of interest: keep events with ``x0 <= x < x0 + width`` and
    ``y0 <= y < y0 + height`` (pixels; a size of 0 runs to the sensor's
    edge). With ``crop`` (default) coordinates shift by ``(-x0, -y0)`` and
    the sensor becomes the region's size. Stateless (no memory)."""

    name = "filter.roi"

    def __init__(self, x0: int = 0, y0: int = 0, width: int = 0, height: int = 0, crop: bool = True) -> None:
        if min(x0, y0, width, height) < 0:
            raise ValueError("x0, y0, width and height must be >= 0")
        self.x0, self.y0, self.width, self.height, self.crop = x0, y0, width, height, bool(crop)

    def region(self, sensor: tuple[int, int]) -> tuple[int, int, int, int]:
        """``(x0, y0, x1, y1)`` clipped to ``sensor``; raises when empty."""
        w, h = sensor
        x1 = w if self.width == 0 else min(w, self.x0 + self.width)
        y1 = h if self.height == 0 else min(h, self.y0 + self.height)
        if self.x0 >= x1 or self.y0 >= y1:
            raise ValueError(f"region of interest is empty on a {w}x{h} sensor")
        return self.x0, self.y0, x1, y1

    def memory_us(self) -> int:
        """Each event on its own: no memory (time sharding needs no warm-up)."""
        return 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        x0, y0, x1, y1 = self.region(packet.sensor)
        keep = (packet.x >= x0) & (packet.x < x1) & (packet.y >= y0) & (packet.y < y1)
        if not self.crop:
            return [select(packet, keep)]
        return [remap(packet, packet.x - np.uint16(x0), packet.y - np.uint16(y0), (x1 - x0, y1 - y0), keep)]


class Flip(Operator):
    """Mirror the image: ``horizontal`` maps x to W-1-x, ``vertical`` y to
    H-1-y (``vx``/``vy`` change sign accordingly). Stateless (no memory)."""

    name = "filter.flip"

    def __init__(self, horizontal: bool = True, vertical: bool = False) -> None:
        self.horizontal, self.vertical = bool(horizontal), bool(vertical)

    def memory_us(self) -> int:
        """Each event on its own: no memory (time sharding needs no warm-up)."""
        return 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        w, h = packet.sensor
        x = (w - 1 - packet.x.astype(np.int32)) if self.horizontal else packet.x
        y = (h - 1 - packet.y.astype(np.int32)) if self.vertical else packet.y
        flow = _flow(packet)
        vx = vy = None
        if flow is not None:
            vx = -flow[0] if self.horizontal else None
            vy = -flow[1] if self.vertical else None
        return [remap(packet, x, y, packet.sensor, None, vx, vy)]


class Rotate(Operator):
    """Rotate the image by ``degrees`` clockwise as displayed (y down).

    Multiples of 90° are exact (90° and 270° swap the sensor's width and
    height). Other angles rotate about the sensor's centre to the nearest
    pixel, keep the sensor size and drop events that land outside.
    Stateless (no memory).
    """

    name = "filter.rotate"

    def __init__(self, degrees: float = 90.0) -> None:
        self.degrees = float(degrees) % 360.0

    def memory_us(self) -> int:
        """Each event on its own: no memory (time sharding needs no warm-up)."""
        return 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        w, h = packet.sensor
        x = packet.x.astype(np.int64)
        y = packet.y.astype(np.int64)
        a = math.radians(self.degrees)
        c, s = math.cos(a), math.sin(a)
        quarter = self.degrees / 90.0
        keep = None
        if quarter == int(quarter):
            q = int(quarter) % 4
            c, s = ((1, 0), (0, 1), (-1, 0), (0, -1))[q]
            sensor = (w, h) if q % 2 == 0 else (h, w)
            nx = (x, h - 1 - y, w - 1 - x, y)[q]
            ny = (y, x, h - 1 - y, w - 1 - x)[q]
        else:
            sensor = (w, h)
            cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
            dx, dy = x - cx, y - cy
            nx = np.rint(c * dx - s * dy + cx).astype(np.int64)
            ny = np.rint(s * dx + c * dy + cy).astype(np.int64)
            keep = (nx >= 0) & (nx < w) & (ny >= 0) & (ny < h)
        flow = _flow(packet)
        vx = vy = None
        if flow is not None:
            vx = (c * flow[0] - s * flow[1]).astype(flow[0].dtype)
            vy = (s * flow[0] + c * flow[1]).astype(flow[1].dtype)
        return [remap(packet, nx, ny, sensor, keep, vx, vy)]


class Downsample(Operator):
    """Spatial downsampling by an integer ``factor``: pixel (x, y) becomes
    (x // factor, y // factor) on a sensor of ceil(W / factor) x
    ceil(H / factor); every event is kept (``vx``/``vy`` divide by the
    factor). Chain ``filter.refractory`` to thin the merged pixels.
    Stateless (no memory)."""

    name = "filter.downsample"

    def __init__(self, factor: int = 2) -> None:
        if factor < 1:
            raise ValueError("factor must be >= 1")
        self.factor = int(factor)

    def memory_us(self) -> int:
        """Each event on its own: no memory (time sharding needs no warm-up)."""
        return 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        f = self.factor
        w, h = packet.sensor
        flow = _flow(packet)
        vx = vy = None
        if flow is not None:
            vx, vy = (flow[0] / f).astype(flow[0].dtype), (flow[1] / f).astype(flow[1].dtype)
        sensor = (-(-w // f), -(-h // f))
        return [remap(packet, packet.x // np.uint16(f), packet.y // np.uint16(f), sensor, None, vx, vy)]
