"""Feature-position truth: where known points are in the image over time.

Features are the scene's ``features`` (a list of world points [x, y, z] in
m), the corners of every bounded plane and box, and the image-plane
objects' corners (rects and bars: four; disks: the centre). At each pose
sample their image positions (px, pixel centres at integers) are recorded
as ``feature_xy`` (N, F, 2) beside ``feature_t`` (µs), with the feature's
object id in ``feature_object_id`` (F,) and its world point (NaN for
image-plane objects) in ``feature_world`` (F, 3). World points behind the
camera are NaN; occlusion is not tested, and points outside the image keep
their (outside) coordinates.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .motion import Trajectory
from .render import DISK, RECT, SPRITE_STATE, sprite_states
from .scenes import CompiledScene

__all__ = ["Features"]


def _patch_corners(patches: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pts, ids = [], []
    for q in patches:
        if not (np.isfinite(q[12]) and np.isfinite(q[13])):
            continue
        c, a1, a2 = q[0:3], q[3:6], q[6:9]
        for s1, s2 in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            pts.append(c + s1 * q[12] * a1 + s2 * q[13] * a2)
            ids.append(int(q[17]))
    if not pts:
        return np.empty((0, 3)), np.empty(0, np.int16)
    P = np.array(pts)
    # the faces of a box share corners: keep each point once
    _, first = np.unique(np.round(P, 9), axis=0, return_index=True)
    first = np.sort(first)
    return P[first], np.array(ids, np.int16)[first]


class Features:
    """The scene's features and their image positions (see the module doc)."""

    def __init__(self, cs: CompiledScene, scene: Mapping[str, Any]) -> None:
        self.cs = cs
        user = np.asarray(scene.get("features", []), np.float64).reshape(-1, 3)
        corners, cids = _patch_corners(cs.patches)
        self.world = np.concatenate([user, corners])
        self.world_ids = np.concatenate([np.zeros(len(user), np.int16), cids])
        s = cs.sprites
        self.sprite_rows = [k for k in range(s.shape[0]) if int(s[k, 0]) in (DISK, RECT)]
        n_sprite = sum(1 if int(s[k, 0]) == DISK else 4 for k in self.sprite_rows)
        self.count = len(self.world) + n_sprite
        sids = [int(s[k, 17]) for k in self.sprite_rows for _ in range(1 if int(s[k, 0]) == DISK else 4)]
        self.object_id = np.concatenate([self.world_ids, np.array(sids, np.int16)])
        self.world_points = np.concatenate([self.world, np.full((n_sprite, 3), np.nan)])

    def positions(self, traj: Trajectory, t_us: np.ndarray) -> np.ndarray:
        """Image positions (N, F, 2) px at the times ``t_us`` (µs)."""
        cs = self.cs
        out = np.empty((len(t_us), self.count, 2))
        nw = len(self.world)
        for n, t in enumerate(np.asarray(t_us, np.float64)):
            ts = t * 1e-6
            if nw:
                R, p = traj.pose(ts)
                Xc = (self.world - p) @ R  # R^T (X - p), row-wise
                with np.errstate(divide="ignore", invalid="ignore"):
                    u = cs.f * Xc[:, 0] / Xc[:, 2] + cs.cx
                    v = cs.f * Xc[:, 1] / Xc[:, 2] + cs.cy
                behind = Xc[:, 2] <= 0
                u[behind] = np.nan
                v[behind] = np.nan
                out[n, :nw, 0], out[n, :nw, 1] = u, v
            if self.sprite_rows:
                st = sprite_states(cs.sprites, ts, np.empty((cs.sprites.shape[0], SPRITE_STATE)))
                j = nw
                for k in self.sprite_rows:
                    x0, y0, c, s = st[k, 0], st[k, 1], st[k, 2], st[k, 3]
                    if int(cs.sprites[k, 0]) == DISK:
                        out[n, j] = (x0, y0)
                        j += 1
                        continue
                    ha, hb = 0.5 * cs.sprites[k, 7], 0.5 * cs.sprites[k, 8]
                    for lx, ly in ((-ha, -hb), (ha, -hb), (ha, hb), (-ha, hb)):
                        out[n, j] = (x0 + c * lx - s * ly, y0 + s * lx + c * ly)
                        j += 1
        return out
