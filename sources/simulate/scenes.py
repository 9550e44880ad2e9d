"""Scenes as data: built-in scenes, TOML loading, and compilation to the
flat arrays the kernels read (see the package docstring for the keys)."""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from .motion import Trajectory
from .render import DISK, EDGE, RECT
from .textures import TexturePool, make_texture
from .video import FrameReader, is_video_spec, video_spec

__all__ = ["BUILTIN", "load_scene", "compile_scene", "CompiledScene", "scene_names"]

_TOP_KEYS = {"name", "description", "sensor", "fov_deg", "focal_px", "duration_us", "background", "panorama",
             "planes", "boxes", "objects", "motion", "sensor_model", "davis", "truth", "sim", "video",
             "features"}
_NOT_WITH_VIDEO = ("background", "panorama", "planes", "boxes", "objects", "motion")
_SHAPES = {"disk": DISK, "rect": RECT, "bar": RECT, "edge": EDGE}


# -- built-in scenes (functions of the sensor size) ----------------------------------------------
def _rotation(w: int, h: int) -> dict[str, Any]:
    return {"description": "camera rotating in front of a textured panorama (angular velocity, mosaicing)",
            "panorama": {"texture": {"kind": "noise", "size": 1024, "blur": 1.5, "contrast": 0.6, "mean": 0.35},
                         "texel_deg": 360 / 1024},
            "motion": {"angular_velocity": [0.1, 0.4, 0.05], "rotation_amplitude": [0.25, 0.35, 0.2],
                       "rotation_freq_hz": [0.7, 0.5, 0.9]}}


def _rotation_plane(w: int, h: int) -> dict[str, Any]:
    return {"description": "camera rotating in front of a large textured plane (homography, mosaicing)",
            "planes": [{"center": [0, 0, 3.0], "texture": {"kind": "noise", "size": 512, "contrast": 0.6},
                        "texel_m": 0.01}],
            "motion": {"rotation_amplitude": [0.2, 0.3, 0.15], "rotation_freq_hz": [0.6, 0.5, 0.8]}}


def _plane_6dof(w: int, h: int) -> dict[str, Any]:
    return {"description": "6-DoF camera motion in front of a textured plane (depth, homography)",
            "planes": [{"center": [0, 0, 2.0], "texture": {"kind": "noise", "size": 512, "contrast": 0.6},
                        "texel_m": 0.006}],
            "motion": {"position_amplitude": [0.3, 0.2, 0.3], "position_freq_hz": [0.5, 0.7, 0.4],
                       "rotation_amplitude": [0.1, 0.1, 0.15], "rotation_freq_hz": [0.6, 0.4, 0.5]}}


def _boxes_3d(w: int, h: int) -> dict[str, Any]:
    tex = {"kind": "noise", "size": 256, "contrast": 0.5}
    return {"description": "camera translating past three textured boxes on a floor before a wall (depth, EMVS)",
            "planes": [{"center": [0, 1.0, 4], "orientation": [math.pi / 2, 0, 0], "texture": tex,
                        "texel_m": 0.02, "id": 0},
                       {"center": [0, 0, 8], "texture": {**tex, "seed": 1}, "texel_m": 0.03, "id": 0}],
            "boxes": [{"center": [-0.8, 0.6, 3.0], "size": [0.6, 0.8, 0.6], "orientation": [0, 0.4, 0],
                       "texture": {"kind": "checker", "period": 16, "contrast": 0.6}, "texel_m": 0.01, "id": 1},
                      {"center": [0.5, 0.5, 4.5], "size": [0.8, 1.0, 0.8], "orientation": [0, -0.3, 0],
                       "texture": {**tex, "seed": 2}, "texel_m": 0.01, "id": 2},
                      {"center": [1.6, 0.7, 3.5], "size": [0.5, 0.6, 0.5],
                       "texture": {**tex, "seed": 3}, "texel_m": 0.008, "id": 3}],
            "motion": {"position": [-0.5, 0, 0], "velocity": [0.5, 0, 0], "position_amplitude": [0, 0.05, 0.1],
                       "position_freq_hz": [0, 1.0, 0.5]},
            "sim": {"supersample": 2}}


def _translation_edges(w: int, h: int) -> dict[str, Any]:
    s = min(w, h)
    return {"description": "straight bars at set velocities (aperture problem) and a tilted square (corners)",
            "background": {"intensity": 0.25},
            "objects": [
                {"shape": "bar", "position": [0.2 * w, 0.5 * h], "size": [0.08 * s, 3 * h], "angle_deg": 30,
                 "velocity": [0.5 * w, 0], "intensity": 0.8, "bounce": [0, 0, w - 1, 0]},
                {"shape": "bar", "position": [0.5 * w, 0.1 * h], "size": [3 * w, 0.06 * s],
                 "velocity": [0, 0.4 * h], "intensity": 0.6, "bounce": [0, 0, 0, h - 1]},
                {"shape": "rect", "position": [0.75 * w, 0.3 * h], "size": [0.25 * s, 0.25 * s], "angle_deg": 15,
                 "velocity": [-0.2 * w, 0.15 * h], "intensity": 0.9, "bounce": True}]}


