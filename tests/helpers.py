"""Helpers for the test suite: generated streams and the shared recordings.

Import as ``from helpers import bars, shared_data`` (``tests`` is on the path).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from tectum import EventPacket, FormatError, concat

ROOT = Path(__file__).resolve().parents[1]


def shared_data() -> Path | None:
    """The folder of real recordings (../shared/data beside the project), or None."""
    env = os.environ.get("TECTUM_SHARED_DATA")
    p = Path(env) if env else ROOT.parent / "shared" / "data"
    return p if p.is_dir() else None


def bars(duration_us: int = 30_000, sensor: str = "64x48", **kw: object) -> EventPacket:
    """A small moving-bars stream with labelled noise, as one packet."""
    from tectum.sources.pattern import PatternSource

    return concat(list(PatternSource(sensor=sensor, duration_us=duration_us, **kw).packets()))  # type: ignore[arg-type,return-value]


def mutate(raw: bytes, data: Any) -> bytes:
    """``raw`` damaged as hypothesis's ``data`` draws it: cut short, up to 8
    bytes overwritten, or up to 64 bytes spliced in."""
    from hypothesis import strategies as st

    out = bytearray(raw)
    op = data.draw(st.sampled_from(["truncate", "flip", "splice"]))
    if op == "truncate":
        return bytes(out[:data.draw(st.integers(0, len(out)))])
    if op == "flip":
        for _ in range(data.draw(st.integers(1, 8))):
            out[data.draw(st.integers(0, len(out) - 1))] = data.draw(st.integers(0, 255))
        return bytes(out)
    i = data.draw(st.integers(0, len(out)))
    out[i:i] = data.draw(st.binary(max_size=64))
    return bytes(out)


def decodes_or_names(source: Any, path: Path) -> None:
    """Every packet of ``source`` obeys the packet contract, or reading it
    raises a FormatError naming ``path``: never another error or a crash."""
    try:
        pkts = list(source.packets())
    except FormatError as e:
        assert e.path == str(path)
        return
    for q in pkts:
        if isinstance(q, EventPacket):
            q.validate()


def run_camera(cam: Any, uri: str = "usb:", sinks: int = 1, **kw: Any) -> tuple[Any, list[Any]]:
    """The emulated camera ``cam`` through a UsbSource (``uri``, options
    ``kw``) into ``sinks`` ListSinks, to the end of its stream: (source, sinks)."""
    import tectum
    from tectum.sources.usb.emulated import EmulatedBackend
    from tectum.sources.usb.source import UsbSource
    from tectum.testing import ListSink

    src = UsbSource(uri, backend=EmulatedBackend(cam), idle_s=0.1, **kw)
    p = tectum.Pipeline()
    s = p.source(src)
    out = [ListSink() for _ in range(sinks)]
    for k in out:
        p.sink(k, s)
    tectum.run(p)
    return src, out


def builtin_operators() -> list[str]:
    """Registry names of every built-in operator (a newly registered one is
    picked up without touching the tests that use this)."""
    import tectum

    return sorted(name for name, e in tectum.get_registry().operators.items() if e.cls.__module__.startswith("tectum."))


def conformance_case(name: str) -> tuple[type, Any, dict[str, Any]]:
    """(class, stream, parameters) to check operator ``name`` with.

    An operator that needs another input than events gives its own stream
    through a class attribute ``conformance_stream`` (a callable returning a
    packet, or one packet per port for operators with named ports); one with
    required parameters gives ``conformance_params`` (a dict). Others get a
    small moving-bars stream with noise. Raises AssertionError (naming the
    operator) where neither fits."""
    import tectum
    from tectum import Kind

    cls = tectum.get_registry().operator(name)
    make_stream = getattr(cls, "conformance_stream", None)
    if make_stream is not None:
        stream = make_stream()
    elif cls.inputs is not None:
        raise AssertionError(f"{name} has ports {sorted(cls.inputs)}: give it a conformance_stream (one packet per port)")
    elif Kind.EVENTS in cls.consumes:
        stream = bars(duration_us=40_000, sensor="48x36", noise_hz=20.0, speed=300.0)
    else:
        raise AssertionError(f"{name} consumes {cls.consumes}: give it a conformance_stream")
    return cls, stream, dict(getattr(cls, "conformance_params", {}))


#: a camera sliding sideways at 0.3 m/s past two boxes before a wall (slider_depth-like, 120x90,
#: 37° wide): the simulated scene of the pose_6dof start and bootstrap tests
SLIDE: dict[str, Any] = {
    "name": "slide", "focal_px": 167.5, "sim": {"supersample": 2},
    "planes": [{"center": [0, 0, 2.3], "texel_m": 0.02,
                "texture": {"kind": "noise", "size": 256, "contrast": 0.5, "blur": 2.0, "seed": 1}}],
    "boxes": [{"center": [-0.15, 0.05, 0.8], "size": [0.2, 0.25, 0.2], "orientation": [0, 0.3, 0], "texel_m": 0.006,
               "texture": {"kind": "noise", "size": 256, "contrast": 0.5, "blur": 2.0, "seed": 2}},
              {"center": [0.25, -0.05, 1.3], "size": [0.3, 0.35, 0.3], "orientation": [0, -0.3, 0], "texel_m": 0.01,
               "texture": {"kind": "noise", "size": 256, "contrast": 0.5, "blur": 2.0, "seed": 3}}],
    "motion": {"position": [0, 0, 0], "velocity": [0.3, 0, 0]}}


#: a small pinhole camera (40x30 px, f 50 px) at the origin looking along z (pose tx ty tz qx qy qz qw),
#: and a plane before it: the photometric map tests' (map.photometric and its measurement module)
SMALL_K = np.array([[50.0, 0.0, 19.5], [0.0, 50.0, 14.5], [0.0, 0.0, 1.0]])
SMALL_W, SMALL_H = 40, 30
STILL = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


def small_plane(depth_m: float = 2.0) -> np.ndarray:
    """A fronto-parallel plane ``depth_m`` (m) away, as a depth map of the small camera."""
    return np.full((SMALL_H, SMALL_W), depth_m)
