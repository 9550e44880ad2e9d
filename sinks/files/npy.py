"""Structured ``.npy`` writer: one record per event (``t`` int64 µs, ``x``,
``y`` uint16, ``p`` int8 ±1), appended as packets come; the header's shape is
patched on close (the header room is fixed, so nothing is rewritten)."""

from __future__ import annotations

import numpy as np

from tectum import EventPacket

from ._common import FileSink

__all__ = ["NpySink", "EVENT_DTYPE"]

EVENT_DTYPE = np.dtype([("t", "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "i1")])
_HEADER = 128


class NpySink(FileSink):
    """Events to a structured ``.npy`` file (readable by ``numpy.load``)."""

    name = "npy"
    format = "npy"
    title = ".npy"
    extensions = (".npy",)

    def open(self) -> None:
        super().open()
        assert self.f is not None
        self.f.write(b"\0" * _HEADER)

    def _begin(self, packet: EventPacket) -> None:
        pass

    def _empty(self) -> None:
        pass

    def _events(self, packet: EventPacket) -> None:
        assert self.f is not None
        rec = np.empty(len(packet), EVENT_DTYPE)
        rec["t"], rec["x"], rec["y"], rec["p"] = packet.t, packet.x, packet.y, packet.p
        self.f.write(rec.tobytes())

    def _end(self) -> None:
        assert self.f is not None
        header = {"descr": np.lib.format.dtype_to_descr(EVENT_DTYPE), "fortran_order": False,
                  "shape": (self.count,)}
        body = repr(header).encode("latin1")
        pre = b"\x93NUMPY\x01\x00"
        pad = _HEADER - len(pre) - 2 - len(body) - 1
        hdr = body + b" " * pad + b"\n"
        self.f.seek(0)
        self.f.write(pre + len(hdr).to_bytes(2, "little") + hdr)
        self.f.seek(0, 2)
