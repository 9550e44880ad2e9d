"""Representations as plain functions of an :class:`tectum.EventPacket`
(tonic style): each allocates its output and calls a numba kernel from
:mod:`tectum.plugins.repr.kernels`. The ``repr.*`` operators, the display
sink and other families reuse them."""

from __future__ import annotations

import numpy as np

from tectum import EventPacket

from . import kernels as K

__all__ = [
    "event_frame", "accumulate", "count_image", "sae", "time_surface", "voxel_grid",
    "polarity_map", "render_polarity", "color", "parse_color",
]


def _hw(ev: EventPacket) -> tuple[int, int]:
    return ev.sensor[1], ev.sensor[0]


def event_frame(ev: EventPacket) -> np.ndarray:
    """Histogram per polarity: (H, W, 2) int32 event counts, channel 0 OFF, 1 ON."""
    out = np.zeros((*_hw(ev), 2), np.int32)
    K.histogram_kernel(ev.x, ev.y, ev.p, out)
    return out


def accumulate(ev: EventPacket) -> np.ndarray:
    """Signed accumulation: (H, W) int32 sum of polarities."""
    out = np.zeros(_hw(ev), np.int32)
    K.signed_kernel(ev.x, ev.y, ev.p, out)
    return out


def count_image(ev: EventPacket) -> np.ndarray:
    """Event count image: (H, W) int32 events per pixel."""
    out = np.zeros(_hw(ev), np.int32)
    K.count_kernel(ev.x, ev.y, out)
    return out


def sae(ev: EventPacket, state: np.ndarray | None = None) -> np.ndarray:
    """Surface of active events: (H, W, 2) int64 latest timestamp (µs) per
    pixel and polarity, :data:`~tectum.plugins.repr.kernels.NEVER` where
    none; updates and returns ``state`` when given."""
    out = np.full((*_hw(ev), 2), K.NEVER, np.int64) if state is None else state
    K.sae_kernel(ev.t, ev.x, ev.y, ev.p, out)
    return out


def time_surface(ev: EventPacket, tau_us: float = 50_000.0, t_ref: int | None = None) -> np.ndarray:
    """Time surface: (H, W, 2) float32 ``exp(-(t_ref - t_last) / tau_us)``
    per pixel and polarity, 0 where none; ``t_ref`` defaults to the last
    event's time (µs)."""
    s = sae(ev)
    if t_ref is None:
        t_ref = int(ev.t[-1]) if len(ev) else ev.t_start
    out = np.empty(s.shape, np.float32)
    K.time_surface_kernel(s, int(t_ref), float(tau_us), out)
    return out


def voxel_grid(ev: EventPacket, bins: int = 5, t0: int | None = None, t1: int | None = None) -> np.ndarray:
    """Voxel grid: (H, W, bins) float32, polarity spread bilinearly over
    ``bins`` time bins spanning ``[t0, t1]`` µs (default: first and last event)."""
    if bins < 1:
        raise ValueError("bins must be >= 1")
    out = np.zeros((*_hw(ev), bins), np.float32)
    if len(ev):
        a = int(ev.t[0]) if t0 is None else int(t0)
        b = int(ev.t[-1]) if t1 is None else int(t1)
        K.voxel_kernel(ev.t, ev.x, ev.y, ev.p, a, b, out)
    return out


def polarity_map(ev: EventPacket) -> np.ndarray:
    """(H, W) int8: the latest polarity per pixel, 0 where no event."""
    out = np.zeros(_hw(ev), np.int8)
    K.last_polarity_kernel(ev.x, ev.y, ev.p, out)
    return out


def parse_color(text: str) -> np.ndarray:
    """``"#rrggbb"`` (or ``rrggbb``) as uint8[3]."""
    s = text.strip().lstrip("#")
    if len(s) != 6:
        raise ValueError(f"colour {text!r} is not #rrggbb")
    return np.array([int(s[i:i + 2], 16) for i in (0, 2, 4)], np.uint8)


def render_polarity(last: np.ndarray, on: str = "#ffffff", off: str = "#3c78ff",
                    background: str = "#000000") -> np.ndarray:
    """RGB (H, W, 3) uint8 of a :func:`polarity_map`."""
    out = np.empty((*last.shape, 3), np.uint8)
    K.render_polarity_kernel(last, parse_color(on), parse_color(off), parse_color(background), out)
    return out


def color(ev: EventPacket, on: str = "#ffffff", off: str = "#3c78ff", background: str = "#000000") -> np.ndarray:
    """Polarity colour rendering: RGB (H, W, 3) uint8, each pixel in the
    colour of its latest event's polarity, ``background`` where none."""
    return render_polarity(polarity_map(ev), on, off, background)
