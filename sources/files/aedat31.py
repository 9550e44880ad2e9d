"""iniVation AEDAT 3.1 files (``#!AER-DAT3.1``), as written by cAER/libcaer.

After ``#`` header lines closed by ``#!END-HEADER``, a series of typed
packets, little-endian. Each has a 28-byte header: int16 type, int16 source,
int32 event size, int32 timestamp offset, int32 timestamp overflow, int32
capacity, int32 number, int32 valid; then ``capacity * size`` bytes.

* Polarity (type 1, 8 bytes): uint32 data (bit 0 valid, bit 1 polarity
  1 = ON, bits 2-16 y, bits 17-31 x), int32 timestamp; time is
  ``overflow << 31 | timestamp``. libcaer's origin is top-left: kept as is.
* IMU6 (type 3, 36 bytes): uint32 info, int32 timestamp, float32 accel x, y,
  z (g), gyro x, y, z (°/s), temperature (°C) -> m/s², rad/s.
* Special (0), frame (2) and others are counted in
  :attr:`Aedat31Source.other_events` and skipped.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import numpy as np

from tectum import ImuPacket, Kind, Packet

from ._common import EventAssembler, FileSource

__all__ = ["Aedat31Source"]

_HDR = np.dtype([("type", "<i2"), ("source", "<i2"), ("size", "<i4"), ("tsoff", "<i4"), ("ovf", "<i4"),
                 ("cap", "<i4"), ("num", "<i4"), ("valid", "<i4")])
_IMU = np.dtype([("info", "<u4"), ("t", "<i4"), ("v", "<f4", (7,))])
_SIZES = {"dvs128": (128, 128), "edvs": (128, 128), "davis240": (240, 180), "davis346": (346, 260),
          "davis640": (640, 480), "dvxplorer": (640, 480), "davis128": (128, 128)}


class Aedat31Source(FileSource):
    """Polarity events and IMU6 samples from AEDAT 3.1 files."""

    name = "aedat31"
    format = "aedat31"
    extensions = (".aedat3", ".aedat31")
    produces = (Kind.EVENTS, Kind.IMU)

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"#!AER-DAT3.1")

    def _header(self, f: Any) -> tuple[int, tuple[int, int] | None]:
        f.seek(0)
        pos = 0
        sensor = None
        while True:
            line = f.readline(1 << 16)
            if pos == 0 and not line.startswith(b"#!AER-DAT3."):
                self._fail("not an AEDAT 3.1 file (first line is not #!AER-DAT3.1)", 0)
            if not line.startswith(b"#") or not line.endswith(b"\n"):
                self._fail("header not closed by #!END-HEADER (truncated or corrupt)", pos)
            pos += len(line)
            if line.startswith(b"#!END-HEADER"):
                break
            m = re.match(rb"#Source \d+:\s*(\S+)", line)
            if m and sensor is None:
                name = m.group(1).decode("latin1").lower()
                sensor = next((s for k, s in _SIZES.items() if k in name), None)
            m = re.search(rb"sizeX=\"?(\d+).*sizeY=\"?(\d+)", line)
            if m:
                sensor = (int(m.group(1)), int(m.group(2)))
        return pos, sensor

    def _packets(self) -> Iterator[Packet]:
        f = self._open()
        start, sensor = self._header(f)
        sensor = self._sensor(sensor)
        if sensor is None:
            self._fail("the header names no known sensor: give sensor=WxH")
        assert sensor is not None
        size = f.seek(0, 2)
        f.seek(start)
        asm = EventAssembler(self, sensor)
        self.other_events = 0
        imu_next: int | None = None
        pos = start
        while pos < size:
            hb = f.read(28)
            if len(hb) < 28:
                if not self.skip_bad:
                    self._fail("file ends inside a packet header (truncated)", pos)
                self._note_skip(pos, size - 1, 1)
                break
            h = np.frombuffer(hb, _HDR)[0]
            etype, esize, cap, num = int(h["type"]), int(h["size"]), int(h["cap"]), int(h["num"])
            body = cap * esize
            if esize <= 0 or cap < 0 or num < 0 or num > cap or body > size - pos - 28:
                if not self.skip_bad:
                    self._fail(f"corrupt packet header (type {etype}, size {esize}, capacity {cap}, "
                               f"number {num}) or truncated packet", pos)
                self._note_skip(pos, size - 1, 1)  # no way to resynchronise: give up the rest
                break
            data = f.read(body)
            ovf = np.int64(int(h["ovf"])) << 31
            if etype == 1 and esize == 8:
                w = np.frombuffer(data, "<u4", count=2 * num).reshape(-1, 2)
                valid = (w[:, 0] & 1) == 1
                d = w[valid, 0]
                t = w[valid, 1].astype(np.int64) + ovf
                x = (d >> 17).astype(np.uint16)
                y = ((d >> 2) & 0x7FFF).astype(np.uint16)
                p = np.where((d >> 1) & 1, 1, -1).astype(np.int8)
                where = pos + 28 + 8 * np.flatnonzero(valid)
                yield from asm.push(t, x, y, p, pos, where)
            elif etype == 3 and esize == 36:
                rec = np.frombuffer(data, _IMU, count=num)
                rec = rec[(rec["info"] & 1) == 1]
                if rec.shape[0]:
                    t = rec["t"].astype(np.int64) + ovf
                    v = rec["v"].astype(np.float64)
                    s = imu_next if imu_next is not None else int(t[0])
                    imu_next = max(s, int(t[-1]) + 1)
                    yield ImuPacket(t, accel=v[:, 0:3] * 9.80665, gyro=np.deg2rad(v[:, 3:6]), temperature=v[:, 6],
                                    t_start=s, t_end=imu_next)
            else:
                self.other_events += num
            pos += 28 + body
            if self.t_end_us is not None and asm.last_t is not None and asm.last_t >= self.t_end_us:
                break
        yield from asm.finish()
