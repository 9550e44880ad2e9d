"""The DVXplorer part of the emulated camera: its word encoder (written
from the protocol description, independently of :mod:`._dvx`) and its
chip's register file."""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

from . import _protocol as P

__all__ = ["DvxEmulation", "dvx_boot_config"]


def dvx_boot_config(model: str, sensor: tuple[int, int], imu_flips: int) -> dict[tuple[int, int], int]:
    """What a DVXplorer's FPGA reports before the host writes anything."""
    w, h = sensor
    return {(P.MOD_SYSINFO, P.SYSINFO_LOGIC_VERSION): 18, (P.MOD_SYSINFO, P.SYSINFO_LOGIC_PATCH): 2,
            (P.MOD_SYSINFO, P.SYSINFO_CHIP_ID): P.DVX_LITE_CHIP_ID if model == "dvxplorer_lite" else P.DVX_CHIP_ID,
            (P.MOD_SYSINFO, P.SYSINFO_IS_MASTER): 1, (P.MOD_SYSINFO, P.SYSINFO_LOGIC_CLOCK): 104,
            (P.MOD_SYSINFO, P.SYSINFO_USB_CLOCK): 80, (P.MOD_SYSINFO, P.SYSINFO_CLOCK_DEVIATION): 1000,
            (P.MOD_DVS, P.DVS_SIZE_COLUMNS): w, (P.MOD_DVS, P.DVS_SIZE_ROWS): h, (P.MOD_DVS, P.DVS_ORIENTATION): 0,
            (P.MOD_IMU, P.IMU_TYPE): 3, (P.MOD_IMU, P.DVX_IMU_ORIENTATION): imu_flips,
            (P.MOD_EXTINPUT, P.EXTINPUT_HAS_GENERATOR): 1,
            # chip registers at power-up (subsampling and area blocking bits start set = disabled)
            (P.DVX_DEVICE_DVS, P.R_DIGITAL_ENABLE): 0x06, (P.DVX_DEVICE_DVS, P.R_SUBSAMPLE_RATIO): 0x3F}


class DvxEmulation:
    """Mixed into :class:`~tectum.sources.usb.emulated.EmulatedCamera`."""

    config: dict[tuple[int, int], int]
    truth: Any
    imu_flips: int
    _last_ts: int | None
    _dev_origin: int

    def _davis_time(self, out: list[int], dev: int) -> None:  # provided by the camera
        raise NotImplementedError

    def dvx_streaming(self) -> bool:
        """The chip streams once the FPGA runs and the chip is in stream mode."""
        c = self.config
        return all(c.get(k, 0) for k in ((P.MOD_USB, P.USB_RUN), (P.MOD_MUX, P.MUX_RUN), (P.MOD_DVS, P.DVS_RUN))) \
            and c.get((P.DVX_DEVICE_DVS, P.R_CONTROL_MODE), 0) == P.DVX_MODE_STREAM

    def _encode_dvx(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, imu_times: list[int]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[int]]:
        """Words for these events (one readout per timestamp: columns in
        order, their 8-pixel groups paired as group 1 / group 2 when they
        are at most 31 groups apart) and IMU samples; returns the events in
        the order sent (duplicates merged) and the words."""
        out: list[int] = []
        tt: list[int] = []
        tx: list[int] = []
        ty: list[int] = []
        tp: list[int] = []
        ts = t.tolist()
        bounds = np.flatnonzero(np.diff(t)) + 1
        starts = [0] + bounds.tolist()
        ends = bounds.tolist() + [len(ts)]
        imu = list(imu_times)
        for a, b in zip(starts, ends):
            if a == b:
                continue
            while imu and imu[0] < ts[a]:
                self._dvx_imu(out, imu.pop(0))
            self._davis_time(out, ts[a] - self._dev_origin)
            groups: dict[int, dict[tuple[int, int], int]] = {}
            for xi, yi, pi in zip(x[a:b].tolist(), y[a:b].tolist(), p[a:b].tolist()):
                col = groups.setdefault(xi, {})
                key = (yi // 8, 1 if pi > 0 else -1)
                col[key] = col.get(key, 0) | (1 << (yi % 8))
            first = True
            for xi in sorted(groups):
                out.append(0x1000 | xi | (0x0800 if first else 0))
                first = False
                items = sorted(groups[xi].items())
                k = 0
                while k < len(items):
                    (g1, p1), m1 = items[k]
                    pair = None
                    if k + 1 < len(items) and abs(items[k + 1][0][0] - g1) <= 31:
                        pair = items[k + 1]
                    g2 = pair[0][0] if pair else g1
                    off = abs(g2 - g1)
                    out.append(0x4000 | g1 | (off << 6) | (0x0800 if g2 < g1 else 0))
                    for code, (g, pol), mask in [(0x3000, (g1, p1), m1)] + ([(0x2000, *pair)] if pair else []):
                        out.append(code | mask | (0 if pol > 0 else 0x0100))
                        for bit in range(8):
                            if mask >> bit & 1:
                                tt.append(ts[a])
                                tx.append(xi)
                                ty.append(g * 8 + bit)
                                tp.append(pol)
                    k += 2 if pair else 1
        for ti in imu:
            self._dvx_imu(out, ti)
        return (np.array(tt, np.int64), np.array(tx, np.uint16), np.array(ty, np.uint16), np.array(tp, np.int8),
                out)

    def _dvx_imu(self, out: list[int], t: int) -> None:
        """One BMI160 sample at pattern time ``t``: ±4 g (range 1) and
        ±500 °/s (range 2), sent Y, X, Z with the orientation flips."""
        self._davis_time(out, t - self._dev_origin)
        ph = t / 1e5
        acc = [int(6000 * np.sin(ph + k)) for k in range(3)]  # x, y, z
        gyr = [int(3000 * np.cos(ph + k)) for k in range(3)]
        temp = -1024  # 21 °C
        out += [0x0005, 0x5300 | (0b111 << 5) | (1 << 3) | 2]
        sent = []
        for v, axis in ((acc[1], 1), (acc[0], 0), (acc[2], 2), (temp, 3), (gyr[1], 1), (gyr[0], 0), (gyr[2], 2)):
            if axis < 3 and (self.imu_flips >> (2 - axis)) & 1:
                v = -v  # the device sends the flipped axis; the host flips it back
            sent.append(v)
        for v in sent:
            v &= 0xFFFF
            out += [0x5000 | (v >> 8), 0x5000 | (v & 0xFF)]
        out.append(0x0007)
        self.truth.imu_t.append(t)
        self.truth.accel.append(tuple(v / 8192 * 9.80665 for v in acc))
        self.truth.gyro.append(tuple(v / 65.536 * np.pi / 180 for v in gyr))
        self.truth.temperature.append(temp / 512 + 23)


def pack_words(words: list[int]) -> bytes:
    return struct.pack(f"<{len(words)}H", *words) if words else b""
