"""Decoder of the DVXplorer's USB byte stream (FX3 + FPGA boards; the MIPI
CX3 "Mini" variant speaks another protocol and is not handled here).

16-bit little-endian words, as libcaer's public source describes them
(read, not copied). Bit 15 set: a timestamp (15 bits, on top of the wraps,
as DAVIS FX3). Otherwise a 3-bit code and 12 bits of data:

- 0 special: 1 timestamp reset, 2/3/4 external input, 5/7 IMU start/end,
  16/17 external generator (others reserved);
- 1 column address: x in bits 0-9, bit 11 marks the first column of a
  readout;
- 2 / 3 an 8-pixel group of group 2 / group 1: bits 0-7 say which of the 8
  pixels (y = group's first row + bit index) fired, bit 8 set = OFF;
- 4 group addresses: group 1 in bits 0-5 (x 8 rows), group 2 = group 1 ±
  bits 6-10 (minus when bit 11 is set);
- 5 misc 8-bit: code 0 IMU data bytes, code 3 IMU configuration (type in
  bits 5-7, accel range bits 3-4, gyro range bits 0-2);
- 7 timestamp wrap: data x 2^15 µs.

Every event gets the current timestamp. Time is reconstructed as for DAVIS
(64-bit, never wraps; a reset continues just past the last time). The IMU
(Bosch BMI160) sends accel Y, X, Z, temperature, gyro Y, X, Z (X and Y are
swapped by the chip's mounting), each axis optionally negated by the
device's IMU orientation flags; accel ±2/4/8/16 g, gyro ±2000..125 °/s,
temperature raw / 512 + 23 °C.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._decode import (
    _BAD,
    _CUR,
    _IMU_BAD,
    _IMU_ON,
    _LAST,
    _SPECIAL,
    _WRAP,
    _WRAPS,
    Decoded,
    _Base,
    _emit_time,
    _imu_byte,
    _imu_end,
    _imu_start,
    _imu_type,
    _reset,
)

__all__ = ["DvxDecoder", "dvx_kernel"]

# slots of our own (after the shared ones, clear of DAVIS's APS slots)
_LX, _LY1, _LY2, _SX, _SY, _INV, _IFLIP, _DUAL, _DFLIP, _ACC_SC, _GYR_SC, _SOF = range(60, 72)
_NSTATE = 72


@njit(cache=True)
def dvx_kernel(words: np.ndarray, state: np.ndarray, imu_cur: np.ndarray, t: np.ndarray, x: np.ndarray,
               y: np.ndarray, p: np.ndarray, imu_t: np.ndarray, imu_v: np.ndarray) -> tuple[int, int]:
    """Decode DVXplorer words; returns (events written, IMU samples
    written). ``t``.. need room for 8 events per word, ``imu_*`` for one
    sample per 16 words. ``imu_v`` rows: accel x, y, z (m/s²), temperature
    (°C), gyro x, y, z (rad/s)."""
    n = 0
    m = 0
    for i in range(words.shape[0]):
        w = np.int64(words[i])
        if w & 0x8000:
            state[_CUR] = state[_WRAP] + (w & 0x7FFF)
            continue
        code = (w >> 12) & 0x7
        data = w & 0x0FFF
        if code == 0:
            if data == 1:
                _reset(state)
            elif data == 5:
                _imu_start(state, imu_cur)
            elif data == 7:  # gyro range codes above 4 are not defined: such a sample is counted bad
                sc = min(state[_GYR_SC], 4)
                m = _imu_end(state, imu_cur, imu_t, imu_v, m, state[_GYR_SC] <= 4,
                             65536.0 / (4 * (1 << state[_ACC_SC])), 65536.0 / (250 * (1 << (4 - sc))), 512.0, 23.0)
            else:  # external input / generator, reserved: not events
                state[_SPECIAL] += 1
        elif code == 1:
            col = data & 0x03FF
            if data & 0x0800:
                state[_SOF] += 1
            if col >= state[_SX]:
                state[_BAD] += 1
            else:
                state[_LX] = col
        elif code == 2 or code == 3:
            ly = state[_LY1] if code == 3 else state[_LY2]
            pol = 1 if (data & 0x0100) == 0 else -1
            tt = np.int64(-1)
            for b in range(8):
                if (data >> b) & 1 == 0:
                    continue
                xa = state[_LX]
                ya = ly + b
                if ya >= state[_SY]:
                    state[_BAD] += 1
                    continue
                if state[_DUAL]:
                    if (state[_DFLIP] & 2) and xa >= state[_SX] // 2:
                        xa -= state[_SX] // 2
                    if (state[_DFLIP] & 1) and ya >= state[_SY] // 2:
                        ya -= state[_SY] // 2
                if tt < 0:
                    tt = _emit_time(state, state[_CUR])
                t[n] = tt
                if state[_INV]:
                    x[n] = ya
                    y[n] = xa
                else:
                    x[n] = xa
                    y[n] = ya
                p[n] = pol
                n += 1
        elif code == 4:
            g1 = data & 0x3F
            off = (data >> 6) & 0x1F
            g2 = g1 - off if data & 0x0800 else g1 + off
            if g1 * 8 >= state[_SY] or g2 < 0 or g2 * 8 >= state[_SY]:
                state[_BAD] += 1
            else:
                state[_LY1] = g1 * 8
                state[_LY2] = g2 * 8
        elif code == 5:
            mcode = (data >> 8) & 0xF
            mdata = data & 0xFF
            if mcode == 0:
                if state[_IMU_ON] != 1:
                    continue
                comp, raw = _imu_byte(state, mdata)
                if comp >= 0:
                    # accel Y, X, Z, temperature, gyro Y, X, Z -> slots ax ay az t gx gy gz
                    slot = (1, 0, 2, 3, 5, 4, 6)[comp]
                    axis = slot % 4  # 0 x, 1 y, 2 z (3: temperature, never flipped)
                    flip = state[_IFLIP]  # bits: 4 x, 2 y, 1 z
                    if axis < 3 and (flip >> (2 - axis)) & 1 and raw != -32768:
                        raw = -raw
                    imu_cur[slot] = raw
            elif mcode == 3:
                if state[_IMU_ON] != 1:
                    continue
                state[_ACC_SC] = (data >> 3) & 0x3
                state[_GYR_SC] = data & 0x7
                _imu_type(state, (data >> 5) & 0x7)
            else:
                state[_SPECIAL] += 1
        elif code == 7:
            state[_WRAPS] += 1
            state[_WRAP] += 0x8000 * data
            state[_CUR] = state[_WRAP]
        else:  # code 6: nothing in this protocol
            state[_SPECIAL] += 1
    return n, m


class DvxDecoder(_Base):
    """DVXplorer words (module docstring) -> events and IMU samples, in
    chunks of any size."""

    word = 2

    def __init__(self, sensor: tuple[int, int], invert_xy: bool = False, imu_flips: int = 0,
                 dual_binning: bool = False, dvs_flips: int = 0) -> None:
        """``sensor`` (width, height) as delivered; ``imu_flips`` the
        device's IMU orientation bits (4 x, 2 y, 1 z); ``dual_binning`` with
        ``dvs_flips`` (2 x, 1 y) folds addresses as libcaer does."""
        super().__init__()
        self.state = np.zeros(_NSTATE, np.int64)
        self.state[_LAST] = -1  # no time emitted yet
        self.sensor = sensor
        s = self.state
        w, h = sensor
        s[_SX], s[_SY] = (h, w) if invert_xy else (w, h)
        s[_INV], s[_IFLIP], s[_DUAL], s[_DFLIP] = int(invert_xy), imu_flips & 7, int(dual_binning), dvs_flips & 3
        self.imu_cur = np.zeros(7, np.float64)

    def feed(self, data: bytes | bytearray | memoryview) -> Decoded:
        words = self._take(data).view("<u2")
        k = words.shape[0]
        t = np.empty(8 * k, np.int64)
        x = np.empty(8 * k, np.uint16)
        y = np.empty(8 * k, np.uint16)
        p = np.empty(8 * k, np.int8)
        mi = k // 16 + 1
        it = np.empty(mi, np.int64)
        iv = np.empty((mi, 7), np.float64)
        n, m = dvx_kernel(words, self.state, self.imu_cur, t, x, y, p, it, iv)
        return Decoded(t[:n].copy(), x[:n].copy(), y[:n].copy(), p[:n].copy(), it[:m], iv[:m])

    @property
    def counts(self) -> dict[str, int]:
        c = super().counts
        c["imu_incomplete"] = int(self.state[_IMU_BAD])
        c["readouts"] = int(self.state[_SOF])
        return c
