"""``filter.undistort``: undistortion / rectification by per-pixel lookup."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numba import njit

from tectum import EventPacket, Operator, same_sensor
from tectum.camera import Camera, read_calibration

__all__ = ["Undistort", "undistort_lut", "packed_lut", "lut_kernel", "kept_index_kernel"]


def undistort_lut(camera: Camera, sensor: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel of a ``sensor`` (w, h) lands after undistortion (and
    rectification when ``camera.R`` is set), to the nearest pixel of the
    same-size output image projected with ``camera.P`` (else ``K``), from
    :meth:`Camera.undistort_maps <tectum.camera.Camera.undistort_maps>`.
    Returns ``(lut_x, lut_y)``, int32 (H, W), -1 where it lands outside (or
    where the lens model has no inverse)."""
    w, h = sensor
    mx, my = camera.undistort_maps(sensor)
    ux, uy = np.rint(mx), np.rint(my)
    ok = (ux >= 0) & (ux < w) & (uy >= 0) & (uy < h)  # false on NaN
    lut_x = np.where(ok, ux, -1).astype(np.int32)
    lut_y = np.where(ok, uy, -1).astype(np.int32)
    return lut_x, lut_y


def packed_lut(lut_x: np.ndarray, lut_y: np.ndarray) -> np.ndarray:
    """The two tables of :func:`undistort_lut` as one (H, W) int32 table,
    ``y << 16 | x`` of the landing pixel, -1 where it lands outside (one
    memory read per event instead of two). int64 when rows above 32767
    would not fit the sign bit."""
    dtype = np.int32 if lut_x.shape[0] <= 32768 else np.int64
    return np.where(lut_x >= 0, (lut_y.astype(np.int64) << 16) | lut_x, -1).astype(dtype)


_LUTS: dict[tuple[bytes, ...], np.ndarray] = {}
_LUTS_MAX = 8


def _cached_lut(camera: Camera, sensor: tuple[int, int]) -> np.ndarray:
    """The packed table of ``camera`` on ``sensor``, built once per
    calibration (a few small tables per process, read-only)."""
    key = tuple(a.tobytes() if a is not None else b"-" for a in (camera.params, camera.R, camera.P))
    key += (np.array(sensor, np.int64).tobytes(),)
    lut = _LUTS.get(key)
    if lut is None:
        lut = packed_lut(*undistort_lut(camera, sensor))
        lut.flags.writeable = False
        if len(_LUTS) >= _LUTS_MAX:
            _LUTS.pop(next(iter(_LUTS)))
        _LUTS[key] = lut
    return lut


@njit(cache=True, nogil=True)
def lut_kernel(t, x, y, p, lut, ot, ox, oy, op):  # type: ignore[no-untyped-def]
    """Map each event through the packed (H, W) int32 table (:func:`packed_lut`),
    dropping those where it holds -1: kept events go, compacted, to ``ot,
    ox, oy, op``. Returns the number kept; all kept when it equals the
    input length."""
    n = 0
    for i in range(x.shape[0]):
        v = lut[y[i], x[i]]
        ot[n] = t[i]
        ox[n] = v & 0xFFFF
        oy[n] = v >> 16
        op[n] = p[i]
        n += v >= 0
    return n


@njit(cache=True, nogil=True)
def kept_index_kernel(x, y, lut, idx):  # type: ignore[no-untyped-def]
    """Input indices of the events :func:`lut_kernel` keeps, into ``idx``;
    returns their number (for the extra columns)."""
    n = 0
    for i in range(x.shape[0]):
        idx[n] = i
        n += lut[y[i], x[i]] >= 0
    return n


class Undistort(Operator):
    """Undistort (and with a stereo calibration, rectify) event coordinates
    with the camera's lens model (OpenCV's radtan or equidistant/fisheye),
    through a per-pixel lookup table built once: each pixel moves to the
    nearest pixel of its undistorted position on a same-size image
    projected with ``P`` (rectified) or ``K``; events landing outside, or
    on pixels the model maps from no ray, are dropped.

    ``calib`` is a file read by :func:`tectum.camera.read_calibration`
    (OpenCV YAML/JSON, ROS ``camera_info``, UZH ``calib.txt``); ``side``
    picks a stereo camera; ``camera`` gives a :class:`tectum.camera.Camera`
    directly (Python use).

    State: one packed int32 table, 4 x W x H bytes (360 kB for 346x260),
    shared by the operators of the same calibration in a process.
    """

    name = "filter.undistort"
    #: For the batch-invariance check of every built-in (a 48x36 sensor, strong barrel distortion).
    conformance_params = {"camera": Camera(K=np.array([[40.0, 0, 24], [0, 40.0, 18], [0, 0, 1]]),
                                           D=np.array([-0.3, 0.1, 0, 0]))}

    def __init__(self, calib: str = "", side: Literal["mono", "left", "right"] = "mono",
                 camera: Camera | None = None) -> None:
        if camera is None:
            if not calib:
                raise ValueError("filter.undistort needs calib=PATH (or a Camera)")
            camera = read_calibration(calib, side)
        self.camera = camera
        self.lut: np.ndarray | None = None  # packed, see packed_lut
        self._sensor = (0, 0)  # (width, height) the table was made for

    def memory_us(self) -> int:
        """Each event on its own: no memory (time sharding needs no warm-up)."""
        return 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.lut is None:
            size = self.camera.size
            if size is not None and size != packet.sensor:
                raise ValueError(f"calibration is for a {size[0]}x{size[1]} sensor, events come from "
                                 f"{packet.sensor[0]}x{packet.sensor[1]}")
            self.lut = _cached_lut(self.camera, packet.sensor)
            self._sensor = packet.sensor
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        m = len(packet)
        ot, ox, oy = np.empty(m + 1, np.int64), np.empty(m + 1, np.uint16), np.empty(m + 1, np.uint16)
        op = np.empty(m + 1, np.int8)
        n = lut_kernel(packet.t, packet.x, packet.y, packet.p, self.lut, ot, ox, oy, op)
        cols = packet.columns
        if cols and n < m:
            idx = np.empty(m + 1, np.int64)
            kept_index_kernel(packet.x, packet.y, self.lut, idx)
            cols = {k: v[idx[:n]] for k, v in cols.items()}
        # the table only lands inside the sensor: a checked packet stays checked
        return [EventPacket._trusted(ot[:n], ox[:n], oy[:n], op[:n], packet.sensor, packet.t_start, packet.t_end,
                                     cols, packet.checked)]
