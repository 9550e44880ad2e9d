"""A DAVIS turning over a textured panorama, and where any pixel goes:
scenes and truth for feature trackers (``tracker.features``).

Under pure rotation a pixel's path does not depend on depth: the pixel
``x0`` seen at ``t0`` is the ray ``R(t0) K⁻¹ x0`` in the world, which at
``t`` projects to ``π(K R(t)ᵀ R(t0) K⁻¹ x0)`` (``R`` world-from-camera,
slerped between the truth's poses). So every corner a tracker picks has a
truth track, not only the scene's listed features
(:mod:`.features`' ``feature_xy``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from tectum import EventPacket, FramePacket, concat

from . import make_simulator
from .scenes import BUILTIN
from .truth import Truth

__all__ = ["davis_rotation_scene", "davis_rotation", "rotation_tracks"]


def davis_rotation_scene(sensor: tuple[int, int], *, aps_rate_hz: float = 20.0, exposure_us: float = 2000.0,
                         speed: float = 1.0, contrast: float = 0.6) -> dict[str, Any]:
    """The built-in ``rotation`` scene with APS frames at ``aps_rate_hz``
    (exposure ``exposure_us`` µs), its motion scaled by ``speed`` and its
    texture's contrast set to ``contrast``."""
    d = BUILTIN["rotation"](*sensor)
    d["panorama"]["texture"]["contrast"] = float(contrast)
    m = d["motion"]
    for key in ("angular_velocity", "rotation_amplitude"):
        m[key] = [float(v) * speed for v in m[key]]
    d["davis"] = {"aps_rate_hz": float(aps_rate_hz), "exposure_us": float(exposure_us)}
    return d


def davis_rotation(sensor: tuple[int, int], duration_us: int, *, aps_rate_hz: float = 20.0, seed: int = 0,
                   preset: str = "ideal", speed: float = 1.0, contrast: float = 0.6,
                   **model: Any) -> tuple[EventPacket, FramePacket, Truth]:
    """Simulate :func:`davis_rotation_scene`: (events, APS frames, truth)."""
    scene = davis_rotation_scene(sensor, aps_rate_hz=aps_rate_hz, speed=speed, contrast=contrast)
    sim = make_simulator(scene, duration_us, seed=seed, preset=preset, sensor=sensor, **model)
    evs, frames = [], []
    for ev, side in sim.windows(10_000):
        evs.append(ev)
        frames += [s for s in side if isinstance(s, FramePacket)]
    events, fr = concat(evs), concat(frames)
    assert isinstance(events, EventPacket) and isinstance(fr, FramePacket)
    return events, fr, sim.truth


def rotation_tracks(truth: Truth, t0: np.ndarray, xy0: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Truth positions (n, 2) px at times ``t`` (n,) µs of the pixels
    ``xy0`` (n, 2) px seen at ``t0`` (n,) µs, for a camera that only
    rotates (see the module doc); NaN outside the poses' span or behind the
    camera."""
    f, cx, cy = (float(v) for v in truth["camera"])
    pt = np.asarray(truth["pose_t"], np.float64)
    slerp = Slerp(pt, Rotation.from_quat(np.asarray(truth["pose_orientation"])))
    t0 = np.asarray(t0, np.float64)
    t = np.asarray(t, np.float64)
    ok = (t0 >= pt[0]) & (t0 <= pt[-1]) & (t >= pt[0]) & (t <= pt[-1])
    out = np.full((len(t), 2), np.nan)
    if not ok.any():
        return out
    R0 = slerp(t0[ok]).as_matrix()
    R1 = slerp(t[ok]).as_matrix()
    xy = np.asarray(xy0, np.float64)[ok]
    ray = np.stack([(xy[:, 0] - cx) / f, (xy[:, 1] - cy) / f, np.ones(len(xy))], axis=1)
    world = np.einsum("nij,nj->ni", R0, ray)
    cam = np.einsum("nji,nj->ni", R1, world)  # R1ᵀ world
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(cam[:, 2] > 0, f * cam[:, 0] / cam[:, 2] + cx, np.nan)
        v = np.where(cam[:, 2] > 0, f * cam[:, 1] / cam[:, 2] + cy, np.nan)
    out[ok, 0], out[ok, 1] = u, v
    return out