def _shapes(w: int, h: int) -> dict[str, Any]:
    s = min(w, h)
    return {"description": "several independently moving, spinning textured shapes over a textured background",
            "background": {"texture": {"kind": "noise", "contrast": 0.3, "mean": 0.3}, "texel_px": 2.0},
            "objects": [
                {"shape": "disk", "position": [0.25 * w, 0.3 * h], "radius": 0.12 * s,
                 "velocity": [0.3 * w, 0.2 * h], "intensity": 0.9, "bounce": True},
                {"shape": "rect", "position": [0.7 * w, 0.6 * h], "size": [0.3 * s, 0.2 * s],
                 "velocity": [-0.25 * w, -0.1 * h], "angular_velocity": 1.5, "bounce": True,
                 "texture": {"kind": "checker", "period": 8, "contrast": 0.7, "mean": 0.5}},
                {"shape": "disk", "position": [0.5 * w, 0.8 * h], "radius": 0.1 * s,
                 "velocity": [0.1 * w, -0.35 * h], "angular_velocity": -2.0, "bounce": True,
                 "texture": {"kind": "noise", "contrast": 0.8, "mean": 0.6, "seed": 5}}]}


def _led_grid(w: int, h: int) -> dict[str, Any]:
    objs = []
    for j in range(3):
        for i in range(4):
            k = j * 4 + i
            objs.append({"shape": "disk", "position": [(i + 0.5) * w / 4, (j + 0.5) * h / 3],
                         "radius": 0.06 * min(w, h), "intensity": 1.0, "intensity_off": 0.05,
                         "blink_hz": 50.0 * (k + 1), "blink_duty": 0.5, "blink_rise_us": 50.0})
    return {"description": "a 4x3 grid of LEDs blinking at 50..600 Hz (calibration, LED markers)",
            "background": {"intensity": 0.05}, "objects": objs}


def _low_texture(w: int, h: int) -> dict[str, Any]:
    return {"description": "a faint texture drifting slowly (low-texture, low event rate)",
            "background": {"texture": {"kind": "noise", "contrast": 0.1, "mean": 0.4, "blur": 3.0},
                           "texel_px": 3.0, "velocity": [40.0, 15.0]}}


def _moving_texture(w: int, h: int) -> dict[str, Any]:
    return {"description": "a rich texture translating in the image plane (speed benchmarks, flow)",
            "background": {"texture": {"kind": "noise", "contrast": 0.7, "mean": 0.4}, "texel_px": 2.0,
                           "velocity": [300.0, 120.0]}}


def _static(w: int, h: int) -> dict[str, Any]:
    return {"description": "a static uniform grey scene (noise statistics)", "background": {"intensity": 0.5}}


BUILTIN: dict[str, Callable[[int, int], dict[str, Any]]] = {
    "rotation": _rotation,
    "rotation_plane": _rotation_plane,
    "plane_6dof": _plane_6dof,
    "boxes_3d": _boxes_3d,
    "translation_edges": _translation_edges,
    "shapes": _shapes,
    "led_grid": _led_grid,
    "low_texture": _low_texture,
    "moving_texture": _moving_texture,
    "static": _static,
}


def scene_names() -> list[str]:
    """Names of the built-in scenes."""
    return list(BUILTIN)


def _parse_sensor(v: Any) -> tuple[int, int]:
    if isinstance(v, str):
        a, b = v.lower().split("x")
        return int(a), int(b)
    w, h = v
    return int(w), int(h)


