"""Photometric maps of simulated scenes, for ``tracker.pose_6dof``: the
scene's true log intensity ``log(I + eps)`` (the sensor model's ``eps``),
its depth (m along the optical axis; NaN where the ray meets nothing at a
finite distance: the panorama, image-plane objects, empty space), the
intrinsics ``K`` and the camera's pose at a chosen time, as the map file
``tracker.pose_6dof`` reads (``image``, ``depth``, ``K``, ``pose``).

Python::

    from tectum.sources.simulate.photomap import scene_map, write_scene_map
    m = scene_map("plane_6dof", t_us=0, sensor="240x180")   # dict of arrays
    write_scene_map("map.npz", "plane_6dof", t_us=0, sensor="240x180")

CLI: ``tectum simulate SCENE --out events.npz --map map.npz [--map-time 50ms]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from tectum.camera import rot_to_quat

from . import make_simulator

__all__ = ["scene_map", "write_scene_map"]


def scene_map(scene: str | Mapping[str, Any], t_us: float = 0.0, *, sensor: Any = None, seed: int = 0,
              preset: str = "ideal", **model: Any) -> dict[str, np.ndarray]:
    """The map of ``scene`` seen at ``t_us`` (µs): ``image`` (H, W) float32
    log intensity, ``depth`` (H, W) float32 m (NaN unknown), ``K`` (3, 3) px,
    ``pose`` (7,) ``tx ty tz qx qy qz qw`` (world-from-camera)."""
    sim = make_simulator(scene, max(int(t_us) + 1, 1), seed=seed, preset=preset, sensor=sensor, **model)
    if sim.video is not None:
        raise ValueError("scene_map: a video scene has no depth (no 3-D world to map)")
    if not sim.cs.has_world:
        raise ValueError("scene_map: the scene has no 3-D world (planes, boxes): nothing has a depth")
    image = np.log(np.maximum(sim.render(float(t_us)), 0.0) + sim.model.eps)
    h, w = image.shape
    ys, xs = (a.ravel().astype(np.float64) for a in np.mgrid[0:h, 0:w])
    _, _, _, depth = sim.probe(xs, ys, float(t_us))
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).reshape(h, w)
    if not np.isfinite(depth).any():
        raise ValueError(f"scene_map: nothing in view at {t_us:g} µs has a finite depth (a panorama or image-plane "
                         "objects only): no map to track against")
    cs = sim.cs
    K = np.array([[cs.f, 0.0, cs.cx], [0.0, cs.f, cs.cy], [0.0, 0.0, 1.0]])
    R, p = sim.pose(float(t_us) * 1e-6)
    pose = np.concatenate([np.asarray(p, np.float64), rot_to_quat(np.asarray(R, np.float64))])
    return {"image": image.astype(np.float32), "depth": depth.astype(np.float32), "K": K, "pose": pose}


def write_scene_map(path: str, scene: str | Mapping[str, Any], t_us: float = 0.0, **kw: Any) -> dict[str, np.ndarray]:
    """:func:`scene_map` written to ``path`` (an ``.npz``); returns the map."""
    m = scene_map(scene, t_us, **kw)
    with open(path, "wb") as f:
        np.savez(f, image=m["image"], depth=m["depth"], K=m["K"], pose=m["pose"])
    return m
