"""An emulated iniVation camera behind a pyusb backend of ours.

:class:`EmulatedBackend` is a ``usb.backend.IBackend``: pyusb's real code
(``usb.core.find``, descriptors, ``ctrl_transfer``, ``read``) runs against
it exactly as against libusb. Behind it, :class:`EmulatedCamera` plays a
DVS128 or a DAVIS240/346: it enumerates with the right ids and string
descriptors, answers the vendor requests (biases, start/stop, DAVIS
configuration reads and writes, all logged in :attr:`EmulatedCamera.control_log`)
and, once started, streams the moving-bars pattern encoded in the camera's
own words, with timestamp wraps, an optional timestamp reset, IMU samples
and APS words (DAVIS), injected overruns and a disconnect.

The encoder here is written from the protocol description independently of
the decoder in :mod:`tectum.sources.usb._decode`, so a round trip tests both.
"""

from __future__ import annotations

import array
import errno
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import usb.backend
import usb.core

from tectum.sources.pattern import moving_bars

from . import _protocol as P
from ._emulated_dvx import DvxEmulation, dvx_boot_config, pack_words

__all__ = ["EmulatedCamera", "EmulatedBackend", "Truth", "emulated_backend"]

_SENSORS = {"dvs128": (128, 128), "davis240": (240, 180), "davis346": (346, 260), "dvxplorer": (640, 480),
            "dvxplorer_lite": (320, 240)}
_CHIPS = {"davis240": P.CHIP_DAVIS240C, "davis346": P.CHIP_DAVIS346B}


