"""``filter.mask``: drop (or keep only) an explicit set of pixels."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tectum import EventPacket, Operator, same_sensor

from ._state import select
from .hot_pixel import mask_kernel

__all__ = ["Mask", "parse_pixels", "load_mask"]


def parse_pixels(text: str) -> list[tuple[int, int]]:
    """``"x,y;x,y"`` (also ``x:y`` or whitespace) into ``(x, y)`` pixels."""
    out = []
    for item in text.replace("\n", ";").split(";"):
        item = item.strip()
        if not item:
            continue
        parts = item.replace(":", ",").replace(" ", ",").split(",")
        parts = [q for q in parts if q]
        if len(parts) != 2:
            raise ValueError(f"pixel {item!r} is not 'x,y'")
        out.append((int(parts[0]), int(parts[1])))
    return out


def load_mask(path: str | Path, sensor: tuple[int, int]) -> np.ndarray:
    """A bool (H, W) mask from a file: ``.npy`` (any (H, W) array, non-zero =
    listed), an image (PNG...; non-zero = listed) or text lines ``x y``."""
    path = Path(path)
    w, h = sensor
    suffix = path.suffix.lower()
    if suffix == ".npy":
        arr = np.load(path) != 0
    elif suffix in (".png", ".bmp", ".pgm", ".tif", ".tiff", ".jpg"):
        import cv2

        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise ValueError(f"{path}: not a readable image")
        arr = img != 0
    else:
        arr = np.zeros((h, w), np.bool_)
        for x, y in parse_pixels(path.read_text()):
            _check(x, y, sensor, path)
            arr[y, x] = True
    if arr.shape != (h, w):
        raise ValueError(f"{path}: mask shape {arr.shape} is not the sensor's (H, W) = {(h, w)}")
    return np.ascontiguousarray(arr, np.bool_)


def _check(x: int, y: int, sensor: tuple[int, int], where: object) -> None:
    if not (0 <= x < sensor[0] and 0 <= y < sensor[1]):
        raise ValueError(f"{where}: pixel ({x}, {y}) is outside the sensor {sensor[0]}x{sensor[1]}")


class Mask(Operator):
    """Drop the events of listed pixels (or, with ``keep``, keep only them).

    Pixels come from ``pixels`` (``"x,y;x,y"``) and/or ``path`` (see
    :func:`load_mask`). State: one bool per pixel (W x H bytes).
    """

    name = "filter.mask"

    def __init__(self, pixels: str = "", path: str = "", keep: bool = False) -> None:
        self.pixels = parse_pixels(pixels)
        self.path = path
        self.keep = bool(keep)
        self.masked: np.ndarray | None = None
        self._sensor = (0, 0)  # (width, height) px that ``masked`` was made for

    def _build(self, sensor: tuple[int, int]) -> np.ndarray:
        w, h = sensor
        m = load_mask(self.path, sensor) if self.path else np.zeros((h, w), np.bool_)
        for x, y in self.pixels:
            _check(x, y, sensor, "filter.mask")
            m[y, x] = True
        return ~m if self.keep else m

    def memory_us(self) -> int:
        """Each event on its own: no memory (time sharding needs no warm-up)."""
        return 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.masked is None:
            self.masked = self._build(packet.sensor)
            self._sensor = packet.sensor
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        keep = np.empty(len(packet), np.bool_)
        mask_kernel(packet.x, packet.y, self.masked, keep)
        return [select(packet, keep)]
