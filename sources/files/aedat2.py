"""iniVation/jAER AEDAT 2.0 files (``#!AER-DAT2.0``).

After ``#`` header lines (CRLF), big-endian pairs of int32 address and int32
timestamp (µs; 32-bit wraps unrolled). The address layout depends on the
jAER chip class named by the ``# AEChip:`` header line:

* DVS128 (``...retina.DVS128``, eDVS): bit 0 polarity, bits 1-7 x, bits 8-14
  y, bit 15 external event. jAER (the reference reader of these files) reads
  ``x = 127 - raw_x`` (stored mirrored), ``y = raw_y`` with the origin at the
  bottom left, and ON when bit 0 is **0** (``type = (1 - addr) & 1``; the
  iniVation format page says the opposite, jAER's code is what wrote and
  reads the files). tectum outputs ``x = 127 - raw_x``, ``y = 127 - raw_y``
  (top-left origin) and that polarity.
* DAVIS (``...davis.DAVIS240C``, ``Davis346...``, ``Davis640``): bit 31 APS/IMU,
  bits 22-30 y, bits 12-21 x, bit 11 polarity (1 = ON), bit 10 external event.
  jAER reads ``x = w - 1 - raw_x`` and a bottom-left ``y = raw_y``; tectum
  outputs ``x = w - 1 - raw_x``, ``y = h - 1 - raw_y`` (top-left origin). APS samples are
  skipped; IMU samples (7 words: accel x, y, z, temperature, gyro x, y, z;
  16-bit signed values in bits 12-27) become an IMU stream, scaled by the
  full ranges the header's ``ImuGyroScale``/``ImuAccelScale`` entries state
  (jAER's defaults ±500 °/s and ±4 g where absent: LSB = range / 32768;
  temperature 1/340 °C per LSB + 35 °C) and converted to m/s² and rad/s.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import numpy as np

from tectum import ImuPacket, Kind, Packet

from . import _kernels as K
from ._common import EventAssembler, FileSource

__all__ = ["Aedat2Source", "CHIPS"]

#: jAER chip class fragment (lower case) -> (width, height, davis layout)
CHIPS = {
    "dvs128": (128, 128, False), "edvs": (128, 128, False), "davis240": (240, 180, True),
    "davis346": (346, 260, True), "davis640": (640, 480, True), "davis128": (128, 128, True),
    "davis208": (208, 192, True),
}

_G = 9.80665


class Aedat2Source(FileSource):
    """Events (and DAVIS IMU samples) from jAER AEDAT 2.0 files.

    Parameters (besides :class:`FileSource`'s)
    ------------------------------------------
    chip:
        Force the address layout/size when the header does not name a known
        chip: ``dvs128``, ``davis240``, ``davis346``, ``davis640``.
    """

    name = "aedat2"
    format = "aedat2"
    extensions = (".aedat", ".aedat2", ".dat2")
    produces = (Kind.EVENTS, Kind.IMU)

    def __init__(self, path: str, chip: str | None = None, **kw: Any) -> None:
        super().__init__(path, **kw)
        self.chip = chip.lower() if chip else None
        # IMU full ranges: jAER's defaults, replaced by what the header states
        self.gyro_full_scale_dps = 500
        self.accel_full_scale_g = 4

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"#!AER-DAT2.0")

    def _header(self, f: Any) -> tuple[int, tuple[int, int] | None, bool]:
        chip = self.chip
        f.seek(0)
        data = f.read(1 << 16)
        if not data.startswith(b"#!AER-DAT2.0"):
            self._fail("not an AEDAT 2.0 file (first line is not #!AER-DAT2.0)", 0)
        pos = 0  # the header is the lines starting with '#'
        while data.startswith(b"#", pos):
            nl = data.find(b"\n", pos)
            while nl < 0:
                more = f.read(1 << 16)
                if not more or len(data) > 1 << 26:
                    self._fail("header line not terminated (truncated header)", pos)
                data += more
                nl = data.find(b"\n", pos)
            pos = nl + 1
            if pos == len(data):
                data += f.read(1 << 16)
        head = data[:pos]
        m = re.search(rb"^#\s*AEChip:\s*(\S+)", head, re.M)
        if m and chip is None:
            chip = m.group(1).decode("latin1").lower()
        for name, attr in ((rb"ImuGyroScale\" value=\"GyroFullScaleDegPerSec(\d+)", "gyro_full_scale_dps"),
                           (rb"ImuAccelScale\" value=\"ImuAccelScaleG(\d+)", "accel_full_scale_g")):
            found = re.findall(name, head)
            if found:
                setattr(self, attr, int(found[-1]))
        f.seek(pos)
        self.chip_class = chip
        for frag, (w, h, davis) in CHIPS.items():
            if chip and frag in chip.split(".")[-1]:
                return pos, (w, h), davis
        if self.sensor_opt is not None:
            return pos, None, self.sensor_opt != (128, 128)
        self._fail(f"unknown jAER chip {chip!r} in the header: give chip=dvs128|davis240|davis346|davis640", 0)
        raise AssertionError

    def _packets(self) -> Iterator[Packet]:
        f = self._open()
        start, sensor, davis = self._header(f)
        sensor = self._sensor(sensor)
        assert sensor is not None
        size = f.seek(0, 2)
        end = start + (size - start) // 8 * 8
        if end < size:
            if not self.skip_bad:
                self._fail(f"file ends inside an 8-byte event (truncated, {size - end} bytes left)", end)
            self._note_skip(end, size - 1, 1)
        f.seek(start)
        state = np.zeros(K.AEDAT2_STATE, np.int64)
        asm = EventAssembler(self, sensor)
        imu = _ImuAssembler(self.gyro_full_scale_dps, self.accel_full_scale_g)
        step = max(8, self.chunk_bytes // 8 * 8)
        pos = start
        while pos < end:
            buf = f.read(min(step, end - pos))
            words = np.frombuffer(buf, ">u4").astype(np.uint32)
            m = words.shape[0] // 2
            t, x, y = np.empty(m, np.int64), np.empty(m, np.uint16), np.empty(m, np.uint16)
            p, where = np.empty(m, np.int8), np.empty(m, np.int64)
            imu_t, imu_v = np.empty(m, np.int64), np.empty((m, 2), np.int64)
            n, ni, bad, nbad = K.decode_aedat2(words, state, davis, sensor[0], sensor[1], t, x, y, p, where,
                                               imu_t, imu_v)
            if nbad:
                if not self.skip_bad:
                    self._fail(f"address 0x{int(words[2 * bad]):08x} is no DVS128 address (bits 16-31 set)",
                               pos + 8 * bad)
                self._note_skip(pos + 8 * bad, pos + len(buf) - 1, int(nbad))
            yield from asm.push(t[:n], x[:n], y[:n], p[:n], pos, pos + 8 * where[:n])
            if ni:
                yield from imu.push(imu_t[:ni], imu_v[:ni])
            pos += len(buf)
            if self.t_end_us is not None and asm.last_t is not None and asm.last_t >= self.t_end_us:
                break
        yield from asm.finish()
        yield from imu.finish()


class _ImuAssembler:
    """Group DAVIS IMU words (7 per sample) into ImuPackets, across chunks.
    Raw 16-bit values scale by the full ranges the header states (jAER's
    ``ImuGyroScale``/``ImuAccelScale``): LSB = full scale / 32768."""

    def __init__(self, gyro_full_scale_dps: int, accel_full_scale_g: int) -> None:
        self.gyro_lsb = 32768.0 / gyro_full_scale_dps  # LSB per °/s
        self.accel_lsb = 32768.0 / accel_full_scale_g  # LSB per g
        self.pending_t = np.empty(0, np.int64)
        self.pending_v = np.empty((0, 2), np.int64)
        self.next_start: int | None = None

    def push(self, t: np.ndarray, v: np.ndarray, final: bool = False) -> list[ImuPacket]:
        """The packets the words ``(t, (component, raw value))`` complete.
        Samples at the latest time wait for the next chunk (one may still
        follow at that time: the contract keeps a time in one packet) until
        ``final``."""
        t = np.concatenate([self.pending_t, t])
        v = np.concatenate([self.pending_v, v])
        # samples start at component 0 (accel x); drop partial groups at the front
        starts = np.flatnonzero(v[:, 0] == 0)
        if starts.size == 0:
            self.pending_t, self.pending_v = t[-6:], v[-6:]
            return []
        t, v = t[starts[0]:], v[starts[0]:]
        n = t.shape[0] // 7
        full = v[: n * 7, 0].reshape(n, 7)
        ok = np.all(full == np.arange(7), axis=1)
        keep = n
        if not final and ok.any():
            group_t = t[: n * 7: 7]
            keep = int(np.flatnonzero(ok & (group_t == group_t[ok][-1]))[0])
            ok[keep:] = False
        self.pending_t, self.pending_v = t[keep * 7:], v[keep * 7:]
        if not ok.any():
            return []
        val = v[: n * 7, 1].reshape(n, 7)[ok].astype(np.uint16).view(np.int16).astype(np.float64)
        ts = t[: n * 7].reshape(n, 7)[ok, 0]
        accel = val[:, 0:3] / self.accel_lsb * _G
        gyro = np.deg2rad(val[:, 4:7] / self.gyro_lsb)
        temp = val[:, 3] / 340.0 + 35.0
        start = self.next_start if self.next_start is not None else int(ts[0])
        end = int(ts[-1]) + 1
        self.next_start = end
        return [ImuPacket(ts, accel=accel, gyro=gyro, temperature=temp, t_start=start, t_end=end)]

    def finish(self) -> list[ImuPacket]:
        """The samples held back for the next chunk, at the end of the file."""
        return self.push(np.empty(0, np.int64), np.empty((0, 2), np.int64), final=True)