@dataclass
class Truth:
    """What the camera sent, in the camera's pattern time (µs from start):
    events and, for DAVIS, IMU samples (accel m/s², gyro rad/s)."""

    t: list[np.ndarray] = field(default_factory=list)
    x: list[np.ndarray] = field(default_factory=list)
    y: list[np.ndarray] = field(default_factory=list)
    p: list[np.ndarray] = field(default_factory=list)
    imu_t: list[int] = field(default_factory=list)
    accel: list[tuple[float, float, float]] = field(default_factory=list)
    gyro: list[tuple[float, float, float]] = field(default_factory=list)
    temperature: list[float] = field(default_factory=list)  # °C (DVXplorer)
    #: APS frames: (start of frame, exposure start, exposure end, end of
    #: frame) µs and the 8-bit image a host must show (rows, columns)
    frame_times: list[tuple[int, int, int, int]] = field(default_factory=list)
    frames: list[np.ndarray] = field(default_factory=list)

    def events(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        cat = [np.concatenate(a) if a else np.empty(0, np.int64) for a in (self.t, self.x, self.y, self.p)]
        return cat[0].astype(np.int64), cat[1].astype(np.uint16), cat[2].astype(np.uint16), cat[3].astype(np.int8)


class EmulatedCamera(DvxEmulation):
    """A camera of ``model`` ("dvs128", "davis240", "davis346", FX3 unless
    ``fx2``; "dvxplorer", "dvxplorer_lite") streaming ``duration_us`` µs of
    moving bars.

    DAVIS: ``filters`` says whether its logic has the DVS filters (pixel,
    background activity, ROI, skip, polarity) and the pulse generator.
    DVXplorer: ``imu_flips`` its IMU orientation bits (4 x, 2 y, 1 z);
    ``mipi`` plays the MIPI CX3 board (DVXplorer Mini), which we refuse.

    Faults: ``reset_at_us`` sends a timestamp reset there (the device clock
    restarts at 0); ``overrun_reads`` are bulk-read indices that fail with
    EOVERFLOW (the data stays queued: nothing is lost); ``disconnect_after``
    unplugs the camera once that many stream bytes were read (reads fail
    with ENODEV and it leaves the bus); ``replug_after_polls`` brings it back
    (as a fresh device whose clock starts at 0) after that many enumerations.
    ``max_transfer`` caps the bytes one bulk read returns (odd values split
    words). ``realtime`` releases data only once its time has come on the
    wall clock (for latency tests).
    """

    def __init__(self, model: str = "davis346", *, serial: str = "EMU00001", fx2: bool = False,
                 duration_us: int = 100_000, speed: float = 2000.0, noise_hz: float = 2.0, seed: int = 0,
                 window_us: int = 5_000, reset_at_us: int | None = None, overrun_reads: tuple[int, ...] = (),
                 disconnect_after: int | None = None, replug_after_polls: int | None = None,
                 max_transfer: int = 4096, imu_period_us: int = 1000, realtime: bool = False,
                 bus: int = 1, address: int = 5, aps_orientation: int = 0, adc_clock_mhz: int = 30,
                 imu_flips: int = 0, mipi: bool = False, filters: bool = True) -> None:
        if model not in _SENSORS:
            raise ValueError(f"unknown model {model!r}; known: {sorted(_SENSORS)}")
        self.model, self.serial, self.sensor = model, serial, _SENSORS[model]
        self.pid = P.DVS128_PID if model == "dvs128" else (P.DAVIS_FX2_PID if fx2 else P.DAVIS_FX3_PID)
        if model.startswith("dvxplorer"):
            self.pid = P.DVX_PID
        self.imu_flips, self.mipi, self.filters = imu_flips, mipi, filters
        self.endpoint = P.DVS128_ENDPOINT if model == "dvs128" else P.DAVIS_ENDPOINT
        self.duration_us, self.window_us = duration_us, window_us
        self.pattern: dict[str, Any] = dict(speed=speed, period_px=24, bar_px=8, noise_hz=noise_hz, jitter_us=20.0)
        self.seed, self.reset_at_us = seed, reset_at_us
        self.overrun_reads = set(overrun_reads)
        self.disconnect_after, self.replug_after_polls = disconnect_after, replug_after_polls
        self.max_transfer, self.imu_period_us, self.realtime = max_transfer, imu_period_us, realtime
        self.bus, self.address = bus, address
        self.aps_orientation, self.adc_clock_mhz = aps_orientation, adc_clock_mhz
        self.control_log: list[tuple[int, int, int, int, bytes]] = []
        self.register_log: list[tuple[int, int]] = []  # DVXplorer chip register writes, in order
        self.config: dict[tuple[int, int], int] = {}
        self.biases = b""
        self.truth = Truth()
        self.attached = True
        self.replugged_at: int | None = None
        self.reads = 0
        self.sent = 0  # stream bytes handed to the host
        self._polls_while_gone = 0
        self._lock = threading.Lock()
        self._boot()

    # -- device life --------------------------------------------------------
    def _boot(self) -> None:
        self.streaming = False
        self._buf = bytearray()
        self._due: list[tuple[int, int]] = []  # (end offset in _buf, pattern time µs) for realtime
        self._gen_t = 0  # pattern time generated so far
        self._rng = np.random.default_rng(self.seed)
        self._dev_origin = 0  # pattern time at which the device clock was 0
        self._wrap = 0  # device-side wrap counter (µs)
        self._last_ts: int | None = None
        self._last_y: int | None = None
        self._reset_sent = False
        self._next_imu = 0
        self._next_frame: int | None = None
        self._frame_ends: list[int] = []
        self._pending_frame: tuple[int, int, np.ndarray, np.ndarray] | None = None
        self._wall0 = 0.0
        if self.model.startswith("dvxplorer"):
            self.config.update(dvx_boot_config(self.model, self.sensor, self.imu_flips))
        elif self.model != "dvs128":
            w, h = self.sensor
            has = int(self.filters)
            self.config.update({(P.MOD_SYSINFO, P.SYSINFO_LOGIC_CLOCK): 104, (P.MOD_SYSINFO, P.SYSINFO_USB_CLOCK): 80,
                                (P.MOD_SYSINFO, P.SYSINFO_CLOCK_DEVIATION): 1005,
                                (P.MOD_DVS, P.DVS_HAS_PIXEL_FILTER): has, (P.MOD_DVS, P.DVS_HAS_BA_FILTER): has,
                                (P.MOD_DVS, P.DVS_HAS_ROI_FILTER): has, (P.MOD_DVS, P.DVS_HAS_SKIP_FILTER): has,
                                (P.MOD_DVS, P.DVS_HAS_POLARITY_FILTER): has,
                                (P.MOD_EXTINPUT, P.EXTINPUT_HAS_GENERATOR): has})
            self.config.update({(P.MOD_SYSINFO, P.SYSINFO_LOGIC_VERSION): 18,
                                (P.MOD_SYSINFO, P.SYSINFO_CHIP_ID): _CHIPS[self.model],
                                (P.MOD_SYSINFO, P.SYSINFO_LOGIC_PATCH): 1,
                                (P.MOD_SYSINFO, P.SYSINFO_IS_MASTER): 1,
                                (P.MOD_DVS, P.DVS_SIZE_COLUMNS): w, (P.MOD_DVS, P.DVS_SIZE_ROWS): h,
                                (P.MOD_DVS, P.DVS_ORIENTATION): 0,
                                # the chip's columns and rows (swapped when its readout is x/y-swapped)
                                (P.MOD_APS, P.APS_SIZE_COLUMNS): h if self.aps_orientation & 4 else w,
                                (P.MOD_APS, P.APS_SIZE_ROWS): w if self.aps_orientation & 4 else h,
                                (P.MOD_APS, P.APS_ORIENTATION): self.aps_orientation,
                                (P.MOD_APS, P.APS_HAS_GLOBAL_SHUTTER): 1,
                                (P.MOD_SYSINFO, P.SYSINFO_ADC_CLOCK): self.adc_clock_mhz,
                                (P.MOD_IMU, P.IMU_TYPE): 1})

    def unplug(self) -> None:
        with self._lock:
            self.attached = False
            self._polls_while_gone = 0

    def poll(self) -> bool:
        """One enumeration: is the camera on the bus? (may replug it)."""
        with self._lock:
            if not self.attached and self.replug_after_polls is not None:
                self._polls_while_gone += 1
                if self._polls_while_gone >= self.replug_after_polls:
                    self.attached = True
                    self.disconnect_after = None
                    self._boot_keep_time()
            return self.attached

    def _boot_keep_time(self) -> None:
        """A replugged camera: fresh clock, the pattern goes on where it was."""
        gen = self._gen_t
        self.replugged_at = gen  # what the camera held unsent at the unplug is lost, as on hardware
        self._boot()
        self._gen_t = gen
        self._dev_origin = gen
        self._next_imu = gen
        self._reset_sent = True

    # -- control transfers -------------------------------------------------
    def control(self, rtype: int, req: int, value: int, index: int, data: bytes, length: int) -> bytes | int:
        if not self.attached:
            raise usb.core.USBError("No such device (it may have been disconnected)", -4, errno.ENODEV)
        self.control_log.append((rtype, req, value, index, bytes(data)))
        if rtype == 0x80 and req == 6:  # GET_DESCRIPTOR (strings)
            return self._string(value & 0xFF)[:length]
        if self.model == "dvs128":
            if req == P.DVS128_REQ_START:
                self._start()
            elif req == P.DVS128_REQ_STOP:
                self.streaming = False
            elif req == P.DVS128_REQ_BIASES:
                self.biases = bytes(data)
            elif req == P.DVS128_REQ_RESET_TS:
                pass
            else:
                raise usb.core.USBError("Pipe error", -9, errno.EPIPE)
            return len(data)
        if req != P.REQ_CONFIG:
            raise usb.core.USBError("Pipe error", -9, errno.EPIPE)
        if rtype & 0x80:
            return struct.pack(">I", self.config.get((value, index), 0))[:length]
        self.config[(value, index)] = struct.unpack(">I", bytes(data))[0]
        if value == P.DVX_DEVICE_DVS and self.model.startswith("dvxplorer"):
            self.register_log.append((index, self.config[(value, index)]))
            if index == P.R_TS_RESET and self.config[(value, index)] == 0 and self._gen_t > 0:
                self._words_reset()  # the chip's timestamp counter restarts
                self._dev_origin, self._wrap, self._last_ts = self._gen_t, 0, None
        if self.model.startswith("dvxplorer"):
            running = self.dvx_streaming()
        else:
            running = all(self.config.get(k, 0) for k in ((P.MOD_USB, P.USB_RUN), (P.MOD_MUX, P.MUX_RUN),
                                                           (P.MOD_DVS, P.DVS_RUN)))
        if running and not self.streaming:
            self._start()
        elif not running:
            self.streaming = False
        return len(data)

    def _string(self, index: int) -> bytes:
        if index == 0:
            return bytes([4, 3, 0x09, 0x04])
        s = {1: "iniVation (emulated)", 2: self.model.upper(), 3: self.serial}.get(index, "")
        b = s.encode("utf-16-le")
        return bytes([len(b) + 2, 3]) + b

    def _start(self) -> None:
        self.streaming = True
        self._wall0 = time.monotonic() - self._gen_t / 1e6

    # -- the stream ---------------------------------------------------------
    def read(self, size: int, timeout_ms: int) -> bytes:
        with self._lock:
            if not self.attached:
                raise usb.core.USBError("No such device (it may have been disconnected)", -4, errno.ENODEV)
            k = self.reads
            self.reads += 1
            if k in self.overrun_reads:
                raise usb.core.USBError("Overflow", -8, errno.EOVERFLOW)
            if not self.streaming:
                raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
            if self.disconnect_after is not None and self.sent >= self.disconnect_after:
                self.attached = False
                self._polls_while_gone = 0
                raise usb.core.USBError("No such device (it may have been disconnected)", -4, errno.ENODEV)
            limit = min(size, self.max_transfer)
            if self.disconnect_after is not None:
                limit = min(limit, self.disconnect_after - self.sent)
            while len(self._buf) < limit and self._gen_t < self.duration_us:
                self._generate()
            n = min(limit, len(self._buf))
            if self.realtime:
                n = min(n, self._due_bytes())
        if n == 0:
            time.sleep(min(timeout_ms, 2) / 1e3)
            raise usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)
        with self._lock:
            out = bytes(self._buf[:n])
            del self._buf[:n]
            self._due = [(e - n, t) for e, t in self._due if e - n > 0]
            self.sent += n
        return out

    def _due_bytes(self) -> int:
        now_us = (time.monotonic() - self._wall0) * 1e6
        ready = 0
        for end, t in self._due:
            if t <= now_us:
                ready = end
            else:
                break
        return ready

    def _generate(self) -> None:
        t0 = self._gen_t
        t1 = min(t0 + self.window_us, self.duration_us)
        if self.reset_at_us is not None and not self._reset_sent and t0 <= self.reset_at_us < t1:
            t1 = self.reset_at_us
        if t1 > t0:
            pk = moving_bars(t0, t1, sensor=self.sensor, rng=self._rng, **self.pattern)
            sent = self._encode(pk.t, pk.x, pk.y, pk.p, t1)
            tt, tx, ty, tp = sent if sent is not None else (pk.t.copy(), pk.x.copy(), pk.y.copy(), pk.p.copy())
            tr = self.truth
            tr.t.append(tt), tr.x.append(tx), tr.y.append(ty), tr.p.append(tp)
        self._gen_t = t1
        if self.reset_at_us is not None and not self._reset_sent and t1 == self.reset_at_us:
            self._reset_sent = True
            self._words_reset()
            self._dev_origin = t1
            self._wrap = 0
            self._last_ts = None
        self._due.append((len(self._buf), t1))

    # per-model word writers
    def _encode(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, t_end: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Append the words; returns the events in the order sent when that
        differs from the input's (DVXplorer)."""
        if self.model.startswith("dvxplorer"):
            imu_times = list(range(self._next_imu, t_end, self.imu_period_us)) if self.imu_period_us else []
            if imu_times:
                self._next_imu = imu_times[-1] + self.imu_period_us
            tt, tx, ty, tp, words = self._encode_dvx(t, x, y, p, imu_times)
            self._buf += pack_words(words)
            return tt, tx, ty, tp
        if self.model == "dvs128":
            self._encode_dvs128(t, x, y, p)
        else:
            self._encode_davis(t, x, y, p, t_end)
        return None

    def _words_reset(self) -> None:
        self._buf += b"\x00\x00\x00\x40" if self.model == "dvs128" else struct.pack("<H", 0x0001)

    def _encode_dvs128(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> None:
        out = bytearray()
        for ti, xi, yi, pi in zip(t.tolist(), x.tolist(), y.tolist(), p.tolist()):
            dev = ti - self._dev_origin
            while dev - self._wrap >= 0x4000:
                self._wrap += 0x4000
                out += b"\x00\x00\x00\x80"
            addr = ((127 - yi) << 8) | ((127 - xi) << 1) | (0 if pi > 0 else 1)
            out += struct.pack("<HH", addr, dev - self._wrap)
        self._buf += out

    def _davis_time(self, out: list[int], dev: int) -> None:
        steps = (dev - self._wrap) >> 15
        while steps > 0:
            k = min(steps, 0xFFF)
            out.append(0x7000 | k)
            self._wrap += k << 15
            steps -= k
            self._last_ts = None
        if dev != self._last_ts:
            out.append(0x8000 | (dev - self._wrap))
            self._last_ts = dev

    def _encode_davis(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, t_end: int) -> None:
        out: list[int] = []
        imu_times = list(range(self._next_imu, t_end, self.imu_period_us)) if self.imu_period_us else []
        if imu_times:
            self._next_imu = imu_times[-1] + self.imu_period_us
        marks = [(ti, 1, 0) for ti in imu_times] + self._frame_marks(t_end)
        marks.sort()
        ts, j = t.tolist(), 0
        for mark in marks + [None]:
            stop = len(ts) if mark is None else int(np.searchsorted(t, mark[0], side="left"))
            for i in range(j, stop):
                self._davis_time(out, ts[i] - self._dev_origin)
                yi = int(y[i])
                if yi != self._last_y:
                    out.append(0x1000 | yi)
                    self._last_y = yi
                out.append((0x3000 if p[i] > 0 else 0x2000) | int(x[i]))
            j = stop
            if mark is None:
                continue
            if mark[1] == 1:
                self._imu_words(out, mark[0])
            else:
                self._frame_words(out, mark[0], mark[2])
        self._buf += array.array("H", out).tobytes() if out else b""

    # -- APS frames ---------------------------------------------------------
    def _aps_timing(self) -> tuple[int, int] | None:
        """(exposure, interval) µs from the host's configuration, when the
        APS runs."""
        c = self.config
        if not c.get((P.MOD_APS, P.APS_RUN), 0):
            return None
        clock = max(1, self.adc_clock_mhz)
        exp = c.get((P.MOD_APS, P.APS_EXPOSURE), P.APS_DEFAULT_EXPOSURE_US * clock) // clock
        interval = c.get((P.MOD_APS, P.APS_FRAME_INTERVAL), P.APS_DEFAULT_INTERVAL_US * clock) // clock
        return max(1, exp), max(exp + 1, interval)

    def _frame_marks(self, t_end: int) -> list[tuple[int, int, int]]:
        """(time, 2, 0) frame start+exposure start and (time, 2, 1)
        exposure end + readout + frame end marks due before ``t_end``."""
        timing = self._aps_timing()
        if timing is None:
            return []
        exp, interval = timing
        if self._next_frame is None:
            self._next_frame = self._gen_t + 500
        marks = []
        while self._next_frame < t_end:
            marks.append((self._next_frame, 2, 0))
            self._frame_ends.append(self._next_frame + exp)
            self._next_frame += interval
        while self._frame_ends and self._frame_ends[0] < t_end:
            marks.append((self._frame_ends.pop(0), 2, 1))
        return marks

    def _frame_words(self, out: list[int], t: int, end: int) -> None:
        self._davis_time(out, t - self._dev_origin)
        if not end:  # global shutter frame start, exposure start; the reset read comes first
            out += [0x0008, 0x000E]
            w, h = self.sensor
            yy, xx = np.mgrid[0:h, 0:w]
            img10 = ((xx * 3 + yy * 2 + t // 500) % 400) * 2  # the scene: even 10-bit CDS values
            reset = (self._rng.integers(400, 500, (h, w)) * 2).astype(np.int64)
            signal = reset - img10
            signal[5, 7] = 0  # too much light: the signal read hits 0 (white)
            reset[6, 9], signal[6, 9] = 300, 100  # reset read under 384 (white)
            img10[5, 7] = img10[6, 9] = 1023
            self._pending_frame = (t, 0, reset, signal)
            self._aps_read(out, reset, 0xB)
            self.truth.frames.append((img10 >> 2).astype(np.uint8))
            return
        assert self._pending_frame is not None
        t0, _, reset, signal = self._pending_frame
        self._pending_frame = None
        out.append(0x000F)  # exposure end, then the signal read and the frame end
        self._aps_read(out, signal, 0xC)
        out.append(0x000A)
        self.truth.frame_times.append((t0, t0, t, t))

    def _aps_read(self, out: list[int], img: np.ndarray, column_start: int) -> None:
        """One readout (reset or signal) of the image, column by column in
        the device's orientation (bits: 4 x/y swapped, 2 x flipped, 1 y flipped)."""
        o = self.aps_orientation
        a = img.T if o & 4 else img  # a[row count, column count] once swapped
        if o & 2:
            a = a[:, ::-1]
        if o & 1:
            a = a[::-1, :]
        vals = (a >> 1) if self.model == "davis240" else a  # its ADC range: the host doubles samples
        cols = np.empty((a.shape[1], a.shape[0] + 2), np.int64)
        cols[:, 0] = column_start
        cols[:, 1:-1] = 0x4000 | vals.T
        cols[:, -1] = 0x000D
        out += cols.ravel().tolist()

    def _imu_words(self, out: list[int], t: int) -> None:
        """One IMU sample at pattern time ``t``: accel (±2 g, scale 0) and gyro
        (±250 °/s, scale 0) as slow sines, plus a few APS words now and then."""
        self._davis_time(out, t - self._dev_origin)
        ph = t / 1e5
        acc_raw = [int(8192 * np.sin(ph + k)) for k in range(3)]
        gyr_raw = [int(3000 * np.cos(ph + k)) for k in range(3)]
        temp_raw = 1000
        out.append(0x0005)
        out.append(0x5300 | (0b111 << 5))  # accel+gyro+temp, both scales 0
        for v in acc_raw + [temp_raw] + gyr_raw:
            v &= 0xFFFF
            out += [0x5000 | (v >> 8), 0x5000 | (v & 0xFF)]
        out.append(0x0007)
        self.truth.imu_t.append(t)
        self.truth.accel.append(tuple(v * 4 / 65536 * 9.80665 for v in acc_raw))
        self.truth.gyro.append(tuple(v * 500 / 65536 * np.pi / 180 for v in gyr_raw))
        if (t // self.imu_period_us) % 10 == 0 and self._aps_timing() is None:
            out += [0x000B, 0x4123, 0x4456, 0x000D, 0x000A]  # stray APS words (no frame start): skipped


# -- the pyusb backend ------------------------------------------------------
class _Desc:
    def __init__(self, **kw: Any) -> None:
        self.__dict__.update(kw)
        self.extra_descriptors: list[Any] = []


class EmulatedBackend(usb.backend.IBackend):
    """A pyusb backend whose bus holds the given emulated cameras."""

    def __init__(self, *cameras: EmulatedCamera) -> None:
        super().__init__()
        self.cameras = list(cameras)

    def enumerate_devices(self):  # type: ignore[no-untyped-def]
        for cam in self.cameras:
            if cam.poll():
                yield cam

    def get_device_descriptor(self, dev: EmulatedCamera) -> _Desc:
        fw = 14 if dev.model == "dvs128" else (4 if dev.pid == P.DAVIS_FX2_PID else 6)
        if dev.pid == P.DVX_PID:
            fw = 8 | ((P.DVX_DEVICE_MIPI if dev.mipi else 1) << 8)
        return _Desc(bLength=18, bDescriptorType=1, bcdUSB=0x0300 if dev.pid == P.DAVIS_FX3_PID else 0x0200,
                     bDeviceClass=0, bDeviceSubClass=0, bDeviceProtocol=0, bMaxPacketSize0=64,
                     idVendor=P.VID, idProduct=dev.pid, bcdDevice=fw, iManufacturer=1, iProduct=2,
                     iSerialNumber=3, bNumConfigurations=1, address=dev.address, bus=dev.bus,
                     port_number=1, port_numbers=(1,), speed=None)

    def get_configuration_descriptor(self, dev: EmulatedCamera, config: int) -> _Desc:
        return _Desc(bLength=9, bDescriptorType=2, wTotalLength=25, bNumInterfaces=1, bConfigurationValue=1,
                     iConfiguration=0, bmAttributes=0x80, bMaxPower=250)

    def get_interface_descriptor(self, dev: EmulatedCamera, intf: int, alt: int, config: int) -> _Desc:
        if intf != 0 or alt != 0:
            raise IndexError("no such interface")
        return _Desc(bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0, bNumEndpoints=1,
                     bInterfaceClass=0xFF, bInterfaceSubClass=0, bInterfaceProtocol=0, iInterface=0)

    def get_endpoint_descriptor(self, dev: EmulatedCamera, ep: int, intf: int, alt: int, config: int) -> _Desc:
        if ep != 0:
            raise IndexError("no such endpoint")
        return _Desc(bLength=7, bDescriptorType=5, bEndpointAddress=dev.endpoint, bmAttributes=2,
                     wMaxPacketSize=1024 if dev.pid == P.DAVIS_FX3_PID else 512, bInterval=0, bRefresh=0,
                     bSynchAddress=0)

    def open_device(self, dev: EmulatedCamera) -> EmulatedCamera:
        if not dev.attached:
            raise usb.core.USBError("No such device", -4, errno.ENODEV)
        return dev

    def close_device(self, dev_handle: EmulatedCamera) -> None:
        pass

    def set_configuration(self, dev_handle: EmulatedCamera, config_value: int) -> None:
        pass

    def get_configuration(self, dev_handle: EmulatedCamera) -> int:
        return 1

    def set_interface_altsetting(self, dev_handle: EmulatedCamera, intf: int, altsetting: int) -> None:
        pass

    def claim_interface(self, dev_handle: EmulatedCamera, intf: int) -> None:
        if not dev_handle.attached:
            raise usb.core.USBError("No such device", -4, errno.ENODEV)

    def release_interface(self, dev_handle: EmulatedCamera, intf: int) -> None:
        pass

    def clear_halt(self, dev_handle: EmulatedCamera, ep: int) -> None:
        pass

    def is_kernel_driver_active(self, dev_handle: EmulatedCamera, intf: int) -> bool:
        return False

    def bulk_read(self, dev_handle: EmulatedCamera, ep: int, intf: int, buff: array.array, timeout: int) -> int:
        if ep != dev_handle.endpoint:
            raise usb.core.USBError("Pipe error", -9, errno.EPIPE)
        data = dev_handle.read(len(buff) * buff.itemsize, timeout)
        memoryview(buff).cast("B")[: len(data)] = data
        return len(data)

    def ctrl_transfer(self, dev_handle: EmulatedCamera, bmRequestType: int, bRequest: int, wValue: int,
                      wIndex: int, data: array.array, timeout: int) -> int:
        n = len(data) * data.itemsize
        if bmRequestType & 0x80:
            got = dev_handle.control(bmRequestType, bRequest, wValue, wIndex, b"", n)
            assert isinstance(got, bytes)
            memoryview(data).cast("B")[: len(got)] = got
            return len(got)
        return int(dev_handle.control(bmRequestType, bRequest, wValue, wIndex, data.tobytes(), n))


def emulated_backend(spec: str) -> EmulatedBackend:
    """A backend with one camera from a short spec: ``"davis346"``,
    ``"dvs128"``, ``"davis240"``, optionally ``":realtime"``."""
    model, _, opt = spec.partition(":")
    return EmulatedBackend(EmulatedCamera(model, realtime=(opt == "realtime"), duration_us=10_000_000
                                          if opt == "realtime" else 1_000_000))
