"""Structured ``.npy`` event files: one record per event with named fields
``t`` (µs, or ``timestamp``/``ts``), ``x``, ``y``, ``p`` (or ``polarity``/``on``),
as written by tectum's npy sink and by tools such as tonic/faery (their
``t`` is µs). Read in chunks straight from the file (memory stays bounded).
The sensor size comes from the option, else the coordinates' extent."""

from __future__ import annotations

from collections.abc import Iterator
from functools import partial
from typing import Any

import numpy as np

from tectum import Packet

from ._common import EventAssembler, FileSource, record_offsets

__all__ = ["NpySource"]

_ALIASES = {"t": ("t", "timestamp", "ts"), "x": ("x",), "y": ("y",), "p": ("p", "polarity", "on", "pol")}


class NpySource(FileSource):
    """Events from a structured ``.npy`` array."""

    name = "npy"
    format = "npy"
    extensions = (".npy",)

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(b"\x93NUMPY")

    def _layout(self, f: Any) -> tuple[np.dtype, int, dict[str, str], int]:
        try:
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read(f, max_header_size=1 << 16)
        except Exception as e:  # numpy raises ValueError, SyntaxError, TokenError... on bad headers
            self._fail(f"not a valid .npy header: {e}", 0)
        if dtype.hasobject:
            self._fail("the array holds Python objects; refusing to unpickle")
        if dtype.names is None or len(shape) != 1:
            self._fail(f"expected a 1-D structured array with fields t, x, y, p; got {dtype} {shape}")
        names = {}
        for k, al in _ALIASES.items():
            m = next((a for a in al if a in dtype.names), None)
            if m is None:
                self._fail(f"no field for {k!r} among {dtype.names}")
            field = dtype[m]
            if field.shape != () or field.kind not in ("iu" if k == "t" else "iub"):
                what = f"an array of shape {field.shape}" if field.shape != () else f"of type {field}"
                self._fail(f"field {m!r} is {what}, not an integer{' (µs)' if k == 't' else ''}")
            names[k] = m
        return dtype, int(shape[0]), names, f.tell()

    def _packets(self) -> Iterator[Packet]:
        f = self._open()
        dtype, n, names, start = self._layout(f)
        size = f.seek(0, 2)
        if start + n * dtype.itemsize > size:
            if not self.skip_bad:
                self._fail(f"file holds {(size - start) // dtype.itemsize} of the {n} records (truncated)", size)
            n = (size - start) // dtype.itemsize
            self._note_skip(start + n * dtype.itemsize, size - 1, 1)
        step = max(1, self.chunk_bytes // dtype.itemsize)
        sensor = self._sensor(None)
        if sensor is None:
            w = h = 1
            for a in self._read(f, start, n, step, dtype):
                if a.size:
                    w, h = max(w, int(a[names["x"]].max()) + 1), max(h, int(a[names["y"]].max()) + 1)
            sensor = self._sensor_guessed((w, h))
        asm = EventAssembler(self, sensor)
        for i, a in enumerate(self._read(f, start, n, step, dtype)):
            at = start + i * step * dtype.itemsize
            idx = self._pixels(a, names, at, dtype.itemsize)
            if idx is not None:
                a = a[idx]
            k = a.shape[0]
            t, x, y, p = asm.reserve(k)
            t[:k], x[:k], y[:k] = a[names["t"]], a[names["x"]], a[names["y"]]
            np.copyto(p[:k], np.where(a[names["p"]] > 0, 1, -1), casting="unsafe")
            yield from asm.commit(k, at, partial(record_offsets, at, dtype.itemsize, k if idx is None else idx))
            if asm.past_end():
                break
        yield from asm.finish()

    def _read(self, f: Any, start: int, n: int, step: int, dtype: np.dtype) -> Iterator[np.ndarray]:
        f.seek(start)
        for i in range(0, n, step):
            k = min(step, n - i)
            yield np.frombuffer(f.read(k * dtype.itemsize), dtype, count=k)

    def _pixels(self, a: np.ndarray, names: dict[str, str], at: int, size: int) -> np.ndarray | None:
        """Indices of the records whose x and y fit uint16 pixel coordinates
        when some do not (``skip_bad``; else the first is named), else None."""
        bad = np.zeros(a.shape[0], bool)
        for c in ("x", "y"):
            v = a[names[c]]
            if v.dtype.kind != "u" or v.dtype.itemsize > 2:
                bad |= (v < 0) | (v > 65535)
        if not bad.any():
            return None
        i = int(np.flatnonzero(bad)[0])
        if not self.skip_bad:
            self._fail(f"({a[names['x']][i]}, {a[names['y']][i]}) is not a pixel coordinate", at + i * size)
        self._note_skip(at + i * size, at + (int(np.flatnonzero(bad)[-1]) + 1) * size - 1, int(bad.sum()))
        return np.flatnonzero(~bad)
