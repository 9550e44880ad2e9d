"""Event text files: the UZH/RPG event-camera dataset ``events.txt`` and CSV.

One event per line, four numbers separated by spaces, tabs or commas, in
the order given by ``columns`` (default ``txyp``) with time in ``time_unit``
(default seconds, as in the dataset: ``0.003811000 96 133 0``). Polarity
0/1 or -1/+1. Lines starting with ``#`` or ``%`` and a header line with
letters (``t,x,y,p``) are skipped. Time is parsed from the decimal text
exactly into integer µs (rounded half up below 1 µs), never through a float.

Companion files next to ``events.txt`` (the dataset's layout) give more
streams: ``imu.txt`` (``t ax ay az gx gy gz``) and ``groundtruth.txt``
(``t px py pz qx qy qz qw``) and ``images.txt`` (``t path``). The sensor
size comes from the option, then from the first image, else from the largest
coordinates (a first pass over the file).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from typing import Any

import numpy as np
from numba import njit

from tectum import ImuPacket, Kind, Packet, PosePacket, FramePacket

from ._common import ColumnPool, EventAssembler, FileSource

__all__ = ["TextSource", "parse_lines"]

_UNIT_DIGITS = {"s": 6, "ms": 3, "us": 0, "ns": -3}
_HOLD = 1 << 21  # events held in memory while inferring the sensor size
_POOL = ColumnPool(max_sets=3, dtypes=(np.int64,) * 5)  # parser outputs: t, x, y, p, line offsets


@njit(cache=True, nogil=True, inline="always")
def _sep(c):  # pragma: no cover - numba
    return c == 32 or c == 9 or c == 44 or c == 13


@njit(cache=True, nogil=True)
def parse_lines(buf, order, digits, t, x, y, p, where):  # pragma: no cover - numba
    """Parse complete lines of ``buf`` (uint8) in one pass. ``order[k]`` is
    the field (0 t, 1 x, 2 y, 3 p) of column k; ``digits`` the power of ten
    from the time unit to µs. Time is built from its decimal digits in
    integer arithmetic: digits below 1 µs round half up (on the first dropped
    digit; away from zero for negative times). Returns (n_events, bytes
    consumed, bad line offset or -1)."""
    n = 0
    i = 0
    m = buf.shape[0]
    # the last complete line ends at the last newline
    last = m - 1
    while last >= 0 and buf[last] != 10:
        last -= 1
    while i <= last:
        start = i
        c = buf[i]
        if c == 35 or c == 37:  # '#' or '%': comment
            while buf[i] != 10:
                i += 1
            i += 1
            continue
        col = 0
        ok = True
        tv = np.int64(0)
        xv = np.int64(0)
        yv = np.int64(0)
        pv = np.int64(0)
        while True:
            while i < last and _sep(buf[i]):
                i += 1
            c = buf[i]
            if c == 10:
                break
            neg = False
            if c == 45:
                neg = True
                i += 1
            elif c == 43:
                i += 1
            ip = np.int64(0)
            nd = 0
            while 48 <= buf[i] <= 57:
                ip = ip * 10 + (buf[i] - 48)
                i += 1
                nd += 1
            frac = np.int64(0)
            fd = 0
            up = 0
            nzfrac = False
            if buf[i] == 46:
                i += 1
                while 48 <= buf[i] <= 57:
                    d = buf[i] - 48
                    if d:
                        nzfrac = True
                    if fd < digits:
                        frac = frac * 10 + d
                        fd += 1
                    elif fd == digits:
                        up = 1 if d >= 5 else 0
                        fd += 1
                    i += 1
                    nd += 1
            c = buf[i]
            if nd == 0 or not (c == 10 or _sep(c)) or col >= 4:
                ok = False
                break
            f = order[col]
            if f == 0:
                v = ip
                if digits >= 0:
                    for _ in range(digits):
                        v *= 10
                    for _ in range(digits - min(fd, digits)):
                        frac *= 10
                    v += frac + up
                else:
                    for _ in range(-digits):
                        v //= 10
                tv = -v if neg else v
            else:
                if nzfrac:
                    ok = False
                    break
                v = -ip if neg else ip
                if f == 1:
                    xv = v
                elif f == 2:
                    yv = v
                else:
                    pv = v
            col += 1
        if not ok or (col != 4 and col != 0):
            return n, start, start
        i += 1  # past the newline
        if col == 0:  # blank line
            continue
        t[n] = tv
        x[n] = xv
        y[n] = yv
        p[n] = pv
        where[n] = start
        n += 1
    return n, last + 1, -1


_NUM = rb"[+-]?(?:\d+\.?\d*|\.\d+)"
_LINE = re.compile(rb"^\s*" + _NUM + rb"(?:[ \t,]+" + _NUM + rb"){3}\s*$")


def looks_like_events_text(head: bytes) -> bool:
    """First data lines are 4 numeric columns, the 4th a polarity (0/1/-1)."""
    lines = [ln for ln in head.split(b"\n")[:-1] if ln.strip() and not ln.startswith((b"#", b"%"))]
    if lines and re.search(rb"[A-Za-z]", lines[0]) and b"," in lines[0]:
        lines = lines[1:]  # CSV header
    if len(lines) < 2:
        return len(lines) == 1 and len(head) < 4096 and bool(_LINE.match(lines[0]))
    for ln in lines[:20]:
        if not _LINE.match(ln):
            return False
        if re.split(rb"[ \t,]+", ln.strip())[3] not in (b"0", b"1", b"-1", b"+1"):
            return False
    return True


class TextSource(FileSource):
    """Events from ``events.txt``-style text or CSV files.

    Parameters (besides :class:`FileSource`'s)
    ------------------------------------------
    columns:
        Column order, a permutation of ``txyp`` (e.g. ``xytp``).
    time_unit:
        ``s`` (default, as in the RPG dataset), ``ms``, ``us`` or ``ns``.
    companions:
        Read ``imu.txt``, ``groundtruth.txt`` and ``images.txt`` beside an
        ``events.txt`` as IMU, pose and frame streams.
    """

    name = "text"
    format = "text"
    extensions = (".txt", ".csv")
    produces = (Kind.EVENTS, Kind.IMU, Kind.POSES, Kind.FRAMES)

    def __init__(self, path: str, columns: str = "txyp", time_unit: str = "s", companions: bool = True,
                 **kw: Any) -> None:
        super().__init__(path, **kw)
        if sorted(columns) != sorted("txyp"):
            raise ValueError(f"columns must be a permutation of 'txyp', got {columns!r}")
        if time_unit not in _UNIT_DIGITS:
            raise ValueError(f"time_unit must be one of {list(_UNIT_DIGITS)}")
        self.columns = columns
        self.time_unit = time_unit
        self.companions = companions

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return looks_like_events_text(head)

    def _chunks(self) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """(byte offset, t, x, y, p, byte offset of each line) per chunk; x, y,
        p and the offsets live in buffers reused by the next chunk."""
        f = self._open()
        order = np.array(["txyp".index(c) for c in self.columns], np.int64)
        digits = _UNIT_DIGITS[self.time_unit]
        pos = 0
        rest = b""
        first = True
        eof = False
        while True:
            data = b"" if eof else f.read(self.chunk_bytes)
            eof = eof or not data
            buf = rest + data
            if eof:
                if not buf.strip():
                    return
                if not buf.endswith(b"\n"):
                    buf += b"\n"  # last line without a newline
            if first:
                first = False
                nl = buf.find(b"\n")
                if nl >= 0 and re.search(rb"[A-Za-z]", buf[:nl]) and not buf.startswith((b"#", b"%")):
                    pos += nl + 1
                    buf = buf[nl + 1:]
            arr = np.frombuffer(buf, np.uint8)
            cap = len(buf) // 8 + 2  # a line has at least 8 bytes ("0 0 0 0\n"); untouched pages cost nothing
            # pooled: t may end in packets (the pool sees them), x, y, p and where are copied by the caller
            t, x, y, p, where = (a[:cap] for a in _POOL.take(cap))
            n, used, bad = parse_lines(arr, order, digits, t, x, y, p, where)
            if bad >= 0:
                end = buf.find(b"\n", bad)
                if not self.skip_bad:
                    self._fail(f"line is not 4 numbers: {bytes(buf[bad:end])[:80]!r}", pos + bad)
                self._note_skip(pos + bad, pos + end, 1)
                used = end + 1
            elif used == 0 and len(buf) > self.chunk_bytes + (1 << 20):
                self._fail("no line end in the last MiB: not a text event file", pos)
            yield pos, t[:n], x[:n], y[:n], p[:n], pos + where[:n]
            rest = buf[used:]
            pos += used
            if eof and bad < 0:
                return

    def _polarity(self, p: np.ndarray, where: np.ndarray) -> np.ndarray:
        bad = (p < -1) | (p > 1)
        if self._pol_zero is None and p.size:
            self._pol_zero = bool((p == 0).any()) if (p == 0).any() or (p == -1).any() else None
        if self._pol_zero and (p == -1).any():
            bad |= p == -1
        elif self._pol_zero is False:
            bad |= p == 0
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            self._fail(f"polarity {int(p[i])} is not 0/1 or -1/+1", int(where[i]))
        return np.where(p > 0, 1, -1).astype(np.int8)

    def _sensor_guess(self) -> tuple[int, int] | None:
        imgs = self._images()
        if imgs:
            import cv2

            img = cv2.imread(imgs[0][1], cv2.IMREAD_UNCHANGED)
            if img is not None:
                return int(img.shape[1]), int(img.shape[0])
        return None

    def _extent(self, chunks: Any) -> tuple[int, int]:
        w = h = 1
        for _, t, x, y, p, _ in chunks:
            if x.size:
                w, h = max(w, int(x.max()) + 1), max(h, int(y.max()) + 1)
        return w, h

    def _sized_chunks(self) -> tuple[tuple[int, int], Any]:
        """(sensor, chunks): without a size from the option or images, the
        extent of the coordinates; a small file (up to ``_HOLD`` events) is
        parsed once and held, a larger one is read twice (bounded memory)."""
        sensor = self._sensor(None) or self._sensor_guess()
        if sensor is not None:
            return sensor, self._chunks()
        held, n = [], 0
        for c in self._chunks():
            held.append((c[0], c[1], *(a.copy() for a in c[2:])))
            n += c[1].shape[0]
            if n > _HOLD:
                self.close()
                sensor = self._extent(self._chunks())
                self.close()
                return sensor, self._chunks()
        self.close()
        return self._extent(held), iter(held)

    def _beside(self, name: str) -> str | None:
        if not self.companions:
            return None
        q = os.path.join(os.path.dirname(os.path.abspath(self.path)), name)
        return q if os.path.isfile(q) else None

    def _images(self) -> list[tuple[int, str]]:
        q = self._beside("images.txt")
        if q is None:
            return []
        out = []
        base = os.path.dirname(q)
        with open(q, "rb") as f:
            for line in f:
                parts = line.split()
                if len(parts) >= 2 and not line.startswith(b"#"):
                    out.append((_to_us(parts[0]), os.path.join(base, parts[1].decode())))
        return out

    def _packets(self) -> Iterator[Packet]:
        self._pol_zero: bool | None = None
        sensor, chunks = self._sized_chunks()
        asm = EventAssembler(self, sensor)
        for pos, t, x, y, p, where in chunks:
            if x.size and (x.min() < 0 or y.min() < 0):
                i = int(np.flatnonzero((x < 0) | (y < 0))[0])
                if not self.skip_bad:
                    self._fail(f"negative coordinate ({int(x[i])}, {int(y[i])})", int(where[i]))
                ok = (x >= 0) & (y >= 0)
                self._note_skip(int(where[i]), int(where[i]), int((~ok).sum()))
                t, x, y, p, where = t[ok], x[ok], y[ok], p[ok], where[ok]
            pol = self._polarity(p, where)
            yield from asm.push(t, np.minimum(x, 65535).astype(np.uint16), np.minimum(y, 65535).astype(np.uint16),
                                pol, pos, where)
            if self.t_end_us is not None and asm.last_t is not None and asm.last_t >= self.t_end_us:
                break
        yield from asm.finish()
        yield from self._companions()

    def _companions(self) -> Iterator[Packet]:
        q = self._beside("imu.txt")
        if q:
            a = _table(q, 7)
            if a is not None:
                yield ImuPacket(a[0], accel=a[1][:, 0:3], gyro=a[1][:, 3:6])
        q = self._beside("groundtruth.txt")
        if q:
            a = _table(q, 8)
            if a is not None:
                yield PosePacket(a[0], position=a[1][:, 0:3], orientation=a[1][:, 3:7])
        imgs = self._images()
        if imgs:
            import cv2

            for k, (t, name) in enumerate(imgs):
                img = cv2.imread(name, cv2.IMREAD_UNCHANGED)
                if img is None:
                    continue
                end = imgs[k + 1][0] if k + 1 < len(imgs) else t + 1
                yield FramePacket(np.array([t], np.int64), images=img[None], t_start=t, t_end=max(end, t + 1))


def _to_us(s: bytes) -> int:
    arr = np.frombuffer(s + b" 0 0 0\n", np.uint8)
    out = [np.empty(1, np.int64) for _ in range(5)]
    n, _, _ = parse_lines(arr, np.arange(4), 6, *out)
    return int(out[0][0]) if n else 0


def _table(path: str, ncols: int) -> tuple[np.ndarray, np.ndarray] | None:
    rows = []
    with open(path, "rb") as f:
        for line in f:
            parts = line.split()
            if len(parts) == ncols and not line.startswith(b"#"):
                rows.append(parts)
    if not rows:
        return None
    t = np.array([_to_us(r[0]) for r in rows], np.int64)
    v = np.array([[float(c) for c in r[1:]] for r in rows], np.float64)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]
