"""Truth for trackers of things that move in the image: where each
image-plane object is (:func:`object_truth`), and a rigid body carrying
blinking LEDs with its true pose (:class:`LedBody`).

Image-plane objects (a scene's ``objects``) move on straight lines, bouncing
off their boxes; :func:`object_truth` evaluates the renderer's own motion
(:func:`~.render.sprite_states`) at any times, so the positions are the ones
the events were drawn from.

An :class:`LedBody` is a rigid set of LEDs (points in the body frame, m,
each with its blink frequency, Hz) held at a fixed orientation in front of
a static camera and translating parallel to the image plane at constant
speed, bouncing between two positions. Under that motion each LED's image
moves on a straight line at its own speed (``f v / z``: nearer LEDs move
faster), exactly what the simulator's image-plane disks do, so the scene is
a set of blinking disks (:meth:`LedBody.scene`) and the truth is exact: the
body's pose in the camera frame at any time (:meth:`LedBody.poses`) and
each LED's image position (:meth:`LedBody.image_points`). Disks are drawn
with a fixed radius in px (an LED is a point source blurred by the optics).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tectum.camera import rot_to_quat, so3_exp

from .render import SPRITE_STATE, sprite_states
from .scenes import compile_scene, load_scene

__all__ = ["object_truth", "moving_objects", "LedBody", "triangle"]


def object_truth(scene: str | Mapping[str, Any], t_us: Sequence[int] | np.ndarray,
                 sensor: Any = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image-plane objects of ``scene`` at times ``t_us`` (µs): ``(ids (m,),
    centres (n, m, 2) px, velocities (n, m, 2) px/s)``; pixel centres at
    integer coordinates, as the events."""
    cs = compile_scene(load_scene(scene, sensor))
    sp = cs.sprites
    t = np.asarray(t_us, np.float64)
    xy = np.empty((len(t), sp.shape[0], 2))
    v = np.empty_like(xy)
    st = np.empty((sp.shape[0], SPRITE_STATE))
    for i, ti in enumerate(t):
        sprite_states(sp, ti * 1e-6, st)
        xy[i] = st[:, 0:2]
        v[i] = st[:, 6:8]
    return sp[:, 17].astype(np.int64), xy, v


def moving_objects(n: int = 4, sensor: tuple[int, int] = (160, 120), speed_px_s: float = 200.0, radius_px: float = 8.0,
                   seed: int = 0, texture: bool = False) -> dict[str, Any]:
    """A scene of ``n`` disks (ids 1..n) moving at ``speed_px_s`` in random
    directions from random places, bouncing off the sensor's sides, over a
    plain background (or a faint static texture): the cluster tracker's
    scene. Disks are drawn in id order (a later one passes over an earlier
    one)."""
    rng = np.random.default_rng(seed)
    w, h = sensor
    objs = []
    for i in range(n):
        a = rng.uniform(0, 2 * np.pi)
        r = radius_px * rng.uniform(0.8, 1.25)
        objs.append({"shape": "disk", "position": [float(rng.uniform(r, w - 1 - r)), float(rng.uniform(r, h - 1 - r))],
                     "radius": float(r), "velocity": [speed_px_s * float(np.cos(a)), speed_px_s * float(np.sin(a))],
                     "intensity": float(rng.uniform(0.6, 0.9)), "bounce": True, "id": i + 1})
    bg: dict[str, Any] = {"intensity": 0.15}
    if texture:
        bg = {"texture": {"kind": "noise", "contrast": 0.3, "mean": 0.15}, "texel_px": 2.0}
    return {"name": "moving_objects", "description": f"{n} disks moving at {speed_px_s:g} px/s",
            "sensor": [w, h], "background": bg, "objects": objs}


