"""Write events to ``.npz`` with named columns, streaming.

Each column is appended to its own temporary ``.npy`` file as packets come
(memory stays bounded); :meth:`NpzSink.close` fixes the headers, stores them
into the archive under a temporary name and renames it into place, so an
aborted run leaves no half-written file.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from typing import IO

import numpy as np

from tectum import EventPacket, Packet, Sink

__all__ = ["NpzSink", "write_npz"]

_HEADER = 128  # bytes reserved for each .npy header (format 1.0 pads to 64)


class NpzSink(Sink):
    """Events (with every extra column) to a ``.npz`` file.

    Parameters
    ----------
    path:
        The output file; replaced atomically when the run ends well.
    compress:
        Deflate the archive (smaller, slower).
    """

    name = "npz"
    extensions = (".npz",)

    def __init__(self, path: str, compress: bool = False) -> None:
        self.path = path
        self.compress = compress
        self._dir: tempfile.TemporaryDirectory[str] | None = None
        self._files: dict[str, IO[bytes]] = {}
        self._dtypes: dict[str, tuple[np.dtype, tuple[int, ...]]] = {}
        self._n = 0
        self._sensor: tuple[int, int] | None = None
        self._interval: list[int] | None = None

    def open(self) -> None:
        parent = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(parent):
            raise FileNotFoundError(f"folder {parent!r} does not exist")
        self._dir = tempfile.TemporaryDirectory(prefix=".tectum-npz-", dir=parent)

    def write(self, packet: Packet) -> None:
        assert isinstance(packet, EventPacket)
        if self._dir is None:
            self.open()
        if self._sensor is None:
            self._sensor = packet.sensor
            self._interval = [packet.t_start, packet.t_end]
            for name in packet.column_names:
                a = packet[name]
                self._dtypes[name] = (a.dtype, a.shape[1:])
                f = open(os.path.join(self._dir.name, name + ".npy"), "wb")  # type: ignore[union-attr]
                f.write(b"\0" * _HEADER)
                self._files[name] = f
        elif packet.sensor != self._sensor:
            raise ValueError(f"sensor size changed from {self._sensor} to {packet.sensor}")
        elif set(packet.column_names) != set(self._files):
            raise ValueError(f"columns changed from {sorted(self._files)} to {sorted(packet.column_names)}")
        assert self._interval is not None
        self._interval[1] = packet.t_end
        for name, f in self._files.items():
            a = packet[name]
            dt, shape = self._dtypes[name]
            if a.dtype != dt or a.shape[1:] != shape:
                raise ValueError(f"column {name!r} changed dtype or shape")
            f.write(np.ascontiguousarray(a).tobytes())
        self._n += len(packet)

    def close(self) -> None:
        if self._dir is None:
            return
        try:
            tmp = os.path.join(self._dir.name, "out.npz")
            mode = zipfile.ZIP_DEFLATED if self.compress else zipfile.ZIP_STORED
            with zipfile.ZipFile(tmp, "w", mode, allowZip64=True) as zf:
                for name, f in self._files.items():
                    dt, shape = self._dtypes[name]
                    _finish_npy(f, dt, (self._n, *shape))
                    f.close()
                    zf.write(f.name, name + ".npy")
                if self._sensor is None:  # nothing was written: an empty, valid file
                    for name, dt in (("t", np.int64), ("x", np.uint16), ("y", np.uint16), ("p", np.int8)):
                        zf.writestr(name + ".npy", _npy_bytes(np.empty(0, dt)))
                else:
                    zf.writestr("sensor.npy", _npy_bytes(np.array(self._sensor, np.int64)))
                    zf.writestr("interval.npy", _npy_bytes(np.array(self._interval, np.int64)))
            os.replace(tmp, self.path)
        finally:
            self._cleanup()

    def abort(self) -> None:
        self._cleanup()

    def _cleanup(self) -> None:
        for f in self._files.values():
            f.close()
        self._files = {}
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None


def _finish_npy(f: IO[bytes], dtype: np.dtype, shape: tuple[int, ...]) -> None:
    header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape}
    f.flush()
    f.seek(0)
    body = repr(header).encode("latin1")
    pre = b"\x93NUMPY\x01\x00"
    pad = _HEADER - len(pre) - 2 - len(body) - 1
    if pad < 0:
        raise ValueError("npy header too long")
    hdr = body + b" " * pad + b"\n"
    f.write(pre + len(hdr).to_bytes(2, "little") + hdr)
    f.flush()


def _npy_bytes(a: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def write_npz(path: str, packet: EventPacket) -> None:
    """Write one packet to ``path`` (convenience for tests and scripts)."""
    s = NpzSink(path)
    s.open()
    s.write(packet)
    s.close()
