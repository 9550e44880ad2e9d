"""Camera calibration with blinking patterns (``tectum calibrate``).

An event camera sees nothing of a still checkerboard, and the corners of a
moving one are blurred in time; a blinking grid of dots (LEDs, or a screen)
seen by a still camera gives sharp dots, one still view at a time:

1. blinking pixels by their ON→OFF transitions at the blink period, the
   dots as 8-connected blobs, their centres as weighted centroids
   (:mod:`._blink`);
2. still views where the blobs hold still, the dots ordered as OpenCV's
   symmetric or asymmetric circle grid; views of part of the board are
   skipped, never mis-ordered (:mod:`._grid`);
3. ``cv2.calibrateCamera`` (radtan) or ``cv2.fisheye.calibrate``, outlier
   views dropped, per-view and total reprojection RMS (:mod:`._solve`);
   stereo extrinsics with ``cv2.stereoCalibrate``;
4. files that ``filter.undistort`` reads: OpenCV YAML, ECD ``calib.txt``,
   ROS ``camera_info``, stereo YAML (:mod:`._write`).

With frames instead (DAVIS APS frames or ``map.high_pass`` reconstructions
of a moving board): :func:`calibrate_frames` finds checkerboard corners.
"""

from __future__ import annotations

from ._calibrate import (
    Calibration,
    CalibrationError,
    StereoCalibration,
    View,
    calibrate,
    calibrate_stereo,
    detect_views,
    read_recording,
)
from ._frames import calibrate_frames
from ._grid import Grid, order_grid
from ._write import format_for, write_calibration, write_stereo

__all__ = ["calibrate", "calibrate_stereo", "calibrate_frames", "detect_views", "read_recording", "Calibration",
           "StereoCalibration", "View", "CalibrationError", "Grid", "order_grid", "write_calibration",
           "write_stereo", "format_for"]
