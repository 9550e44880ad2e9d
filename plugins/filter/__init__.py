"""Family ``filter``: event filters (denoising, refractory, masks, geometry,
undistortion, rate limiting). Each operator is a thin class around numba
kernels that are importable on their own."""

from __future__ import annotations

from tectum.camera import Camera, read_calibration, read_uzh_calib
from tectum.hookspecs import hookimpl

from .background_activity import BackgroundActivity, background_activity_kernel
from .geometry import Downsample, Flip, Roi, Rotate
from .hot_pixel import HotPixel
from .mask import Mask
from .polarity import Polarity
from .rate_limit import RateLimit
from .refractory import Refractory, refractory_kernel
from .stcf import SpatioTemporalCorrelation, stcf_kernel
from .time_window import TimeWindow
from .undistort import Undistort, undistort_lut

__all__ = [
    "BackgroundActivity", "SpatioTemporalCorrelation", "Refractory", "HotPixel", "Mask", "Polarity",
    "Roi", "Flip", "Rotate", "Downsample", "TimeWindow", "RateLimit", "Undistort",
    "Camera", "read_calibration", "read_uzh_calib", "undistort_lut",
    "background_activity_kernel", "stcf_kernel", "refractory_kernel", "OPERATORS",
]

OPERATORS = (
    BackgroundActivity, SpatioTemporalCorrelation, Refractory, HotPixel, Mask, Polarity,
    Roi, Flip, Rotate, Downsample, TimeWindow, RateLimit, Undistort,
)


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    for cls in OPERATORS:
        registry.add_operator(cls)
