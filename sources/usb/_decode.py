"""Decoders of the cameras' USB byte streams into events with int64 µs time.

Each decoder keeps its whole state in one int64 array (and one float array
for a half-read IMU sample) passed to a numba kernel, so a stream can be fed
in chunks of any size (a partial word is held back) and the result does not
depend on where the chunks were cut.

Time reconstruction: the device counts µs in 15 bits (DAVIS) or 14 bits
(DVS128) and sends wrap words. We add the wraps into a 64-bit counter, so
time never overflows (libcaer's 31-bit "big wrap" does not exist here). A
timestamp reset (device counter back to 0) moves a base offset to just past
the last emitted time, so the output stays non-decreasing across resets;
resets, wraps, out-of-order times (clamped) and bad addresses are counted.

APS frames (DAVIS) follow libcaer's readout: a frame start (global or
rolling shutter) opens a frame of the current ROI; per column, a reset read
and a signal read (column start / ADC samples / column end, in either
order); exposure start/end stamp the frame; at frame end each pixel is the
correlated double sample ``reset - signal`` (10 bits, clipped; a reset
under 384 or a signal of 0 means the pixel saw too much light: white),
given as 8 bits (``>> 2``, as DV's 8-bit frames). A frame whose column
counts are wrong is dropped and counted (``aps_bad_frames``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

__all__ = ["Dvs128Decoder", "DavisDecoder", "Decoded"]

# state slots shared by both kernels
_WRAP, _BASE, _LAST, _WRAPS, _RESETS, _NONMONO, _CUR, _BAD, _SPECIAL = 0, 1, 2, 3, 4, 5, 6, 7, 8
# DAVIS only
_LASTY, _IMU_ON, _IMU_N, _IMU_TYPE, _IMU_TMP, _ACC_SC, _GYR_SC, _SX, _SY, _INV, _IMU_BAD, _APS = (
    9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20)
# APS (DAVIS): frame in progress, its times, readout type, counts per readout
# type (column, row), ROI (start column/row, size), expected counts,
# ROI-update sequence, orientation flags (1 flipY, 2 flipX, 4 invertXY),
# DAVIS240 (samples x 2), frames made / dropped, full APS size
(_A_ON, _A_SOF, _A_SEXP, _A_EEXP, _A_TYPE, _A_CX0, _A_CX1, _A_CY0, _A_CY1, _A_POSX, _A_POSY, _A_SIZEX,
 _A_SIZEY, _A_EXPX, _A_EXPY, _A_ROITMP, _A_ROIUPD, _A_ORIENT, _A_IS240, _A_FRAMES, _A_BAD, _A_W, _A_H,
 _A_ENDX, _A_ENDY) = range(24, 49)
_NSTATE = 56
_NMETA = 8  # per frame: start, end, exposure start, exposure end, position x, y, size x, y
G = 9.80665


@njit(cache=True)
def _emit_time(state: np.ndarray, dev: np.int64) -> np.int64:
    t = state[_BASE] + dev
    if t < state[_LAST]:
        state[_NONMONO] += 1
        t = state[_LAST]
    state[_LAST] = t
    return t


@njit(cache=True)
def _reset(state: np.ndarray) -> None:
    state[_RESETS] += 1
    state[_WRAP] = 0
    state[_CUR] = 0
    state[_BASE] = state[_LAST] + 1 if state[_LAST] >= 0 else 0


@njit(cache=True)
def _imu_start(state: np.ndarray, imu_cur: np.ndarray) -> None:
    """IMU start mark: a new sample begins."""
    state[_IMU_ON] = 1
    state[_IMU_N] = 0
    state[_IMU_TYPE] = 0
    imu_cur[:] = 0.0


@njit(cache=True)
def _imu_end(state: np.ndarray, imu_cur: np.ndarray, imu_t: np.ndarray, imu_v: np.ndarray, m: int, ok: bool,
             acc_lsb: float, gyr_lsb: float, temp_lsb: float, temp_zero: float) -> int:
    """IMU end mark: the sample (when all 14 bytes came and ``ok``) into row
    ``m``, scaled by the LSB per g, per °/s and per °C above ``temp_zero``;
    an incomplete one is counted. Returns the rows written so far."""
    if state[_IMU_ON] != 1:
        return m
    if state[_IMU_N] != 14 or not ok:
        state[_IMU_BAD] += 1
        return m
    imu_t[m] = _emit_time(state, state[_CUR])
    for k in range(3):
        imu_v[m, k] = imu_cur[k] / acc_lsb * G
        imu_v[m, 4 + k] = imu_cur[4 + k] / gyr_lsb * np.pi / 180.0
    imu_v[m, 3] = imu_cur[3] / temp_lsb + temp_zero
    return m + 1


@njit(cache=True)
def _imu_skip(state: np.ndarray, c: np.int64) -> None:
    """After IMU byte ``c``: skip the counts of sensors not sent (type bits
    4 accel, 1 temperature, 2 gyro)."""
    typ = state[_IMU_TYPE]
    if c == 5 and not (typ & 0x01):
        state[_IMU_N] += 2 if (typ & 0x02) else 8
    elif c == 7 and not (typ & 0x02):
        state[_IMU_N] += 6


@njit(cache=True)
def _imu_byte(state: np.ndarray, mdata: np.int64) -> tuple[int, int]:
    """One IMU data byte (high byte first, then low): returns the sample
    component 0..6 (device order) and its int16 value once a pair is
    complete, else (-1, 0). Advances the byte count, skipping sensors not sent."""
    c = state[_IMU_N]
    state[_IMU_N] += 1
    if c % 2 == 0:
        state[_IMU_TMP] = mdata
        return -1, 0
    if c > 13:
        return -1, 0
    raw = (state[_IMU_TMP] << 8) | mdata
    if raw >= 0x8000:
        raw -= 0x10000
    _imu_skip(state, c)
    return (c - 1) // 2, raw


@njit(cache=True)
def _imu_type(state: np.ndarray, typ: np.int64) -> None:
    """An IMU configuration word: which sensors follow, hence the first count."""
    state[_IMU_TYPE] = typ
    if typ & 0x04:
        state[_IMU_N] = 0
    elif typ & 0x01:
        state[_IMU_N] = 6
    elif typ & 0x02:
        state[_IMU_N] = 8
    else:
        state[_IMU_N] = 14


@njit(cache=True)
def dvs128_kernel(buf: np.ndarray, state: np.ndarray, t: np.ndarray, x: np.ndarray, y: np.ndarray,
                  p: np.ndarray) -> int:
    """Decode whole 4-byte words of ``buf``; returns the number of events written."""
    n = 0
    for i in range(0, buf.shape[0] - 3, 4):
        b3 = buf[i + 3]
        if b3 & 0x80:  # wrap: +2^14 µs
            state[_WRAPS] += 1
            state[_WRAP] += 0x4000
            state[_CUR] = state[_WRAP]
        elif b3 & 0x40:  # timestamp reset
            _reset(state)
        else:
            addr = np.int64(buf[i]) | (np.int64(buf[i + 1]) << 8)
            ts = np.int64(buf[i + 2]) | (np.int64(b3) << 8)
            state[_CUR] = state[_WRAP] + ts
            tt = _emit_time(state, state[_CUR])
            if addr & 0x8000:  # external sync
                state[_SPECIAL] += 1
                continue
            t[n] = tt
            x[n] = 127 - ((addr >> 1) & 0x7F)
            y[n] = 127 - ((addr >> 8) & 0x7F)
            p[n] = 1 if (addr & 1) == 0 else -1
            n += 1
    return n


@njit(cache=True)
def _aps_roi_sizes(state: np.ndarray) -> None:
    """ROI start/end (as received) -> position and size, checked against
    the APS size (libcaer falls back to the full array / position 0)."""
    sx = state[_A_ENDX] + 1 - state[_A_POSX]
    sy = state[_A_ENDY] + 1 - state[_A_POSY]
    if sx <= 0 or sx > state[_A_W]:
        sx = state[_A_W]
    if sy <= 0 or sy > state[_A_H]:
        sy = state[_A_H]
    if state[_A_POSX] + sx > state[_A_W]:
        state[_A_POSX] = 0
    if state[_A_POSY] + sy > state[_A_H]:
        state[_A_POSY] = 0
    state[_A_SIZEX], state[_A_SIZEY] = sx, sy
    if state[_A_ORIENT] & 4:
        state[_A_EXPX], state[_A_EXPY] = sy, sx
    else:
        state[_A_EXPX], state[_A_EXPY] = sx, sy


@njit(cache=True)
def _aps_sample(state: np.ndarray, px: np.ndarray, data: np.int64) -> None:
    """One ADC sample into the frame: a reset read is stored, a signal read
    turns the pixel into its CDS value."""
    typ = state[_A_TYPE]
    cx = state[_A_CX1] if typ else state[_A_CX0]
    cy = state[_A_CY1] if typ else state[_A_CY0]
    if cx >= state[_A_EXPX] or cy >= state[_A_EXPY]:  # lost column marks: ignore, as libcaer
        return
    if state[_A_IS240]:
        data = data << 1
    xp = state[_A_EXPX] - 1 - cx if state[_A_ORIENT] & 2 else cx
    yp = state[_A_EXPY] - 1 - cy if state[_A_ORIENT] & 1 else cy
    if state[_A_ORIENT] & 4:
        xp, yp = yp, xp
    k = yp * state[_A_SIZEX] + xp
    if typ == 0:
        px[k] = data
    else:
        reset = px[k]
        if reset < 384 or data == 0:
            v = 1023
        else:
            v = min(max(reset - data, 0), 1023)
        px[k] = v
    if typ:
        state[_A_CY1] += 1
    else:
        state[_A_CY0] += 1


@njit(cache=True)
def davis_kernel(words: np.ndarray, start: int, state: np.ndarray, imu_cur: np.ndarray, t: np.ndarray,
                 x: np.ndarray, y: np.ndarray, p: np.ndarray, imu_t: np.ndarray, imu_v: np.ndarray,
                 aps_px: np.ndarray, fr_px: np.ndarray, fr_meta: np.ndarray) -> tuple[int, int, int, int]:
    """Decode 16-bit DAVIS words from index ``start``; returns (events
    written, IMU samples written, frames written, index where it stopped).
    It stops early once ``fr_px`` (frames, 8-bit pixels flattened) is full.

    ``imu_v`` rows: accel x, y, z (m/s²), temperature (°C), gyro x, y, z (rad/s).
    """
    n = 0
    m = 0
    f = 0
    i = start
    while i < words.shape[0]:
        if f == fr_px.shape[0]:
            break
        w = np.int64(words[i])
        i += 1
        if w & 0x8000:  # timestamp: 15 bits on top of the wraps
            state[_CUR] = state[_WRAP] + (w & 0x7FFF)
            continue
        code = (w >> 12) & 0x7
        data = w & 0x0FFF
        if code == 0:
            if data == 1:
                _reset(state)
            elif data == 2 or data == 3 or data == 4:
                state[_SPECIAL] += 1
            elif data == 5:  # IMU start
                _imu_start(state, imu_cur)
            elif data == 7:  # IMU end
                m = _imu_end(state, imu_cur, imu_t, imu_v, m, True, 65536.0 / (4 * (1 << state[_ACC_SC])),
                             65536.0 / (500 * (1 << state[_GYR_SC])), 340.0, 35.0)
            elif data == 8 or data == 9:  # APS frame start, global / rolling shutter
                state[_A_ON] = 1
                state[_A_SOF] = state[_BASE] + state[_CUR]
                state[_A_SEXP] = -1
                state[_A_EEXP] = -1
                state[_A_TYPE] = 0
                state[_A_CX0] = 0
                state[_A_CX1] = 0
                state[_A_CY0] = 0
                state[_A_CY1] = 0
                state[_A_ROIUPD] = 0
                npx = state[_A_SIZEX] * state[_A_SIZEY]
                aps_px[:npx] = 0
            elif state[_A_ON] != 1:
                if data >= 10 and data <= 15:
                    state[_APS] += 1  # a frame's marks without its start
                else:
                    state[_SPECIAL] += 1
            elif data == 10:  # APS frame end
                state[_A_ON] = 0
                if state[_A_CX0] != state[_A_EXPX] or state[_A_CX1] != state[_A_EXPX]:
                    state[_A_BAD] += 1
                    continue
                npx = state[_A_SIZEX] * state[_A_SIZEY]
                for k in range(npx):
                    fr_px[f, k] = np.uint8(aps_px[k] >> 2)
                fr_meta[f, 0] = state[_A_SOF]
                fr_meta[f, 1] = state[_BASE] + state[_CUR]
                fr_meta[f, 2] = state[_A_SEXP]
                fr_meta[f, 3] = state[_A_EEXP]
                fr_meta[f, 4] = state[_A_POSX]
                fr_meta[f, 5] = state[_A_POSY]
                fr_meta[f, 6] = state[_A_SIZEX]
                fr_meta[f, 7] = state[_A_SIZEY]
                f += 1
                state[_A_FRAMES] += 1
            elif data == 11 or data == 12:  # reset / signal column start
                typ = data - 11
                state[_A_TYPE] = typ
                if typ:
                    state[_A_CY1] = 0
                else:
                    state[_A_CY0] = 0
            elif data == 13:  # column end
                if state[_A_TYPE]:
                    state[_A_CX1] += 1
                else:
                    state[_A_CX0] += 1
            elif data == 14:
                state[_A_SEXP] = state[_BASE] + state[_CUR]
            elif data == 15:
                state[_A_EEXP] = state[_BASE] + state[_CUR]
            else:
                state[_SPECIAL] += 1
        elif code == 1:  # row address
            if data >= (state[_SX] if state[_INV] else state[_SY]):
                state[_BAD] += 1
            else:
                state[_LASTY] = data
        elif code == 2 or code == 3:  # column address with polarity (3: ON)
            if data >= (state[_SY] if state[_INV] else state[_SX]):
                state[_BAD] += 1
                continue
            t[n] = _emit_time(state, state[_CUR])
            if state[_INV]:
                x[n] = state[_LASTY]
                y[n] = data
            else:
                x[n] = data
                y[n] = state[_LASTY]
            p[n] = 1 if code == 3 else -1
            n += 1
        elif code == 4:  # APS ADC sample
            if state[_A_ON] == 1:
                _aps_sample(state, aps_px, data)
            else:
                state[_APS] += 1
        elif code == 5:
            mcode = (data >> 8) & 0xF
            mdata = data & 0xFF
            if mcode == 0:
                if state[_IMU_ON] != 1:
                    continue
                slot, raw = _imu_byte(state, mdata)  # slots 0..6: ax ay az temp gx gy gz
                if slot >= 0:
                    imu_cur[slot] = raw
            elif mcode == 3:
                if state[_IMU_ON] != 1:
                    continue
                state[_ACC_SC] = (mdata >> 2) & 0x3
                state[_GYR_SC] = mdata & 0x3
                _imu_type(state, (mdata >> 5) & 0x7)
            elif mcode == 1:  # APS ROI value, high byte
                state[_A_ROITMP] = mdata << 8
            elif mcode == 2:  # low byte: start column, start row, end column, end row in turn
                v = state[_A_ROITMP] | mdata
                u = state[_A_ROIUPD] & 3
                if u == 0:
                    state[_A_POSX] = v
                elif u == 1:
                    state[_A_POSY] = v
                elif u == 2:
                    state[_A_ENDX] = v
                else:
                    state[_A_ENDY] = v
                    _aps_roi_sizes(state)  # sent right after a frame's start, before its samples
                state[_A_ROIUPD] += 1
            else:
                state[_SPECIAL] += 1
        elif code == 6:  # misc 10 bits: the frame's exposure (not needed: the marks give it)
            pass
        else:  # code 7: timestamp wrap, data = how many 2^15 µs steps
            state[_WRAPS] += 1
            state[_WRAP] += 0x8000 * data
            state[_CUR] = state[_WRAP]
    return n, m, f, i


@dataclass
class Frame:
    """One APS frame: 8-bit image (rows, columns) of the ROI at
    ``position`` (x, y), its start/end of readout and exposure (µs; -1
    when the camera sent no exposure mark) and ``t``, mid-exposure (µs)."""

    image: np.ndarray
    start: int
    end: int
    exposure_start: int
    exposure_end: int
    position: tuple[int, int]

    @property
    def t(self) -> int:
        if 0 <= self.exposure_start <= self.exposure_end:
            return (self.exposure_start + self.exposure_end) // 2
        return self.start


@dataclass
class Decoded:
    """One chunk's output: events (t µs, x, y, p ±1), IMU samples
    (``imu_t`` µs, ``imu`` rows of accel m/s², temperature °C, gyro rad/s)
    and complete APS frames."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    p: np.ndarray
    imu_t: np.ndarray
    imu: np.ndarray
    frames: list[Frame] = field(default_factory=list)