def load_scene(scene: str | Mapping[str, Any], sensor: Any = None, fps: float = 0.0) -> dict[str, Any]:
    """A scene dict from a built-in name, a TOML file path, a video / image
    folder / image list path (see :mod:`.video`) or a dict.

    ``sensor`` ("WxH" or (w, h)) overrides the scene's sensor size; built-in
    scenes are laid out for whatever size is asked (default 346x260), videos
    default to their frame size. ``fps`` > 0 overrides a video's frame rate."""
    if isinstance(scene, Mapping):
        d = dict(scene)
    elif scene not in BUILTIN and is_video_spec(scene):
        d = {"name": os.path.splitext(os.path.basename(os.path.normpath(scene)))[0], "video": {"path": scene}}
    elif scene in BUILTIN:
        size = _parse_sensor(sensor) if sensor is not None else (346, 260)
        d = BUILTIN[scene](*size)
        d["name"] = scene
        d["sensor"] = list(size)
    elif os.path.isfile(scene):
        with open(scene, "rb") as f:
            d = tomllib.load(f)
        d.setdefault("name", os.path.splitext(os.path.basename(scene))[0])
    else:
        raise ValueError(f"unknown scene {scene!r}: not a built-in ({', '.join(BUILTIN)}) nor a TOML file")
    unknown = set(d) - _TOP_KEYS
    if unknown:
        raise ValueError(f"scene {d.get('name', '?')!r}: unknown keys {sorted(unknown)}; known: {sorted(_TOP_KEYS)}")
    if sensor is not None:
        d["sensor"] = list(_parse_sensor(sensor))
    if "video" in d:
        _load_video(d, fps)
    d["sensor"] = list(_parse_sensor(d.get("sensor", (346, 260))))
    return d


def _load_video(d: dict[str, Any], fps: float) -> None:
    """Validate a video scene; fill in its sensor size and duration."""
    v = d["video"] = video_spec(d["video"])
    if fps > 0:
        v["fps"] = float(fps)
    both = [k for k in _NOT_WITH_VIDEO if k in d]
    if both:
        raise ValueError(f"scene {d.get('name', '?')!r}: a video scene cannot also have {both}")
    size = _parse_sensor(d["sensor"]) if "sensor" in d else None
    reader = FrameReader(v["path"], float(v.get("fps", 0.0)), float(v.get("gamma", 1.0)),
                         int(v.get("start_frame", 0)), size)
    d["sensor"] = list(reader.size)
    d.setdefault("duration_us", max(1, int(round(reader.duration_us))))


@dataclass
class CompiledScene:
    """A scene as kernel inputs, with its camera and trajectory."""

    name: str
    sensor: tuple[int, int]
    f: float
    cx: float
    cy: float
    patches: np.ndarray
    pano: np.ndarray
    bg: np.ndarray
    sprites: np.ndarray
    tex_data: np.ndarray
    tex_table: np.ndarray
    trajectory: Trajectory
    supersample: int
    has_world: bool
    max_blink_hz: float
    min_blink_duty: float
    video: dict[str, Any] | None = None


def _bounce_box(spec: Any, shape: str, a: float, b: float, w: int, h: int, i: int) -> list[float]:
    """The box ``[x0, y0, x1, y1]`` (px) an object's centre bounces inside:
    ``true`` keeps the whole shape on the sensor (its bounding circle), a
    list gives the box (an axis with ``x0 == x1`` does not bounce); ``false``
    (no box: ``[0, 0, 0, 0]``) lets it fly."""
    if spec is False or spec is None:
        return [0.0, 0.0, 0.0, 0.0]
    if spec is True:
        if shape in ("edge", "bar"):
            raise ValueError(f"object {i}: a {shape} reaches beyond the sensor: give bounce as [x0, y0, x1, y1]")
        r = a if shape == "disk" else 0.5 * math.hypot(a, b)
        box = [r, r, w - 1 - r, h - 1 - r]
    else:
        box = [float(v) for v in spec]
    if len(box) != 4 or box[2] < box[0] or box[3] < box[1] or box[:2] == box[2:]:
        raise ValueError(f"object {i}: bounce box {box} is not [x0, y0, x1, y1] with x0 <= x1, y0 <= y1 "
                         "(and one of them <)")
    return box


def _patch_row(center: Any, rot: np.ndarray, hw: float, hh: float, tid: int, texel: float, inten: float,
               oid: int) -> list[float]:
    c = np.asarray(center, np.float64)
    return [*c, *rot[:, 0], *rot[:, 1], *rot[:, 2], hw, hh, tid, texel, inten, oid]


def _texture_or_constant(pool: TexturePool, spec: Mapping[str, Any], key_seed: int) -> tuple[int, float]:
    tex = spec.get("texture")
    if tex is None:
        return -1, float(spec.get("intensity", 0.5))
    return pool.add(make_texture(tex, seed=key_seed)), float(spec.get("intensity", 0.5))


