"""``filter.undistort``: undistortion / rectification by per-pixel lookup."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numba import njit

from tectum import EventPacket, Operator

from .calibration import Camera, read_calibration

__all__ = ["Undistort", "undistort_lut", "lut_kernel"]


def undistort_lut(camera: Camera, sensor: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel of a ``sensor`` (w, h) lands after undistortion (and
    rectification when ``camera.R`` is set), to the nearest pixel of the
    same-size output image projected with ``camera.P`` (else ``K``).
    Returns ``(lut_x, lut_y)``, int32 (H, W), -1 where it lands outside."""
    import cv2

    w, h = sensor
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1).reshape(-1, 1, 2)
    P = camera.P if camera.P is not None else camera.K
    und = cv2.undistortPoints(pts, camera.K, camera.D if camera.D.size else None, R=camera.R, P=P)
    ux = np.rint(und[:, 0, 0]).reshape(h, w)
    uy = np.rint(und[:, 0, 1]).reshape(h, w)
    ok = np.isfinite(ux) & np.isfinite(uy) & (ux >= 0) & (ux < w) & (uy >= 0) & (uy < h)
    lut_x = np.where(ok, ux, -1).astype(np.int32)
    lut_y = np.where(ok, uy, -1).astype(np.int32)
    return lut_x, lut_y


@njit(cache=True, nogil=True)
def lut_kernel(t, x, y, p, lut_x, lut_y, ot, ox, oy, op, idx):  # type: ignore[no-untyped-def]
    """Map each event through the (H, W) int32 tables, dropping those where
    the table holds -1: kept events go, compacted, to ``ot, ox, oy, op``
    and their input index to ``idx``. Returns the number kept."""
    n = 0
    for i in range(x.shape[0]):
        nx = lut_x[y[i], x[i]]
        ot[n] = t[i]
        ox[n] = nx
        oy[n] = lut_y[y[i], x[i]]
        op[n] = p[i]
        idx[n] = i
        n += nx >= 0
    return n


class Undistort(Operator):
    """Undistort (and with a stereo calibration, rectify) event coordinates
    with the OpenCV camera model, through a per-pixel lookup table built
    once: each pixel moves to the nearest pixel of its undistorted position
    on a same-size image projected with ``P`` (rectified) or ``K``; events
    landing outside are dropped.

    ``calib`` is a file read by :func:`read_calibration` (OpenCV YAML/JSON,
    UZH ``calib.txt``); ``side`` picks a stereo camera; ``camera`` gives a
    :class:`Camera` directly (Python use).

    State: two int32 tables, 8 x W x H bytes (720 kB for 346x260).
    """

    name = "filter.undistort"
    #: For the batch-invariance check of every built-in (a 48x36 sensor, strong barrel distortion).
    conformance_params = {"camera": Camera(K=[[40.0, 0, 24], [0, 40.0, 18], [0, 0, 1]], D=[-0.3, 0.1, 0, 0])}

    def __init__(self, calib: str = "", side: Literal["mono", "left", "right"] = "mono",
                 camera: Camera | None = None) -> None:
        if camera is None:
            if not calib:
                raise ValueError("filter.undistort needs calib=PATH (or a Camera)")
            camera = read_calibration(calib, side)
        self.camera = camera
        self.lut: tuple[np.ndarray, np.ndarray] | None = None

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.lut is None:
            size = self.camera.size
            if size is not None and size != packet.sensor:
                raise ValueError(f"calibration is for a {size[0]}x{size[1]} sensor, events come from "
                                 f"{packet.sensor[0]}x{packet.sensor[1]}")
            self.lut = undistort_lut(self.camera, packet.sensor)
        m = len(packet)
        ot, ox, oy = np.empty(m + 1, np.int64), np.empty(m + 1, np.uint16), np.empty(m + 1, np.uint16)
        op, idx = np.empty(m + 1, np.int8), np.empty(m + 1, np.int64)
        n = lut_kernel(packet.t, packet.x, packet.y, packet.p, self.lut[0], self.lut[1], ot, ox, oy, op, idx)
        cols = {k: v[idx[:n]] for k, v in packet.columns.items()}
        return [EventPacket(ot[:n], ox[:n], oy[:n], op[:n], sensor=packet.sensor,
                            t_start=packet.t_start, t_end=packet.t_end, columns=cols)]