_EMPTY_IMU = (np.empty(0, np.int64), np.empty((0, 7), np.float64))


class _Base:
    word = 1

    def __init__(self) -> None:
        self.state = np.zeros(_NSTATE, np.int64)
        self.state[_LAST] = -1
        self._rest = b""

    def _take(self, data: bytes | bytearray | memoryview) -> np.ndarray:
        raw = self._rest + bytes(data)
        cut = len(raw) - len(raw) % self.word
        self._rest = raw[cut:]
        return np.frombuffer(raw[:cut], np.uint8)

    @property
    def counts(self) -> dict[str, int]:
        """Counters: ``wraps``, ``resets``, ``nonmonotonic`` (clamped times),
        ``bad_address``, ``special`` (sync/trigger words skipped)."""
        s = self.state
        return {"wraps": int(s[_WRAPS]), "resets": int(s[_RESETS]), "nonmonotonic": int(s[_NONMONO]),
                "bad_address": int(s[_BAD]), "special": int(s[_SPECIAL])}

    @property
    def last_t(self) -> int:
        """The newest time emitted, µs (-1 before any)."""
        return int(self.state[_LAST])

    @property
    def device_now(self) -> int:
        """The newest time the device announced (µs, our time base): no later
        event can come before it."""
        return int(self.state[_BASE] + self.state[_CUR])

    def rebase(self) -> None:
        """The device restarted (reconnect): its clock restarts from 0, our
        output goes on from just past the last emitted time."""
        s = self.state
        s[_WRAP] = 0
        s[_CUR] = 0
        s[_BASE] = s[_LAST] + 1 if s[_LAST] >= 0 else 0
        self._rest = b""


