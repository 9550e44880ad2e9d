"""iniVation AEDAT 3.1 files (``#!AER-DAT3.1``), as written by cAER/libcaer.

After ``#`` header lines closed by ``#!END-HEADER``, a series of typed
packets, little-endian. Each has a 28-byte header: int16 type, int16 source,
int32 event size, int32 timestamp offset, int32 timestamp overflow, int32
capacity, int32 number, int32 valid; then ``capacity * size`` bytes.

* Polarity (type 1, 8 bytes): uint32 data (bit 0 valid, bit 1 polarity
  1 = ON, bits 2-16 y, bits 17-31 x), int32 timestamp; time is
  ``overflow << 31 | timestamp``. libcaer's origin is top-left: kept as is.
* Frame (type 2, event size ``36 + 2 * max pixels``): uint32 info (bit 0
  valid, bits 1-3 colour channels), int32 start/end of frame, int32
  start/end of exposure, int32 lengthX, lengthY, positionX, positionY, then
  ``lengthX * lengthY * channels`` uint16 pixels (normalised to 16 bits,
  top-left origin). A :class:`tectum.FramePacket` per packet (per run of
  frames of one size): ``t`` mid-exposure, ``images`` uint16 (N, H, W) or
  (N, H, W, C), ``exposure_start``/``exposure_end`` µs, ``position``.
* IMU6 (type 3, 36 bytes): uint32 info, int32 timestamp, float32 accel x, y,
  z (g), gyro x, y, z (°/s), temperature (°C) -> m/s², rad/s.
* Special (type 0, 8 bytes): uint32 data (bit 0 valid, bits 1-7 type, bits
  8-31 data), int32 timestamp: a :class:`tectum.TriggerPacket` with
  ``channel`` = libcaer's special type (1 timestamp reset, 2/3/4 external
  input rising/falling edge/pulse, ...) and ``value`` 0 for a falling edge
  (type 3), else 1; timestamp wraps (0) and row-only events (5) are
  bookkeeping and skipped.
* Other types are counted in :attr:`Aedat31Source.other_events` and skipped.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import numpy as np

from tectum import FramePacket, ImuPacket, Kind, Packet, TriggerPacket

from ._common import EventAssembler, FileSource, SampleTiler

__all__ = ["Aedat31Source"]

_HDR = np.dtype([("type", "<i2"), ("source", "<i2"), ("size", "<i4"), ("tsoff", "<i4"), ("ovf", "<i4"),
                 ("cap", "<i4"), ("num", "<i4"), ("valid", "<i4")])
_IMU = np.dtype([("info", "<u4"), ("t", "<i4"), ("v", "<f4", (7,))])
_FRAME = np.dtype([("info", "<u4"), ("frame", "<i4", (2,)), ("exposure", "<i4", (2,)), ("size", "<i4", (2,)),
                   ("position", "<i4", (2,))])
_SIZES = {"dvs128": (128, 128), "edvs": (128, 128), "davis240": (240, 180), "davis346": (346, 260),
          "davis640": (640, 480), "dvxplorer": (640, 480), "davis128": (128, 128)}


class Aedat31Source(FileSource):
    """Polarity events, frames, IMU6 samples and special events (triggers)
    from AEDAT 3.1 files."""

    name = "aedat31"
    format = "aedat31"
    extensions = (".aedat3", ".aedat31")
    produces = (Kind.EVENTS, Kind.FRAMES, Kind.IMU, Kind.TRIGGERS)

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
        tiler = SampleTiler(self)
        self.other_events = 0
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
            ovf = int(h["ovf"]) << 31
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
                    v = rec["v"].astype(np.float64)
                    imu = tiler.push(ImuPacket, "imu", rec["t"].astype(np.int64) + ovf, pos,
                                     accel=v[:, 0:3] * 9.80665, gyro=np.deg2rad(v[:, 3:6]), temperature=v[:, 6])
                    if imu is not None:
                        yield imu
            elif etype == 0 and esize == 8:
                w = np.frombuffer(data, "<u4", count=2 * num).reshape(-1, 2)
                typ = (w[:, 0] >> 1) & 0x7F
                keep = ((w[:, 0] & 1) == 1) & (typ != 0) & (typ != 5)
                if keep.any():
                    q = tiler.push(TriggerPacket, "triggers", w[keep, 1].astype(np.int64) + ovf, pos,
                                   channel=typ[keep].astype(np.int16),
                                   value=np.where(typ[keep] == 3, 0, 1).astype(np.int8))
                    if q is not None:
                        yield q
            elif etype == 2 and esize >= _FRAME.itemsize:
                yield from self._frames(tiler, data, esize, num, ovf, pos)
            else:
                self.other_events += num
            pos += 28 + body
            if self.t_end_us is not None and asm.last_t is not None and asm.last_t >= self.t_end_us:
                break
        yield from asm.finish()

    def _frames(self, tiler: SampleTiler, data: bytes, esize: int, num: int, ovf: int, pos: int) -> Iterator[Packet]:
        """The valid frames of a frame packet, one FramePacket per run of
        frames of the same size and channels."""
        heads = np.frombuffer(data, _FRAME, count=num, offset=0) if esize == _FRAME.itemsize else \
            np.ndarray((num,), _FRAME, data, 0, (esize,))
        run: list[tuple[int, np.ndarray, np.ndarray]] = []  # (mid-exposure µs, image, header)
        for k in range(num):
            h = heads[k]
            if not h["info"] & 1:
                continue
            ch = int(h["info"] >> 1) & 7
            w, hgt = int(h["size"][0]), int(h["size"][1])
            if ch not in (1, 3, 4) or w < 0 or hgt < 0 or _FRAME.itemsize + 2 * w * hgt * ch > esize:
                if not self.skip_bad:
                    self._fail(f"frame {k} of a frame packet: {w}x{hgt}x{ch} pixels do not fit its {esize} bytes",
                               pos + 28 + k * esize)
                self._note_skip(pos + 28 + k * esize, pos + 28 + (k + 1) * esize - 1, 1)
                continue
            img = np.frombuffer(data, "<u2", count=w * hgt * ch, offset=k * esize + _FRAME.itemsize)
            img = img.reshape((hgt, w) if ch == 1 else (hgt, w, ch))
            if run and run[-1][1].shape != img.shape:
                yield from self._frame_run(tiler, run, ovf, pos)
                run = []
            run.append((int(h["exposure"].astype(np.int64).sum()) // 2, img, h))
        if run:
            yield from self._frame_run(tiler, run, ovf, pos)

    def _frame_run(self, tiler: SampleTiler, run: list[tuple[int, np.ndarray, Any]], ovf: int,
                   pos: int) -> Iterator[Packet]:
        hs = np.stack([h for _, _, h in run])
        q = tiler.push(FramePacket, "frames", np.array([t for t, _, _ in run], np.int64) + ovf, pos,
                       images=np.stack([img for _, img, _ in run]),
                       exposure_start=hs["exposure"][:, 0].astype(np.int64) + ovf,
                       exposure_end=hs["exposure"][:, 1].astype(np.int64) + ovf,
                       position=hs["position"].astype(np.int16))
        if q is not None:
            yield q
