"""Camera geometry shared by operators, sources and sinks: the calibrated
camera, its calibration files, rotations and rigid motions.

Conventions
-----------
* Units: metres (m) for positions and depths, radians (rad) for angles,
  pixels (px) for image coordinates, microseconds (µs, int64) for times.
* Pixels: ``(u, v)``, origin at the top-left pixel, ``u`` to the right,
  ``v`` down; integer coordinates are pixel *centres* (OpenCV's convention,
  and an event's ``(x, y)``).
* Camera frame (OpenCV): ``x`` right, ``y`` down, ``z`` forward along the
  optical axis. A point ``(X, Y, Z)`` with ``Z > 0`` is in front; its
  normalised coordinates are ``(X/Z, Y/Z)``; "depth" is ``Z`` (not the
  distance to the centre).
* Poses are world-from-camera, ``T_wc = (R, t)``: ``p_w = R p_c + t``, so
  ``t`` is the camera centre in the world (as :class:`~tectum.PosePacket`
  holds them). ``compose(T_ab, T_bc) = T_ac``.
* Quaternions: ``(x, y, z, w)``, scalar last, Hamilton product, unit norm;
  ``quat_to_rot(a ⊗ b) = quat_to_rot(a) @ quat_to_rot(b)``.
* Rotation vectors ``ω`` (rad): axis times angle, ``so3_exp(ω)``. Twists are
  6-vectors ``(ω, v)``, **rotation first**, then translation (m);
  ``se3_exp`` / ``se3_log``.

What is here
------------
* :class:`Camera` (pinhole, ``radtan`` or ``equidistant`` distortion, with
  ``project``, ``bearings``, ``back_project``, ``undistort_points``,
  ``undistort_maps`` ...) and :func:`read_calibration` /
  :func:`read_uzh_calib` for OpenCV YAML/JSON, stereo, ROS ``camera_info``
  and UZH ``calib.txt`` files; :func:`camera_from` for an operator's
  ``calib=`` (a file, or inline ``fx;fy;cx;cy[;k1;k2;p1;p2[;k3]]``);
  :func:`depth_points`: a depth map's known pixels as world points.
* SO(3)/SE(3): :func:`hat`, :func:`so3_exp`, :func:`so3_log`,
  :func:`quat_to_rot`, :func:`rot_to_quat`, :func:`quat_mul`,
  :func:`quat_conj`, :func:`quat_slerp`, :func:`interpolate_poses`,
  :func:`se3_exp`, :func:`se3_log`, :func:`transform_points`,
  :func:`compose`, :func:`invert`; :func:`rotation_matrix` (a rotation
  given as 3 or 9 numbers); :func:`gyro_rotations`, :func:`gyro_turn` (a
  gyro's samples integrated).
* Kernels for other numba code (one element, no checks): the camera's
  :func:`project_kernel`, :func:`distort_kernel`, :func:`undistort_kernel`,
  :func:`pixel_to_normalized_kernel` (taking ``Camera.params``), and
  ``so3_exp_kernel`` ... ``interpolate_poses_kernel``.

This module imports no plugin, source or sink.
"""

from __future__ import annotations

from ._calibration_files import Side, camera_from, read_calibration, read_uzh_calib
from ._camera import Camera, Model, depth_points
from ._lens import distort_kernel, pixel_to_normalized_kernel, project_kernel, undistort_kernel
from ._rigid import (
    QUAT_TOL,
    compose,
    gyro_rotations,
    gyro_turn,
    hat,
    interpolate_poses,
    interpolate_poses_kernel,
    invert,
    quat_conj,
    quat_mul,
    quat_mul_kernel,
    quat_slerp,
    quat_slerp_kernel,
    quat_to_rot,
    quat_to_rot_kernel,
    rot_to_quat,
    rot_to_quat_kernel,
    rotation_matrix,
    se3_exp,
    se3_exp_kernel,
    se3_log,
    se3_log_kernel,
    so3_exp,
    so3_exp_kernel,
    so3_log,
    so3_log_kernel,
    transform_points,
)

__all__ = [
    "Camera", "Model", "Side", "depth_points", "camera_from", "read_calibration", "read_uzh_calib",
    "project_kernel", "distort_kernel", "undistort_kernel", "pixel_to_normalized_kernel",
    "hat", "so3_exp", "so3_log", "quat_to_rot", "rot_to_quat", "quat_mul", "quat_conj", "quat_slerp",
    "interpolate_poses", "se3_exp", "se3_log", "transform_points", "compose", "invert", "QUAT_TOL",
    "rotation_matrix", "gyro_rotations", "gyro_turn",
    "so3_exp_kernel", "so3_log_kernel", "quat_to_rot_kernel", "rot_to_quat_kernel", "quat_mul_kernel",
    "quat_slerp_kernel", "se3_exp_kernel", "se3_log_kernel", "interpolate_poses_kernel",
]
