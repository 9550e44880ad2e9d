"""Recycled blocks of frames for the ``repr`` operators.

A block of frames handed out in a packet is the consumer's: nothing writes
it while anyone can still read it. A pool keeps a reference to each block
it made (up to :data:`POOL_BYTES`) and hands a block out again only when
that reference is the last one: no packet, frame, view, buffer export
(``memoryview``, a C extension's ``Py_buffer``) or weak reference to it is
left anywhere. Every way to read an array's memory later holds a
reference to the array that owns it (a view holds its base, an export its
exporter), so the last reference means nobody can read the block again:
reusing it is the allocator handing out freed memory, minus the page
faults and the zeroing of fresh pages (a 720 kB frame is 176 fresh pages a
window) that made frames cost more than the events in them.
"""

from __future__ import annotations

import sys
import threading
import weakref
from collections import OrderedDict

import numpy as np

__all__ = ["Block", "FramePool", "pool", "POOL_BYTES", "POOLS", "SHARED_BYTES"]

#: the most bytes of blocks one pool keeps for reuse (blocks are plain
#: ``np.zeros``: numpy advises huge pages for them, and gets them for the
#: 2 MB pages wholly inside, 4 of a 5.5 MB block of event frames; a block
#: in a map of its own aligned to 2 MB, all on huge pages, zeroed a 720 kB
#: frame in 8.4 us against 10.2 on 4 kB pages, but frames through a
#: pipeline did not gain: 0.98x, 1.00, 1.00 at 0.5, 2, 5 Mev/s, per round)
POOL_BYTES = 1 << 26
#: the most pools (frame shapes and dtypes) kept, the last used
POOLS = 4
#: frames smaller than this (bytes) are not pooled across operators
SHARED_BYTES = 1 << 14


class Block:
    """``images`` (g, *frame shape) and ``flat``, the same as one flat view;
    for images that must start at zero, where each frame was written:
    ``marks[k, :n_marks[k]]`` (flat indices in frame ``k``; ``n_marks[k]``
    -1: anywhere, 0: nowhere, as a new block)."""

    __slots__ = ("images", "flat", "marks", "n_marks")

    def __init__(self, images: np.ndarray, marks: int) -> None:
        self.images, self.flat = images, images.reshape(-1)
        self.marks = np.empty((images.shape[0], marks), np.uint32)
        self.n_marks = np.zeros(images.shape[0], np.int64)


def _refs(b: Block) -> int:
    return sys.getrefcount(b.images)


#: what :func:`_refs` says of a block's images that only the block holds
#: (the pool's own reference plus what the call adds, measured here rather
#: than assumed: interpreters differ in what a call's argument costs)
_ALONE = _refs(Block(np.zeros(1), 0))


def _unshared(b: Block) -> bool:
    """Nobody but the pool holds ``b``'s images (nor a weak reference)."""
    return _refs(b) == _ALONE and not weakref.getweakrefcount(b.images)


class FramePool:
    """Blocks of ``per_block`` frames of ``shape`` and ``dtype``. ``marks``:
    how many written indices a frame records for its next zeroing (0: the
    frames are overwritten whole, or start at zero some other way). Use
    :func:`pool` (shared by the operators of a process, so a pipeline built
    again finds the blocks the last one freed)."""

    def __init__(self, shape: tuple[int, ...], dtype: np.dtype, per_block: int, marks: int, max_blocks: int) -> None:
        self.shape, self.dtype, self.per_block, self.n_marks = shape, dtype, per_block, marks
        self.max_blocks = max_blocks
        self._blocks: list[Block] = []
        self._lock = threading.Lock()  # operators in several threads may share the pool

    def take(self, skip: int = 0) -> tuple[Block, np.ndarray]:
        """The free block handed out last (the likeliest still in cache: a
        720 kB frame written cold costs 4x one written in cache), else a new
        zeroed one (kept while the pool has room). Free: nobody else holds
        it; it is dirty as its ``n_marks`` say. Returned with a reference to
        its images, taken under the lock: hold it (or views of it) while
        the block is in use, so no other thread takes the block meanwhile.
        ``skip``: the blocks the caller took last and still holds (the last
        ones out): not looked at again (a caller taking k blocks looks at
        each block once, not k times; a wrong count only passes a free block
        by)."""
        with self._lock:
            blocks = self._blocks
            for j in range(len(blocks) - 1 - skip, -1, -1):  # blocks in the order they went out
                b = blocks[j]
                if _unshared(b):
                    del blocks[j]
                    blocks.append(b)
                    return b, b.images
            b = Block(np.zeros((self.per_block, *self.shape), self.dtype), self.n_marks)
            if len(blocks) < self.max_blocks:
                blocks.append(b)
            return b, b.images


_POOLS: OrderedDict[tuple[object, ...], FramePool] = OrderedDict()
_POOLS_LOCK = threading.Lock()


def pool(shape: tuple[int, ...], dtype: np.dtype, per_block: int, marks: int = 0) -> FramePool:
    """The process's pool of blocks of ``per_block`` frames of ``shape`` and
    ``dtype`` (``marks``: see :class:`FramePool`). Pools last while they are
    among the :data:`POOLS` used last; each keeps at most
    :data:`POOL_BYTES` of blocks, and only as many as were out at once.
    Frames under :data:`SHARED_BYTES` get a pool of their own (an
    operator's warm-up on a tiny sensor, tests), not shared."""
    frame_bytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
    max_blocks = max(1, POOL_BYTES // max(frame_bytes * per_block, 1))
    if frame_bytes < SHARED_BYTES:  # the operator's own: small frames do not push others out
        return FramePool(tuple(shape), np.dtype(dtype), per_block, marks, max_blocks)
    key = (tuple(shape), np.dtype(dtype).str, per_block, marks)
    with _POOLS_LOCK:
        p = _POOLS.get(key)
        if p is None:
            p = _POOLS[key] = FramePool(tuple(shape), np.dtype(dtype), per_block, marks, max_blocks)
            while len(_POOLS) > POOLS:
                _POOLS.popitem(last=False)
        _POOLS.move_to_end(key)
        return p
