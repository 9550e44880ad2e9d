"""Pictures of frames (:class:`tectum.FramePacket`: APS frames, the images
of the ``repr.*`` operators) for the display sinks, chosen by each frame's
shape and dtype:

* (H, W) uint8 (an APS frame): grey as it is;
* (H, W) of other dtypes: grey, stretched from 0 to the 99th percentile of
  the non-zero values (counts, an image of warped events), or, with
  negative values (a signed accumulation), ON colour for positive and OFF
  colour for negative, stretched to the 99th percentile of the magnitudes;
* (H, W, 3) uint8: colour as it is, RGB (``repr.color``);
* (H, W, 2): channel 0 OFF, channel 1 ON (tectum's polarity channels), each
  in its colour over the background: counts stretched as above, values of
  a float frame between 0 and 1 (a time surface) as they are, and int64
  times in µs (``repr.sae``) as their recency at the frame's time, newest
  brightest, over the 99th percentile of the ages;
* (H, W, C) of C time bins (``repr.voxel_grid``): the bins summed, signed.

Pixels without a value (NaN) are in :data:`tectum.sinks.display.maps.UNKNOWN_COLOUR`.
"""

from __future__ import annotations

import numpy as np

from .maps import UNKNOWN_COLOUR
from .render import BACKGROUND, OFF_COLOUR, ON_COLOUR

__all__ = ["frame_picture", "frame_caption"]

_BG = np.array(BACKGROUND, np.float32)
_ON = np.array(ON_COLOUR, np.float32) - _BG
_OFF = np.array(OFF_COLOUR, np.float32) - _BG
_CAPTIONS = {
    "grey": "grey levels as recorded",
    "counts": "grey from 0 to the 99th percentile of its non-zero values",
    "signed": "light blue positive, red negative, full colour at the 99th percentile of the magnitudes",
    "rgb": "its own colours",
    "times": "each pixel's newest event by its age, newest brightest (light blue ON, red OFF)",
    "polarity": "ON events light blue, OFF events red, full colour at the 99th percentile of the counts",
    "unit": "ON light blue, OFF red, in proportion to the values from 0 to 1",
    "bins": "its time bins summed, light blue positive, red negative",
}


def frame_picture(image: np.ndarray, t_us: int) -> np.ndarray:
    """(H, W, 3) BGR uint8 picture of one frame (see the module docstring);
    ``t_us`` is the frame's time (µs), used by frames of times."""
    a = np.asarray(image)
    what = _what(a)
    if what == "grey":
        return np.repeat(a[:, :, None], 3, axis=2)
    if what == "rgb":
        return np.ascontiguousarray(a[:, :, ::-1])
    if what == "bins":
        return frame_picture(a.astype(np.float32).sum(axis=2), t_us)
    if what == "times":  # the latest time (µs) per pixel and polarity
        age = (t_us - a).astype(np.float32)
        seen = (age >= 0) & (age < 2.0**40)  # a time past 2^40 µs (12.7 days) before the frame: none
        span = _scale(np.where(seen, age + 1, 0))
        rec = np.where(seen, 1.0 - np.minimum(age / span, 1.0), 0.0)
        return _tones(rec[:, :, 1], rec[:, :, 0], None)
    v = a.astype(np.float32)
    if what == "counts":
        return _grey(v / _scale(v), v)
    if what == "signed":
        s = _scale(np.abs(v))
        return _tones(np.clip(v, 0, None) / s, np.clip(-v, 0, None) / s, v)
    s = np.float32(1.0) if what == "unit" else _scale(np.abs(v))
    return _tones(v[:, :, 1] / s, v[:, :, 0] / s, v.sum(axis=2))


def frame_caption(image: np.ndarray, t_us: int) -> str:
    """What :func:`frame_picture` shows for ``image``, in one sentence."""
    a = np.asarray(image)
    return f"Frame ({a.shape[1]}x{a.shape[0]} px) at t = {t_us / 1e6:.3f} s: {_CAPTIONS[_what(a)]}."


def _what(a: np.ndarray) -> str:
    """Which picture a frame gets, by its shape and dtype (the module docstring's list)."""
    if a.ndim == 2:
        if a.dtype == np.uint8:
            return "grey"
        return "signed" if a.size and np.nanmin(a) < 0 else "counts"
    if a.ndim == 3 and a.shape[2] == 3 and a.dtype == np.uint8:
        return "rgb"
    if a.ndim == 3 and a.shape[2] == 2:
        if a.dtype == np.int64:
            return "times"
        if a.dtype.kind == "f" and np.nanmax(a, initial=0.0) <= 1.0 and np.nanmin(a, initial=0.0) >= 0.0:
            return "unit"
        return "polarity"
    if a.ndim == 3:
        return "bins"
    raise ValueError(f"a frame of shape {a.shape} is not a picture: (H, W), (H, W, 2), (H, W, 3) or (H, W, bins)")


def _scale(values: np.ndarray) -> np.float32:
    """The 99th percentile of the finite non-zero values (1 when none)."""
    nz = values[np.isfinite(values) & (values != 0)]
    return np.float32(max(float(np.percentile(nz, 99)), 1e-12)) if nz.size else np.float32(1.0)


def _grey(level: np.ndarray, raw: np.ndarray) -> np.ndarray:
    g = np.clip(np.nan_to_num(level), 0.0, 1.0) * 255.0
    out = np.repeat(np.round(g).astype(np.uint8)[:, :, None], 3, axis=2)
    out[np.isnan(raw)] = UNKNOWN_COLOUR
    return out


def _tones(on: np.ndarray, off: np.ndarray, raw: np.ndarray | None) -> np.ndarray:
    on = np.clip(np.nan_to_num(on), 0.0, 1.0)[:, :, None]
    off = np.clip(np.nan_to_num(off), 0.0, 1.0)[:, :, None]
    out = np.clip(_BG + _ON * on + _OFF * off, 0, 255)
    pic = np.round(out).astype(np.uint8)
    if raw is not None:
        pic[np.isnan(raw)] = UNKNOWN_COLOUR
    return pic
