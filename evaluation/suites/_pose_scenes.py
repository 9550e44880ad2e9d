"""Simulated 6-DoF scenes for ``tracker.pose_6dof`` (tests and the ``pose``
bench): a textured plane and textured boxes before a wall, the camera
oscillating in all six degrees of freedom at a chosen peak speed.

Textures are smooth at the pixel scale (a noise texel of 1-2 px at 240x180
from 2 m), so a batch of events sees a brightness increment the map can
predict; the peak rotation speed ``deg_s`` (°/s) and translation speed
``m_s`` (m/s) are those of the sinusoids (amplitude × 2π × frequency).
The field of view is 90° by default (a wide lens: with 60° the translation
along the image plane and the rotation that shifts the image the same way
are harder to tell apart, and the position errors double).
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["plane", "boxes"]


def _motion(m_s: float, deg_s: float, freq_hz: float = 2.0) -> dict[str, Any]:
    w = 2 * math.pi * freq_hz
    a = m_s / w  # m, per axis scaled below
    r = math.radians(deg_s) / w
    return {"position_amplitude": [a, 0.7 * a, 0.5 * a], "position_freq_hz": [freq_hz, freq_hz, freq_hz],
            "position_phase": [0.0, 0.25, 0.5],
            "rotation_amplitude": [0.6 * r, r, 0.4 * r], "rotation_freq_hz": [freq_hz, freq_hz, freq_hz]}


def plane(m_s: float = 0.5, deg_s: float = 30.0, texel_m: float = 0.02, contrast: float = 0.5,
          freq_hz: float = 2.0, fov_deg: float = 90.0) -> dict[str, Any]:
    """A noise-textured plane 2 m in front of the camera's start."""
    return {"name": "pose_plane", "description": "6-DoF camera before a textured plane at 2 m", "fov_deg": fov_deg,
            "planes": [{"center": [0, 0, 2.0], "texture": {"kind": "noise", "size": 512, "contrast": contrast,
                                                          "blur": 2.0}, "texel_m": texel_m}],
            "motion": _motion(m_s, deg_s, freq_hz)}


def boxes(m_s: float = 0.5, deg_s: float = 30.0, freq_hz: float = 2.0, fov_deg: float = 90.0) -> dict[str, Any]:
    """Two textured boxes at 2-2.6 m before a textured wall at 4 m."""
    tex = {"kind": "noise", "size": 256, "contrast": 0.5, "blur": 2.0}
    return {"name": "pose_boxes", "description": "6-DoF camera before textured boxes and a wall",
            "planes": [{"center": [0, 0, 4.0], "texture": {**tex, "seed": 1}, "texel_m": 0.04}],
            "boxes": [{"center": [-0.5, 0.2, 2.0], "size": [0.5, 0.6, 0.5], "orientation": [0, 0.4, 0],
                       "texture": {**tex, "seed": 2}, "texel_m": 0.015},
                      {"center": [0.5, -0.2, 2.6], "size": [0.6, 0.7, 0.6], "orientation": [0, -0.3, 0],
                       "texture": {**tex, "seed": 3}, "texel_m": 0.02}],
            "motion": _motion(m_s, deg_s, freq_hz), "sim": {"supersample": 2}, "fov_deg": fov_deg}
