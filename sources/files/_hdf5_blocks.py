"""Reading HDF5 datasets that may be damaged or truncated.

A chunk whose bytes are damaged fails to decompress (h5py raises OSError
from deep inside HDF5); a truncated file does not even open (HDF5 compares
the end of file its superblock records with the file's size). Here:

* :func:`open_file` opens a truncated file through :class:`PastEnd`, a
  file object that reads zeros past the real end and remembers it did, so
  the chunks before the cut can still be read;
* :class:`BlockReader` reads rows ``[i, j)`` of a few datasets of equal
  length at once and, when that fails (or touched bytes past the end),
  again chunk by chunk: each chunk that cannot be read is a
  :class:`tectum.FormatError` naming the dataset, its rows and the chunk's
  byte offset, or with ``skip_bad`` its rows are dropped and counted once
  (:meth:`FileSource._note_skip` with the chunk's byte range).
"""

from __future__ import annotations

import io
import os
import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ._common import FileSource

__all__ = ["PastEnd", "BlockReader", "open_file", "chunk_bytes"]

class PastEnd(io.RawIOBase):
    """A truncated file as HDF5 expects it: ``size`` bytes long (the end its
    superblock records), zeros past the real end; :attr:`touched` is set
    by any read that reached past it (no data there: it must be dropped)."""

    def __init__(self, path: str, size: int) -> None:
        super().__init__()
        self._f = open(path, "rb")
        self.real = os.fstat(self._f.fileno()).st_size
        self.size = max(size, self.real)
        self._pos = 0
        self.touched = False

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        base = (0, self._pos, self.size)[whence]
        self._pos = base + offset
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, b: Any) -> int:
        view = memoryview(b).cast("B")
        self._f.seek(self._pos)
        got = self._f.readinto(view) or 0
        if got < len(view):
            view[got:] = bytes(len(view) - got)
            self.touched = True
        self._pos += len(view)
        return len(view)

    def close(self) -> None:
        self._f.close()
        super().close()


def open_file(h5py: Any, path: str) -> tuple[Any, PastEnd | None]:
    """``h5py.File`` for ``path`` and, for a truncated file, the
    :class:`PastEnd` it reads through (to close after the file; None
    otherwise). Raises OSError when the file does not open either way."""
    try:
        return h5py.File(path, "r"), None
    except OSError as e:
        m = re.search(r"truncated file: .*stored_eof = (\d+)", str(e))
        if m is None:
            raise
        raw = PastEnd(path, int(m.group(1)))
        try:  # no chunk cache: a chunk read past the end must be seen to be so each time
            return h5py.File(raw, "r", rdcc_nbytes=0), raw
        except BaseException:
            raw.close()
            raise


class BlockReader:
    """Rows of datasets of one file, read for ``src`` (its ``skip_bad``,
    its skip counts); ``past`` is the :class:`PastEnd` of a truncated file."""

    def __init__(self, src: FileSource, past: PastEnd | None) -> None:
        self.src = src
        self.past = past

    def why(self) -> str:
        """What is wrong with the file, for messages."""
        if self.past is not None:
            return f"the file is truncated (it ends at byte {self.past.real} of {self.past.size})"
        return "the file is damaged"

    def read(self, dsets: Sequence[Any], i: int, j: int,
             count: bool = True) -> tuple[list[np.ndarray], np.ndarray | None]:
        """Rows ``[i, j)`` of each of ``dsets`` and the mask of the rows to
        keep (None: all). A chunk that cannot be read raises
        :class:`tectum.FormatError`, or with ``skip_bad`` its rows are
        dropped (in every dataset) and, when ``count``, counted."""
        try:
            out = [self._get(d, i, j) for d in dsets]
            return out, None
        except OSError:
            pass
        keep = np.ones(j - i, np.bool_)
        out = []
        failed: list[tuple[int, int, Any, OSError]] = []
        for d in dsets:
            col = np.zeros((j - i, *d.shape[1:]), d.dtype)
            for a, b in self._blocks(d, i, j):
                try:
                    col[a - i:b - i] = self._get(d, a, b)
                except OSError as e:
                    failed.append((a, b, d, e))
            out.append(col)
        for a, b, d, err in sorted(failed, key=lambda f: f[0]):  # the first rows first, whichever the dataset
            self._bad(d, a, b, err, keep, i, count)
        return out, keep

    def _get(self, d: Any, a: int, b: int) -> np.ndarray:
        if self.past is not None:
            self.past.touched = False
        v = np.asarray(d[a:b])
        if self.past is not None and self.past.touched:
            raise OSError("past the end of the file")
        return v

    def _blocks(self, d: Any, i: int, j: int) -> list[tuple[int, int]]:
        """``[i, j)`` cut at the chunk boundaries of ``d`` (an unchunked
        dataset at the first row past the end of a truncated file)."""
        if d.chunks:
            step = d.chunks[0]
            cuts = list(range((i // step + 1) * step, j, step))
        else:
            at, size = chunk_bytes(d, 0)
            end = (self.past.real - at) // size if self.past is not None and size else j
            cuts = [end] if i < end < j else []
        return list(zip([i, *cuts], [*cuts, j]))

    def _bad(self, d: Any, a: int, b: int, e: OSError, keep: np.ndarray, i: int, count: bool) -> None:
        """Rows ``[a, b)`` of ``d`` (the mask ``keep`` starts at row ``i``)
        did not read: raise, or drop them, counting the rows not dropped yet."""
        at, size = chunk_bytes(d, a)
        m = re.search(r"\(([^()]*)\)\s*$", str(e))
        reason = m.group(1) if m else str(e)
        if d.chunks:
            c = a // d.chunks[0] * d.chunks[0]
            what = f"chunk of rows {c}-{min(c + d.chunks[0], d.shape[0]) - 1}"
        else:
            what = f"rows {a}-{b - 1}"
        if not self.src.skip_bad:
            self.src._fail(f"{d.name}: the {what} cannot be read ({reason}): {self.why()}", at)
        new = int(np.count_nonzero(keep[a - i:b - i]))
        keep[a - i:b - i] = False
        if count and new:
            self.src._note_skip(at, at + size, new)


def chunk_bytes(d: Any, row: int) -> tuple[int, int]:
    """Byte offset and stored size of the chunk of ``d`` holding ``row``
    (of the rows from there, unchunked); (0, 0) when the file cannot say."""
    try:
        if d.chunks:
            info = d.id.get_chunk_info_by_coord((row // d.chunks[0] * d.chunks[0],) + (0,) * (d.ndim - 1))
            return int(info.byte_offset), int(info.size)
        itemsize = d.dtype.itemsize * int(np.prod(d.shape[1:], dtype=np.int64))
        return int(d.id.get_offset()) + row * itemsize, itemsize
    except (OSError, TypeError, ValueError, AttributeError):
        return 0, 0