class Dvs128Decoder(_Base):
    """DVS128 words: 16-bit address (bit 0 polarity, inverted; bits 1-7 x,
    bits 8-14 y, both mirrored; bit 15 sync) then 16-bit timestamp whose top
    bits flag a wrap (0x8000: +2^14 µs) or a reset (0x4000)."""

    word = 4
    sensor = (128, 128)

    def feed(self, data: bytes | bytearray | memoryview) -> Decoded:
        buf = self._take(data)
        k = buf.shape[0] // 4
        t = np.empty(k, np.int64)
        x = np.empty(k, np.uint16)
        y = np.empty(k, np.uint16)
        p = np.empty(k, np.int8)
        n = dvs128_kernel(buf, self.state, t, x, y, p)
        return Decoded(t[:n], x[:n], y[:n], p[:n], *_EMPTY_IMU)


class DavisDecoder(_Base):
    """DAVIS 16-bit words (little-endian): bit 15 set = timestamp (15 bits);
    else a 3-bit code and 12 bits of data: 0 special (1 = timestamp reset,
    5/7 IMU start/end, 8.. APS frame marks), 1 row, 2/3 column with polarity
    OFF/ON, 4 APS sample, 5 misc 8-bit (IMU bytes, IMU scale, APS ROI),
    6 misc 10-bit, 7 timestamp wrap (data x 2^15 µs)."""

    word = 2

    def __init__(self, sensor: tuple[int, int], invert_xy: bool = False, aps_size: tuple[int, int] | None = None,
                 aps_orientation: int = 0, davis240: bool = False) -> None:
        """``aps_size`` (columns, rows) of the frames (default: ``sensor``);
        ``aps_orientation`` the device's APS orientation bits (4 invert x/y,
        2 flip x, 1 flip y); ``davis240`` doubles ADC samples (its ADC
        reference range, as libcaer)."""
        super().__init__()
        self.sensor = sensor
        w, h = sensor
        s = self.state
        # the chip's own columns/rows (before a swap of x and y)
        s[_SX], s[_SY] = (h, w) if invert_xy else (w, h)
        s[_INV] = int(invert_xy)
        self.imu_cur = np.zeros(7, np.float64)
        aw, ah = aps_size or sensor
        s[_A_W], s[_A_H], s[_A_ORIENT], s[_A_IS240] = aw, ah, aps_orientation & 7, int(davis240)
        s[_A_POSX], s[_A_POSY], s[_A_ENDX], s[_A_ENDY] = 0, 0, aw - 1, ah - 1
        _aps_roi_sizes(s)
        self.aps_px = np.zeros(aw * ah, np.int64)
        self._fr_px = np.empty((2, aw * ah), np.uint8)
        self._fr_meta = np.empty((2, _NMETA), np.int64)

    def feed(self, data: bytes | bytearray | memoryview) -> Decoded:
        words = self._take(data).view("<u2")
        k = words.shape[0]
        t = np.empty(k, np.int64)
        x = np.empty(k, np.uint16)
        y = np.empty(k, np.uint16)
        p = np.empty(k, np.int8)
        mi = k // 8 + 1
        it = np.empty(mi, np.int64)
        iv = np.empty((mi, 7), np.float64)
        frames: list[Frame] = []
        n = m = i = 0
        while True:  # the kernel stops each time its frame buffer is full
            dn, dm, f, i = davis_kernel(words, i, self.state, self.imu_cur, t[n:], x[n:], y[n:], p[n:], it[m:],
                                        iv[m:], self.aps_px, self._fr_px, self._fr_meta)
            n, m = n + dn, m + dm
            for meta, px in zip(self._fr_meta[:f].tolist(), self._fr_px[:f]):
                sof, eof, sexp, eexp, posx, posy, sx, sy = meta
                frames.append(Frame(px[: sx * sy].reshape(sy, sx).copy(), sof, eof, sexp, eexp, (posx, posy)))
            if i >= k:
                break
        return Decoded(t[:n], x[:n], y[:n], p[:n], it[:m], iv[:m], frames)

    @property
    def frame_in_progress_since(self) -> int | None:
        """Start time (µs) of the APS frame being read out, if any: no
        later frame can have an earlier time."""
        s = self.state
        return int(s[_A_SOF]) if s[_A_ON] == 1 else None

    @property
    def counts(self) -> dict[str, int]:
        c = super().counts
        c["imu_incomplete"] = int(self.state[_IMU_BAD])
        c["aps_words_skipped"] = int(self.state[_APS])
        c["aps_frames"] = int(self.state[_A_FRAMES])
        c["aps_bad_frames"] = int(self.state[_A_BAD])
        return c
