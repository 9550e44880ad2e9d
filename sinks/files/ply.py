"""Point clouds to PLY (``.ply``), ASCII or binary little-endian.

One ``vertex`` element, a row per point of the stream::

    ply
    format ascii 1.0            (binary_little_endian 1.0 with ?binary=true)
    comment tectum points
    element vertex N
    property double x
    property double y
    property double z
    property float intensity    (when the stream has intensities)
    property double t_us
    comment                     (padding: the header has a fixed size)
    end_header

``x y z`` in metres (float64, as ``double``), ``intensity`` float32, and
the point's time ``t_us`` in µs as a ``double``: PLY has no 64-bit integer
type, and a double holds every integer up to 2**53 µs (285 years) exactly,
so reading back restores the integer µs (times beyond that are refused).
Rows sharing a ``t_us`` form one cloud. ASCII numbers are printed with the
fewest digits that read back to the same value. Other fields have no place
in the format: a stream that carries them is refused (write ``.csv`` or
``.npz``). :class:`tectum.sources.files.ply.PlySource` reads the file back,
as do other tools.
"""

from __future__ import annotations

import numpy as np

from tectum import Kind, SamplePacket
from tectum.tables import Group, layout, ply_header

from ._rows import SampleFileSink, text_rows

__all__ = ["PlySink"]

#: Bytes of the header (fixed, so that the vertex count can be written at the end).
HEADER_BYTES = 512
#: Largest |t| in µs a double holds exactly.
MAX_T = 1 << 53
_PLY_TYPE = {"f8": "double", "f4": "float"}


class PlySink(SampleFileSink):
    """Point clouds (``PointPacket``) to a PLY file.

    Parameters
    ----------
    path:
        The output file; replaced atomically when the run ends well.
    binary:
        Binary little-endian rows instead of ASCII text.
    """

    name = "ply"
    format = "ply"
    title = "PLY"
    extensions = (".ply",)
    consumes = (Kind.POINTS,)
    kind = Kind.POINTS

    def __init__(self, path: str, binary: bool = False) -> None:
        super().__init__(path)
        self.binary = binary

    def open(self) -> None:
        super().open()
        assert self.f is not None
        self.f.write(b"\n" * HEADER_BYTES)  # the header's room, written in _end

    def _layout(self, cls: type[SamplePacket], data: dict[str, np.ndarray]) -> list[Group]:
        other = sorted(set(data) - {"position", "intensity"})
        if other:
            raise ValueError(f"ply: field(s) {other} have no place in a PLY file (position, intensity and t "
                             "have): write .csv or .npz")
        return layout(cls, data)

    def _properties(self) -> list[tuple[str, str]]:
        assert self.groups is not None
        props = [(c, _PLY_TYPE[g.dtype.str[1:]]) for g in self.groups for c in g.columns]
        return [*props, ("t_us", "double")]

    def _head(self) -> None:
        """The header is written in :meth:`_end`, when the count is known."""

    def _rows(self, t: np.ndarray, data: dict[str, np.ndarray]) -> None:
        assert self.f is not None and self.groups is not None
        if int(np.abs(t).max()) > MAX_T:
            raise ValueError(f"ply: t={int(t[np.argmax(np.abs(t))])} µs is beyond 2**53 µs, which a PLY double "
                             "holds exactly")
        if not self.binary:
            self._put(text_rows(t, data, self.groups, " ", time_last=True))
            return
        rec = np.empty(len(t), [(n, "<f8" if ty == "double" else "<f4") for n, ty in self._properties()])
        for g in self.groups:
            a = data[g.field]
            for j, c in enumerate(g.columns):
                rec[c] = a if g.width is None else a[:, j]
        rec["t_us"] = t
        self.f.write(rec.tobytes())

    def _end(self) -> None:
        assert self.f is not None
        head = ply_header(self.binary, self.rows, self._properties(), ["tectum points"], size=HEADER_BYTES)
        self.f.seek(0)
        self.f.write(head)
        self.f.seek(0, 2)