def compile_scene(d: Mapping[str, Any]) -> CompiledScene:
    """Turn a scene dict (from :func:`load_scene`) into kernel arrays."""
    w, h = _parse_sensor(d.get("sensor", (346, 260)))
    if "focal_px" in d:
        f = float(d["focal_px"])
    else:
        f = 0.5 * w / math.tan(math.radians(float(d.get("fov_deg", 60.0))) / 2)
    pool = TexturePool()
    rows: list[list[float]] = []
    for i, pl in enumerate(d.get("planes", [])):
        rot = Rotation.from_rotvec(np.asarray(pl.get("orientation", [0, 0, 0]), float)).as_matrix()
        size = pl.get("size")
        hw, hh = (np.inf, np.inf) if size is None else (0.5 * float(size[0]), 0.5 * float(size[1]))
        tid, inten = _texture_or_constant(pool, pl, 1000 + i)
        rows.append(_patch_row(pl.get("center", [0, 0, 2]), rot, hw, hh, tid, float(pl.get("texel_m", 0.01)),
                               inten, int(pl.get("id", 0))))
    for i, bx in enumerate(d.get("boxes", [])):
        rot = Rotation.from_rotvec(np.asarray(bx.get("orientation", [0, 0, 0]), float)).as_matrix()
        c = np.asarray(bx.get("center", [0, 0, 3]), float)
        s = np.broadcast_to(np.asarray(bx.get("size", [1, 1, 1]), float), (3,))
        tid, inten = _texture_or_constant(pool, bx, 2000 + i)
        for k in range(3):
            ka, kb = (k + 1) % 3, (k + 2) % 3  # the face's in-plane axes
            for sign in (-1.0, 1.0):
                fr = np.stack([rot[:, ka], rot[:, kb], sign * rot[:, k]], axis=1)
                rows.append(_patch_row(c + sign * 0.5 * s[k] * rot[:, k], fr, 0.5 * s[ka], 0.5 * s[kb], tid,
                                       float(bx.get("texel_m", 0.01)), inten, int(bx.get("id", i + 1))))
    patches = np.array(rows, np.float64).reshape(-1, 18)
    pano = np.array([-1.0, 1.0, 0.0])
    if "panorama" in d:
        pn = d["panorama"]
        tex = make_texture(pn.get("texture", {"kind": "noise", "size": 1024}), seed=3000)
        # the texture's width spans 360 degrees exactly, so it wraps seamlessly
        pano = np.array([pool.add(tex), 2 * math.pi / tex.shape[1], float(pn.get("id", 0))])
    bgs = d.get("background", {})
    btid = pool.add(make_texture(bgs["texture"], seed=4000)) if "texture" in bgs else -1
    bvel = bgs.get("velocity", [0.0, 0.0])
    bg = np.array([float(bgs.get("intensity", 0.5)), btid, float(bgs.get("texel_px", 1.0)), float(bvel[0]),
                   float(bvel[1]), float(bgs.get("log_slope", 0.0)), float(bgs.get("id", 0))])
    srows = []
    max_blink, min_duty = 0.0, 0.5
    for i, ob in enumerate(d.get("objects", [])):
        shape = ob.get("shape", "disk")
        if shape not in _SHAPES:
            raise ValueError(f"object {i}: unknown shape {shape!r}; known: {sorted(_SHAPES)}")
        if shape == "disk":
            a = b = float(ob.get("radius", 10.0))
        elif shape == "edge":
            a = b = 0.0
        else:
            a, b = (float(v) for v in ob.get("size", [20.0, 20.0]))
        tid, inten = _texture_or_constant(pool, ob, 5000 + i)
        pos, vel = ob.get("position", [w / 2, h / 2]), ob.get("velocity", [0.0, 0.0])
        bhz = float(ob.get("blink_hz", 0.0))
        duty = float(ob.get("blink_duty", 0.5))
        if bhz > 0:
            max_blink = max(max_blink, bhz)
            min_duty = min(min_duty, duty, 1 - duty)
        srows.append([_SHAPES[shape], float(pos[0]), float(pos[1]), float(vel[0]), float(vel[1]),
                      math.radians(float(ob.get("angle_deg", 0.0))), float(ob.get("angular_velocity", 0.0)),
                      a, b, inten, float(ob.get("intensity_off", inten)), tid, float(ob.get("texel_px", 1.0)),
                      bhz, duty, float(ob.get("blink_rise_us", 100.0)) * 1e-6, float(ob.get("blink_phase", 0.0)),
                      float(ob.get("id", i + 1)), *_bounce_box(ob.get("bounce", False), shape, a, b, w, h, i)])
    sprites = np.array(srows, np.float64).reshape(-1, 22)
    data, table = pool.arrays()
    sim = d.get("sim", {})
    return CompiledScene(
        name=str(d.get("name", "scene")), sensor=(w, h), f=f, cx=(w - 1) / 2, cy=(h - 1) / 2,
        patches=patches, pano=pano, bg=bg, sprites=sprites, tex_data=data, tex_table=table,
        trajectory=Trajectory(d.get("motion")), supersample=int(sim.get("supersample", 1)),
        has_world=bool(patches.shape[0] or pano[0] >= 0), max_blink_hz=max_blink, min_blink_duty=min_duty,
        video=d.get("video"))