def triangle(u0: float, v: float, t: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Position at times ``t`` (s) of a point starting at ``u0`` with speed
    ``v`` bouncing between ``lo`` and ``hi`` (no bounds when ``hi <= lo``):
    the renderer's bounce, vectorised."""
    u = u0 + v * np.asarray(t, np.float64)
    if hi <= lo:
        return u
    span = hi - lo
    q = np.mod(u - lo, 2 * span)
    return np.where(q <= span, lo + q, lo + 2 * span - q)


@dataclass(frozen=True)
class LedBody:
    """A rigid body with blinking LEDs in front of a static camera (see the module).

    points:
        LED positions in the body frame, m (n, 3).
    freqs_hz:
        Blink frequency of each LED, Hz (square wave, ``duty``, ``rise_us``).
    rvec:
        The body's orientation in the camera frame (rotation vector, rad),
        constant; OpenCV camera axes (x right, y down, z forward).
    position:
        The body origin in the camera frame at t = 0, m.
    velocity:
        Its velocity (vx, vy) parallel to the image plane, m/s.
    bounce:
        Half range (m) of the bounce about ``position`` per axis (0: no bounce).
    sensor, focal_px:
        The camera: pinhole, principal point at the sensor's centre ``((w - 1) / 2, (h - 1) / 2)``.
    radius_px, on, off, background:
        LED disks' radius (px) and linear intensities when on and off, and the background's.
    flicker:
        Extra blinking disks that are not markers: (x, y, radius px, Hz) each,
        e.g. lamps on 50 Hz mains flickering at 100 Hz.
    """

    points: tuple[tuple[float, float, float], ...]
    freqs_hz: tuple[float, ...]
    rvec: tuple[float, float, float] = (0.3, -0.2, 0.1)
    position: tuple[float, float, float] = (0.0, 0.0, 1.0)
    velocity: tuple[float, float] = (0.2, 0.1)
    bounce: tuple[float, float] = (0.12, 0.08)
    sensor: tuple[int, int] = (160, 120)
    focal_px: float = 150.0
    radius_px: float = 2.0
    duty: float = 0.5
    rise_us: float = 20.0
    on: float = 1.0
    off: float = 0.05
    background: float = 0.05
    flicker: tuple[tuple[float, float, float, float], ...] = field(default=())

    def __post_init__(self) -> None:
        if len(self.points) != len(self.freqs_hz):
            raise ValueError("LedBody: one frequency per point")

    @property
    def K(self) -> np.ndarray:
        """Intrinsics (3, 3), px."""
        w, h = self.sensor
        return np.array([[self.focal_px, 0, (w - 1) / 2], [0, self.focal_px, (h - 1) / 2], [0, 0, 1.0]])

    @property
    def R(self) -> np.ndarray:
        """Camera-from-body rotation (3, 3)."""
        return so3_exp(np.asarray(self.rvec, np.float64))

    @property
    def calib(self) -> str:
        """The intrinsics inline, ``fx;fy;cx;cy`` (an operator's ``calib=``)."""
        K = self.K
        return ";".join(repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))

    def _axis(self, k: int, t_s: np.ndarray) -> np.ndarray:
        b = self.bounce[k]
        p0 = self.position[k]
        return triangle(p0, self.velocity[k], t_s, p0 - b, p0 + b)

    def poses(self, t_us: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The body in the camera frame at ``t_us`` (µs): positions (n, 3) m
        and orientations (n, 4) x, y, z, w (camera-from-body)."""
        t = np.asarray(t_us, np.float64) * 1e-6
        pos = np.stack([self._axis(0, t), self._axis(1, t), np.full(len(t), self.position[2])], axis=1)
        q = np.tile(rot_to_quat(self.R), (len(t), 1))
        return pos, q

    def image_points(self, t_us: Sequence[int] | np.ndarray) -> np.ndarray:
        """Each LED's image position at ``t_us`` (µs): (n, LEDs, 2) px."""
        pos, _ = self.poses(t_us)
        P = np.asarray(self.points, np.float64) @ self.R.T  # (L, 3), camera axes, body at origin
        c = pos[:, None, :] + P[None]
        K = self.K
        return np.stack([K[0, 0] * c[..., 0] / c[..., 2] + K[0, 2], K[1, 1] * c[..., 1] / c[..., 2] + K[1, 2]], axis=2)

    def scene(self) -> dict[str, Any]:
        """The simulator scene: one blinking disk per LED moving as its
        image does (straight line, bouncing with the body), then the flicker lamps."""
        P = np.asarray(self.points, np.float64) @ self.R.T
        K = self.K
        objs: list[dict[str, Any]] = []
        for i, (p, hz) in enumerate(zip(P, self.freqs_hz)):
            z = p[2] + self.position[2]
            if z <= 0:
                raise ValueError(f"LedBody: LED {i} is behind the camera (z = {z} m)")
            a = (K[0, 0] * p[0] / z + K[0, 2], K[1, 1] * p[1] / z + K[1, 2])
            b = (K[0, 0] / z, K[1, 1] / z)
            pos = [a[k] + b[k] * self.position[k] for k in range(2)]
            box = [a[k] + b[k] * (self.position[k] - self.bounce[k]) for k in range(2)] + \
                  [a[k] + b[k] * (self.position[k] + self.bounce[k]) for k in range(2)]
            vel = [b[0] * self.velocity[0], b[1] * self.velocity[1]]
            objs.append({"shape": "disk", "position": pos, "velocity": vel,
                         "radius": self.radius_px, "intensity": self.on, "intensity_off": self.off,
                         "blink_hz": float(hz), "blink_duty": self.duty, "blink_rise_us": self.rise_us, "id": i + 1,
                         "bounce": box if any(self.bounce) else False})
        for j, (x, y, r, hz) in enumerate(self.flicker):
            objs.insert(0, {"shape": "disk", "position": [x, y], "radius": r, "intensity": 0.6,
                            "intensity_off": 0.15, "blink_hz": hz, "blink_duty": 0.5,
                            "blink_rise_us": 0.45e6 / hz, "id": 100 + j})
        return {"name": "led_body", "description": "LEDs blinking at distinct frequencies on a moving rigid body",
                "sensor": list(self.sensor), "focal_px": self.focal_px, "background": {"intensity": self.background},
                "objects": objs}

    def layout_text(self) -> str:
        """The LEDs as a ``layout=`` file (see :mod:`tectum.plugins.tracker.layout`)."""
        rows = ["# LED marker layout: id, x, y, z (m, body frame), frequency (Hz)"]
        rows += [f"{i + 1} {float(p[0])!r} {float(p[1])!r} {float(p[2])!r} {float(hz)!r}"
                 for i, (p, hz) in enumerate(zip(self.points, self.freqs_hz))]
        return "\n".join(rows) + "\n"
