"""Ordering blob centroids as OpenCV's circle grid, and the board's object points.

The centroids are drawn as black disks on a white image (scaled so
neighbouring dots are about 24 px apart) and handed to
``cv2.findCirclesGrid``, which finds the grid's rows and columns (its
``CALIB_CB_CLUSTERING`` variant as a fallback for strongly distorted
views); each point it returns is then replaced by the exact centroid it was
drawn from. An order is accepted only when every grid point came from a
distinct centroid, the grid is smooth (along each row and each column,
the second difference of the points is under ``smooth`` of the step: a
mis-ordered point breaks this by a whole step) and no other dot sits where
the grid would go on beyond its border (a board larger than ``--grid``).

A symmetric grid looks the same turned by 180°: of its two orders the one
that starts nearer the image's top left (smaller ``u + v``) is returned, so
two cameras side by side order a board alike (stereo pairs). A board partly out of
view has fewer dots than the grid and is never ordered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Grid", "order_grid"]


@dataclass(frozen=True)
class Grid:
    """A circle grid: ``cols`` dots per row, ``rows`` rows, ``spacing`` m
    (OpenCV's convention: neighbours of a row of a symmetric grid; half the
    distance between neighbours of a row of an ``asymmetric`` one)."""

    cols: int
    rows: int
    spacing: float
    asymmetric: bool = False

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"grid: needs at least 2x2 dots, got {self.cols}x{self.rows}")
        if not self.spacing > 0:
            raise ValueError(f"grid: spacing must be > 0 m, got {self.spacing}")

    @property
    def size(self) -> int:
        """Dots on the board."""
        return self.cols * self.rows

    def object_points(self) -> np.ndarray:
        """Dot centres (rows*cols, 3) m on the board plane (z = 0), row by
        row, as OpenCV's samples define them."""
        i, j = np.divmod(np.arange(self.size), self.cols)
        xs = (2 * j + i % 2) * self.spacing if self.asymmetric else j * self.spacing
        return np.column_stack([xs, i * self.spacing, np.zeros(self.size)]).astype(np.float32)


def _draw(xy: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """White image with black disks at ``xy``; returns it, the scale and the offset."""
    import cv2

    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    np.fill_diagonal(d, np.inf)
    nn = float(np.median(d.min(axis=1)))
    scale = 24.0 / max(nn, 1e-3)
    lo = xy.min(axis=0) - 2 * nn
    size = np.ceil((xy.max(axis=0) - lo + 2 * nn) * scale).astype(int)
    if np.any(size > 8000):
        scale *= 8000 / size.max()
        size = np.ceil((xy.max(axis=0) - lo + 2 * nn) * scale).astype(int)
    img = np.full((int(size[1]), int(size[0])), 255, np.uint8)
    r = max(2, int(round(0.3 * nn * scale)))
    for u, v in (xy - lo) * scale:
        cv2.circle(img, (int(round(u * 16)), int(round(v * 16))), r * 16, 0, -1, cv2.LINE_AA, 4)
    return img, scale, lo


def _smooth(g: np.ndarray, smooth: float, asymmetric: bool) -> bool:
    """Second differences along rows and columns of the (rows, cols, 2) grid
    under ``smooth`` of the local step."""
    def ok(a: np.ndarray, axis: int, stride: int) -> bool:
        n = a.shape[axis]
        if n < 2 * stride + 1:
            return True
        s = [slice(None)] * 3
        def take(k0: int, k1: int) -> np.ndarray:
            s[axis] = slice(k0, k1, stride)
            return a[tuple(s)]
        p0, p1, p2 = take(0, n - 2 * stride), take(stride, n - stride), take(2 * stride, n)
        second = np.linalg.norm(p2 - 2 * p1 + p0, axis=2)
        step = np.minimum(np.linalg.norm(p1 - p0, axis=2), np.linalg.norm(p2 - p1, axis=2))
        return bool(np.all(second <= smooth * step))
    return ok(g, 1, 1) and ok(g, 0, 2 if asymmetric else 1)


def order_grid(xy: np.ndarray, grid: Grid, smooth: float = 0.35) -> np.ndarray | None:
    """The centroids ``xy`` (N, 2) px in OpenCV's circle-grid order
    (``grid.size`` points, row by row), or None when the whole grid is not
    found among them (see the module docstring)."""
    import cv2

    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if len(xy) < grid.size:
        return None
    img, scale, lo = _draw(xy)
    kind = cv2.CALIB_CB_ASYMMETRIC_GRID if grid.asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    for flags in (kind, kind | cv2.CALIB_CB_CLUSTERING):
        found, centres = cv2.findCirclesGrid(img, (grid.cols, grid.rows), None, flags)
        if not found or centres is None:
            continue
        pts = centres.reshape(-1, 2) / scale + lo
        d = np.linalg.norm(pts[:, None] - xy[None], axis=2)
        pick = np.argmin(d, axis=1)
        if len(np.unique(pick)) != grid.size or np.any(d[np.arange(len(pick)), pick] > 0.5):
            continue
        ordered = xy[pick]
        if not grid.asymmetric and ordered[0].sum() > ordered[-1].sum():
            ordered = ordered[::-1].copy()  # one of the two orders of a symmetric grid: first dot top left
        if _smooth(ordered.reshape(grid.rows, grid.cols, 2), smooth, grid.asymmetric) and not _extends(
                ordered, xy, grid):
            return ordered
    return None


def _extends(ordered: np.ndarray, xy: np.ndarray, grid: Grid) -> bool:
    """True when a dot of ``xy`` sits where the grid would go on, one row or
    column beyond its border (the board is larger than ``grid``: a sub-grid
    of it is no view of the board), by the grid's homography."""
    import cv2

    if len(xy) == len(ordered):
        return False
    obj = grid.object_points()[:, :2].astype(np.float64)
    Hm, _ = cv2.findHomography(obj, ordered, 0)
    if Hm is None:
        return True
    s = grid.spacing
    i, j = np.meshgrid(np.arange(-1, grid.rows + 1), np.arange(-1, grid.cols + 1), indexing="ij")
    border = (i < 0) | (i >= grid.rows) | (j < 0) | (j >= grid.cols)
    i, j = i[border], j[border]
    xs = (2 * j + i % 2) * s if grid.asymmetric else j * s
    cand = cv2.perspectiveTransform(np.column_stack([xs, i * s])[None].astype(np.float64), Hm)[0]
    d = np.linalg.norm(ordered[:, None] - ordered[None], axis=2)
    np.fill_diagonal(d, np.inf)
    step = float(np.median(d.min(axis=1)))
    return bool(np.any(np.linalg.norm(cand[:, None] - xy[None], axis=2) < 0.3 * step))
