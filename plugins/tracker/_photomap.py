"""Photometric maps for ``tracker.pose_6dof``: a log-intensity image with
depth, seen from a known view.

A map file is an ``.npz`` with ``image`` (H, W) log intensity, ``depth``
(H, W) m (NaN where unknown), ``K`` (3, 3) px (pinhole intrinsics of the
image, no skew) and ``pose`` (7,) ``tx ty tz qx qy qz qw`` (world-from-camera,
m and a unit quaternion); a :class:`~tectum.MapPacket` on a ``maps`` port
carries the same fields. :func:`load_map` and :func:`map_from_packet` check
them and raise a ValueError (a :class:`tectum.FormatError` for a file) naming
the field and what is wrong; :func:`save_map` writes one.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass

import numpy as np

from tectum import FormatError, MapPacket
from tectum.camera import QUAT_TOL

__all__ = ["PhotoMap", "load_map", "map_from_packet", "save_map", "check_map"]


@dataclass(frozen=True)
class PhotoMap:
    """A checked map: ``image`` (H, W) float64 log intensity, ``depth``
    (H, W) float64 m (NaN unknown), ``K`` (3, 3), ``position`` (3,) m and
    ``orientation`` (4,) x, y, z, w of the map's view (world-from-camera)."""

    image: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    position: np.ndarray
    orientation: np.ndarray

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) px."""
        return int(self.image.shape[1]), int(self.image.shape[0])

    @property
    def pose7(self) -> np.ndarray:
        """``tx ty tz qx qy qz qw``."""
        return np.concatenate([self.position, self.orientation])


def check_map(image: object, depth: object, K: object, pose: object, where: str) -> PhotoMap:
    """The fields as a :class:`PhotoMap`, checked (ValueError naming
    ``where`` and the field otherwise)."""
    img = np.asarray(image)
    dep = np.asarray(depth)
    if img.ndim != 2 or img.shape[0] < 8 or img.shape[1] < 8 or img.dtype.kind not in "fiu":
        raise ValueError(f"{where}: 'image' must be a numeric (H, W) log-intensity image of at least 8x8 px, "
                         f"got {img.dtype} {img.shape}")
    img = img.astype(np.float64)
    if not np.isfinite(img).all():
        raise ValueError(f"{where}: 'image' has {int((~np.isfinite(img)).sum())} non-finite values")
    if dep.shape != img.shape or dep.dtype.kind not in "fiu":
        raise ValueError(f"{where}: 'depth' must be numeric of the image's shape {img.shape}, got {dep.dtype} "
                         f"{dep.shape}")
    dep = dep.astype(np.float64)
    known = np.isfinite(dep)
    if (dep[known] <= 0).any():
        raise ValueError(f"{where}: 'depth' has {int((dep[known] <= 0).sum())} values <= 0 m (NaN marks unknown)")
    if known.sum() < 16:
        raise ValueError(f"{where}: 'depth' is known (finite) at {int(known.sum())} pixels: nothing to track against")
    k = np.asarray(K, np.float64)
    if k.shape != (3, 3) or not np.isfinite(k).all():
        raise ValueError(f"{where}: 'K' must be a finite 3x3 matrix, got shape {k.shape}")
    if not (k[0, 0] > 0 and k[1, 1] > 0 and k[0, 1] == 0 and np.allclose(k[2], [0, 0, 1]) and k[1, 0] == 0):
        raise ValueError(f"{where}: 'K' must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got "
                         f"{k.tolist()}")
    p = np.asarray(pose, np.float64).reshape(-1)
    if p.shape != (7,) or not np.isfinite(p).all():
        raise ValueError(f"{where}: 'pose' must be 7 finite numbers tx ty tz qx qy qz qw, got {p.tolist()}")
    n = float(np.linalg.norm(p[3:]))
    if abs(n - 1.0) > QUAT_TOL:
        raise ValueError(f"{where}: 'pose' orientation has norm {n:.6g}, not a unit quaternion (x, y, z, w)")
    return PhotoMap(img, dep, k, p[:3].copy(), p[3:] / n)


def load_map(path: str) -> PhotoMap:
    """Read and check a map ``.npz`` (see the module)."""
    if not os.path.isfile(path):
        raise FormatError("no such map file (map=FILE.npz: image, depth, K, pose)", path=path)
    if not zipfile.is_zipfile(path):  # np.load would read any other file as a pickle and say so
        raise FormatError("not a .npz map (a zip of arrays image, depth, K, pose)", path=path)
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("image", "depth", "K", "pose") if k not in z.files]
            if missing:
                raise FormatError(f"a map needs arrays image, depth, K and pose; missing {missing} "
                                  f"(has {sorted(z.files)})", path=path)
            fields = {k: z[k] for k in ("image", "depth", "K", "pose")}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as e:
        if isinstance(e, FormatError):
            raise
        raise FormatError(f"not a readable .npz map ({type(e).__name__}: {e})", path=path) from None
    try:
        return check_map(fields["image"], fields["depth"], fields["K"], fields["pose"], "map")
    except ValueError as e:
        raise FormatError(str(e), path=path) from None


def map_from_packet(pkt: MapPacket, i: int) -> PhotoMap:
    """Sample ``i`` of a map stream, checked; it needs ``image``, ``depth``,
    ``K`` and ``pose``."""
    where = f"map at t={int(pkt.t[i])} µs (port 'maps')"
    missing = [k for k in ("image", "depth", "K", "pose") if k not in pkt.data]
    if missing:
        raise ValueError(f"{where}: a photometric map needs image, depth, K and pose; missing {missing}")
    return check_map(pkt.data["image"][i], pkt.data["depth"][i], pkt.data["K"][i], pkt.data["pose"][i], where)


def save_map(path: str, image: np.ndarray, depth: np.ndarray, K: np.ndarray, pose: np.ndarray) -> None:
    """Check and write a map ``.npz`` (``image`` and ``depth`` as float32)."""
    m = check_map(image, depth, K, pose, "save_map")
    np.savez(path, image=m.image.astype(np.float32), depth=m.depth.astype(np.float32), K=m.K, pose=m.pose7)
