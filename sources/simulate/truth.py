"""Ground truth sampled in time, beside the events, with bounded memory.

Every series (poses, IMU, dense truth maps, APS images, per-event truth
kept out of the packets) is appended to a raw file in a temporary folder as
it comes and read back as a memory map, so a long run holds none of it in
memory; :meth:`Truth.save` streams everything into one ``.npz``. The folder is removed when the Truth
is garbage-collected (or at :meth:`Truth.close`).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import weakref
import zipfile
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Truth"]

_COPY_CHUNK = 1 << 22


@dataclass
class _Spilled:
    path: str
    dtype: np.dtype
    row_shape: tuple[int, ...]
    rows: int = 0


@dataclass
class Truth:
    """Ground truth sampled in time, beside the events (arrays by name).

    ``pose_*`` at ``pose_rate_hz``: ``pose_t`` µs, ``pose_position`` m,
    ``pose_orientation`` xyzw (world-from-camera), ``pose_angular_velocity``
    rad/s (camera frame), ``pose_velocity`` m/s (world). ``frame_*`` at
    ``truth_fps``: ``frame_intensity`` (linear, 1 = full scale),
    ``frame_depth`` (m; inf at infinity, NaN for image-plane objects),
    ``frame_vx``/``frame_vy`` px/s, ``frame_object_id``. ``aps_*`` and
    ``imu_*`` when the scene's ``davis`` section asks. ``camera`` is
    ``(f, cx, cy)`` px, ``sensor`` ``(w, h)``. Series live on disk (see the
    module doc); ``spill=False`` keeps them in memory.
    """

    meta: dict[str, Any] = field(default_factory=dict)
    parts: dict[str, list[np.ndarray]] = field(default_factory=dict)
    spill: bool = True
    spilled: dict[str, _Spilled] = field(default_factory=dict)
    _dir: str | None = None

    def _folder(self) -> str:
        if self._dir is None:
            self._dir = tempfile.mkdtemp(prefix="tectum-truth-")
            self._finalizer = weakref.finalize(self, shutil.rmtree, self._dir, True)
        return self._dir

    def add(self, **arrays: Any) -> None:
        """Append rows (along the first axis) to the named series."""
        for k, v in arrays.items():
            a = np.asarray(v)
            if a.ndim == 0:
                a = a[None]
            if self.spill:
                self._append(k, a)
            else:
                self.parts.setdefault(k, []).append(a)

    def _append(self, key: str, a: np.ndarray) -> None:
        sp = self.spilled.get(key)
        if sp is None:
            sp = self.spilled[key] = _Spilled(os.path.join(self._folder(), key + ".bin"), a.dtype, a.shape[1:])
        if a.shape[1:] != sp.row_shape or a.dtype != sp.dtype:
            raise ValueError(f"truth {key!r}: rows of {a.dtype}{a.shape[1:]} after {sp.dtype}{sp.row_shape}")
        with open(sp.path, "ab") as f:
            f.write(np.ascontiguousarray(a).tobytes())
        sp.rows += a.shape[0]

    def __getitem__(self, key: str) -> np.ndarray:
        if key in self.meta:
            return np.asarray(self.meta[key])
        sp = self.spilled.get(key)
        if sp is not None:
            if sp.rows == 0:
                return np.empty((0, *sp.row_shape), sp.dtype)
            return np.memmap(sp.path, sp.dtype, "r", shape=(sp.rows, *sp.row_shape))
        parts = self.parts.get(key)
        if not parts:
            raise KeyError(key)
        return np.concatenate(parts) if len(parts) > 1 else parts[0]

    def keys(self) -> list[str]:
        return list(self.meta) + list(self.parts) + list(self.spilled)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: self[k] for k in self.keys()}

    def save(self, path: str) -> None:
        """Write every array to an ``.npz`` file (dense maps copied from
        disk in chunks: memory stays bounded)."""
        tmp = str(path) + ".part"
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            for k in self.keys():
                with zf.open(k + ".npy", "w", force_zip64=True) as out:
                    sp = self.spilled.get(k)
                    if sp is None:
                        np.lib.format.write_array(out, np.asarray(self[k]), allow_pickle=False)
                        continue
                    header = {"descr": np.lib.format.dtype_to_descr(sp.dtype), "fortran_order": False,
                              "shape": (sp.rows, *sp.row_shape)}
                    np.lib.format.write_array_header_2_0(out, header)
                    with open(sp.path, "rb") as src:
                        shutil.copyfileobj(src, out, _COPY_CHUNK)
        os.replace(tmp, path)

    def close(self) -> None:
        """Remove the spilled maps (the Truth is empty of them afterwards)."""
        if self._dir is not None:
            self._finalizer()
            self._dir = None
        self.spilled.clear()
