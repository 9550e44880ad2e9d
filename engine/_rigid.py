"""Rotations and rigid motions: SO(3), SE(3), unit quaternions, pose interpolation.

Conventions (see :mod:`tectum.camera`): quaternions are (x, y, z, w),
Hamilton product, ``quat_to_rot(a ⊗ b) = quat_to_rot(a) @ quat_to_rot(b)``;
rotation vectors in rad; twists are ``(ω, v)``, rotation first; a pose
``(R, t)`` maps points of its own frame into the parent frame,
``p_parent = R p + t`` (metres).

Each ``*_kernel`` is a numba function on one element (no validation, no
raising, writes into ``out``), usable inside other kernels; the functions
without the suffix are typed wrappers that check their input, take one
element or a stack of ``N`` and loop in compiled code.

Numerics: the series of ``sin θ/θ``, ``(θ - sin θ)/θ³`` and of the inverse
left Jacobian cancel near ``θ = 0``, so below ``SMALL`` rad their Taylor
series are used (the first term left out is below 1e-17);
``(1 - cos θ)/θ²`` is written ``2 sin²(θ/2)/θ²``, which does not cancel. The
logarithm takes ``θ = atan2(|vee(R - Rᵀ)|/2, (tr R - 1)/2)`` (accurate at
every angle) and, past 150°, its axis from the symmetric part of ``R``,
where ``vee(R - Rᵀ) = 2 sin θ u`` has lost its digits.
"""

from __future__ import annotations

import math
from typing import overload

import numpy as np
from numba import njit

__all__ = [
    "QUAT_TOL", "hat", "so3_exp", "so3_log", "quat_to_rot", "rot_to_quat", "quat_mul", "quat_conj",
    "quat_slerp", "interpolate_poses", "se3_exp", "se3_log", "transform_points", "compose", "invert",
    "so3_exp_kernel", "so3_log_kernel", "quat_to_rot_kernel", "rot_to_quat_kernel", "quat_mul_kernel",
    "quat_slerp_kernel", "se3_exp_kernel", "se3_log_kernel", "interpolate_poses_kernel",
    "gyro_rotations", "gyro_turn", "rotation_matrix",
]

#: below this angle (rad) the closed forms give way to their Taylor series
SMALL = 1e-2
#: a quaternion whose norm differs from 1 by more than this is rejected
#: (files printing 4 decimals are within 1e-4); accepted ones are normalised
QUAT_TOL = 1e-3
#: a matrix is a rotation when ``|RᵀR - I|`` and ``|det R - 1|`` are below this
ROT_TOL = 1e-6

Pose = tuple[np.ndarray, np.ndarray]


# -- kernels on one element ------------------------------------------------------
@njit(cache=True, nogil=True)
def so3_exp_kernel(w, out):  # type: ignore[no-untyped-def]
    """Rotation matrix of the rotation vector ``w`` (3,) rad, into ``out`` (3, 3):
    ``I + A W + B W²`` with ``W = hat(w)``, ``A = sin θ/θ``, ``B = (1 - cos θ)/θ²``."""
    x, y, z = w[0], w[1], w[2]
    t2 = x * x + y * y + z * z
    th = math.sqrt(t2)
    if th < SMALL:
        a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0
    else:
        a = math.sin(th) / th
        h = math.sin(0.5 * th)
        b = 2.0 * h * h / t2
    out[0, 0] = 1.0 - b * (y * y + z * z)
    out[1, 1] = 1.0 - b * (x * x + z * z)
    out[2, 2] = 1.0 - b * (x * x + y * y)
    out[0, 1] = b * x * y - a * z
    out[1, 0] = b * x * y + a * z
    out[0, 2] = b * x * z + a * y
    out[2, 0] = b * x * z - a * y
    out[1, 2] = b * y * z - a * x
    out[2, 1] = b * y * z + a * x


@njit(cache=True, nogil=True)
def so3_log_kernel(R, out):  # type: ignore[no-untyped-def]
    """Rotation vector (3,) rad of the rotation matrix ``R``, into ``out``;
    angle in [0, π]."""
    vx = R[2, 1] - R[1, 2]
    vy = R[0, 2] - R[2, 0]
    vz = R[1, 0] - R[0, 1]
    s = 0.5 * math.sqrt(vx * vx + vy * vy + vz * vz)
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    th = math.atan2(s, c)
    if th < SMALL:
        f = 0.5 * (1.0 + th * th / 6.0 + 7.0 * th ** 4 / 360.0)
        out[0], out[1], out[2] = f * vx, f * vy, f * vz
    elif c > -0.866:  # below 150°
        f = 0.5 * th / s
        out[0], out[1], out[2] = f * vx, f * vy, f * vz
    else:
        # (R + Rᵀ)/2 - c I = (1 - c) u uᵀ: the column of the largest diagonal
        k = 0
        for i in range(1, 3):
            if R[i, i] > R[k, k]:
                k = i
        bkk = R[k, k] - c
        g = 1.0 / math.sqrt((1.0 - c) * bkk)
        ux = 0.5 * (R[0, k] + R[k, 0]) * g
        uy = 0.5 * (R[1, k] + R[k, 1]) * g
        uz = 0.5 * (R[2, k] + R[k, 2]) * g
        if k == 0:
            ux = bkk * g
        elif k == 1:
            uy = bkk * g
        else:
            uz = bkk * g
        if ux * vx + uy * vy + uz * vz < 0.0:
            th = -th
        out[0], out[1], out[2] = th * ux, th * uy, th * uz


@njit(cache=True, nogil=True)
def quat_to_rot_kernel(q, out):  # type: ignore[no-untyped-def]
    """Rotation matrix (3, 3) of the quaternion ``q`` (x, y, z, w), normalised first."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    x, y, z, w = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - z * w)
    out[0, 2] = 2.0 * (x * z + y * w)
    out[1, 0] = 2.0 * (x * y + z * w)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - x * w)
    out[2, 0] = 2.0 * (x * z - y * w)
    out[2, 1] = 2.0 * (y * z + x * w)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@njit(cache=True, nogil=True)
def rot_to_quat_kernel(R, out):  # type: ignore[no-untyped-def]
    """Unit quaternion (x, y, z, w) with ``w >= 0`` of the rotation matrix ``R``,
    into ``out`` (from the largest of the four ``|x|, |y|, |z|, |w|``, so no
    square root of a small number)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr >= R[0, 0] and tr >= R[1, 1] and tr >= R[2, 2]:
        w = 0.5 * math.sqrt(1.0 + tr)
        f = 0.25 / w
        x, y, z = (R[2, 1] - R[1, 2]) * f, (R[0, 2] - R[2, 0]) * f, (R[1, 0] - R[0, 1]) * f
    elif R[0, 0] >= R[1, 1] and R[0, 0] >= R[2, 2]:
        x = 0.5 * math.sqrt(1.0 + 2.0 * R[0, 0] - tr)
        f = 0.25 / x
        w, y, z = (R[2, 1] - R[1, 2]) * f, (R[0, 1] + R[1, 0]) * f, (R[0, 2] + R[2, 0]) * f
    elif R[1, 1] >= R[2, 2]:
        y = 0.5 * math.sqrt(1.0 + 2.0 * R[1, 1] - tr)
        f = 0.25 / y
        w, x, z = (R[0, 2] - R[2, 0]) * f, (R[0, 1] + R[1, 0]) * f, (R[1, 2] + R[2, 1]) * f
    else:
        z = 0.5 * math.sqrt(1.0 + 2.0 * R[2, 2] - tr)
        f = 0.25 / z
        w, x, y = (R[1, 0] - R[0, 1]) * f, (R[0, 2] + R[2, 0]) * f, (R[1, 2] + R[2, 1]) * f
    if w < 0.0:
        x, y, z, w = -x, -y, -z, -w
    n = math.sqrt(x * x + y * y + z * z + w * w)
    out[0], out[1], out[2], out[3] = x / n, y / n, z / n, w / n


@njit(cache=True, nogil=True)
def quat_mul_kernel(a, b, out):  # type: ignore[no-untyped-def]
    """Hamilton product ``a ⊗ b`` of (x, y, z, w) quaternions, into ``out``."""
    ax, ay, az, aw = a[0], a[1], a[2], a[3]
    bx, by, bz, bw = b[0], b[1], b[2], b[3]
    out[0] = aw * bx + ax * bw + ay * bz - az * by
    out[1] = aw * by - ax * bz + ay * bw + az * bx
    out[2] = aw * bz + ax * by - ay * bx + az * bw
    out[3] = aw * bw - ax * bx - ay * by - az * bz


@njit(cache=True, nogil=True)
def quat_slerp_kernel(q0, q1, s, out):  # type: ignore[no-untyped-def]
    """Spherical interpolation from ``q0`` (s = 0) to ``q1`` (s = 1) along the
    shorter arc, into ``out`` (unit): ``q0 ⊗ r^s`` with ``r = q0* ⊗ q1``,
    both normalised first. Exact at ``s = 0`` up to that normalisation."""
    n0 = math.sqrt(q0[0] * q0[0] + q0[1] * q0[1] + q0[2] * q0[2] + q0[3] * q0[3])
    n1 = math.sqrt(q1[0] * q1[0] + q1[1] * q1[1] + q1[2] * q1[2] + q1[3] * q1[3])
    ax, ay, az, aw = q0[0] / n0, q0[1] / n0, q0[2] / n0, q0[3] / n0
    bx, by, bz, bw = q1[0] / n1, q1[1] / n1, q1[2] / n1, q1[3] / n1
    # r = conj(a) ⊗ b
    rx = aw * bx - ax * bw - ay * bz + az * by
    ry = aw * by + ax * bz - ay * bw - az * bx
    rz = aw * bz - ax * by + ay * bx - az * bw
    rw = aw * bw + ax * bx + ay * by + az * bz
    if rw < 0.0:
        rx, ry, rz, rw = -rx, -ry, -rz, -rw
    sn = math.sqrt(rx * rx + ry * ry + rz * rz)
    half = math.atan2(sn, rw)
    if half < 1e-8:
        f = s  # sin(s h)/sin(h), error below 1e-16
    else:
        f = math.sin(s * half) / sn
    px, py, pz, pw = f * rx, f * ry, f * rz, math.cos(s * half)
    # a ⊗ r^s
    x = aw * px + ax * pw + ay * pz - az * py
    y = aw * py - ax * pz + ay * pw + az * px
    z = aw * pz + ax * py - ay * px + az * pw
    w = aw * pw - ax * px - ay * py - az * pz
    n = math.sqrt(x * x + y * y + z * z + w * w)
    out[0], out[1], out[2], out[3] = x / n, y / n, z / n, w / n


@njit(cache=True, nogil=True)
def _jacobian_series(t2):  # type: ignore[no-untyped-def]
    """``(A, B, C)`` of the SO(3)/SE(3) exponential at ``θ² = t2``:
    ``sin θ/θ``, ``(1 - cos θ)/θ²``, ``(θ - sin θ)/θ³``."""
    th = math.sqrt(t2)
    if th < SMALL:
        return (1.0 - t2 / 6.0 + t2 * t2 / 120.0, 0.5 - t2 / 24.0 + t2 * t2 / 720.0,
                1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0)
    h = math.sin(0.5 * th)
    return math.sin(th) / th, 2.0 * h * h / t2, (th - math.sin(th)) / (t2 * th)


@njit(cache=True, nogil=True)
def se3_exp_kernel(xi, R, t):  # type: ignore[no-untyped-def]
    """Pose ``(R, t)`` of the twist ``xi = (ω, v)`` (rad, m), rotation first:
    ``R = exp(ω)``, ``t = V v`` with ``V = I + B W + C W²``."""
    so3_exp_kernel(xi[:3], R)
    x, y, z = xi[0], xi[1], xi[2]
    _, b, c = _jacobian_series(x * x + y * y + z * z)
    vx, vy, vz = xi[3], xi[4], xi[5]
    # W v and W (W v)
    wx, wy, wz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
    ux, uy, uz = y * wz - z * wy, z * wx - x * wz, x * wy - y * wx
    t[0] = vx + b * wx + c * ux
    t[1] = vy + b * wy + c * uy
    t[2] = vz + b * wz + c * uz


@njit(cache=True, nogil=True)
def se3_log_kernel(R, t, out):  # type: ignore[no-untyped-def]
    """Twist ``(ω, v)`` (6,), rotation first, of the pose ``(R, t)``:
    ``ω = log R``, ``v = V⁻¹ t`` with ``V⁻¹ = I - W/2 + D W²``,
    ``D = (1 - A / (2 B)) / θ²``."""
    so3_log_kernel(R, out[:3])
    x, y, z = out[0], out[1], out[2]
    t2 = x * x + y * y + z * z
    if math.sqrt(t2) < SMALL:
        d = 1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
    else:
        a, b, _ = _jacobian_series(t2)
        d = (1.0 - a / (2.0 * b)) / t2
    px, py, pz = t[0], t[1], t[2]
    wx, wy, wz = y * pz - z * py, z * px - x * pz, x * py - y * px
    ux, uy, uz = y * wz - z * wy, z * wx - x * wz, x * wy - y * wx
    out[3] = px - 0.5 * wx + d * ux
    out[4] = py - 0.5 * wy + d * uy
    out[5] = pz - 0.5 * wz + d * uz


@njit(cache=True, nogil=True)
def interpolate_poses_kernel(tq, t, position, orientation, out_pos, out_ori, valid):  # type: ignore[no-untyped-def]
    """Poses at the times ``tq`` (µs) from samples at the non-decreasing
    times ``t`` (µs): at a sample time, that sample itself (the last of
    equal times); between two samples, linear in position and slerp in
    orientation; outside ``[t[0], t[-1]]``, ``valid`` false and NaN."""
    n = t.shape[0]
    for i in range(tq.shape[0]):
        q = tq[i]
        if n == 0 or q < t[0] or q > t[n - 1]:
            valid[i] = False
            out_pos[i, :] = np.nan
            out_ori[i, :] = np.nan
            continue
        valid[i] = True
        j = np.searchsorted(t, q, side="right") - 1  # t[j] <= q < t[j + 1]
        if t[j] == q:
            out_pos[i, :] = position[j]
            out_ori[i, :] = orientation[j]
            continue
        s = (q - t[j]) / (t[j + 1] - t[j])
        for k in range(3):
            out_pos[i, k] = position[j, k] + s * (position[j + 1, k] - position[j, k])
        quat_slerp_kernel(orientation[j], orientation[j + 1], s, out_ori[i])


# -- a gyro's samples integrated -------------------------------------------------
@njit(cache=True, nogil=True)
def _gyro_step(w, dt, out):  # type: ignore[no-untyped-def]
    """``exp(hat(w) dt)`` into ``out``: ``w`` rad/s (3,), ``dt`` s."""
    so3_exp_kernel(w * dt, out)


@njit(cache=True, nogil=True)
def gyro_rotations(t, knot_t, knot_w, t_ref):  # type: ignore[no-untyped-def]
    """Rotation ``R_ref_from_t`` (N, 3, 3): camera at ``t_ref`` from camera at
    each time ``t`` (int64 µs, sorted, all >= ``knot_t[0]``, none past
    ``t_ref``), given gyro knots: ω ``knot_w[k]`` (rad/s, camera frame)
    held over ``[knot_t[k], knot_t[k+1])`` (zero-order hold; the last
    one onwards). Orientation follows ``dR/dt = R hat(ω)``."""
    m = knot_t.shape[0]
    step = np.empty((3, 3))
    # orientation at each knot relative to knot 0, then at t_ref
    Rk = np.empty((m, 3, 3))
    Rk[0] = np.eye(3)
    for k in range(1, m):
        _gyro_step(knot_w[k - 1], (knot_t[k] - knot_t[k - 1]) * 1e-6, step)
        Rk[k] = Rk[k - 1] @ step
    k = m - 1
    while k > 0 and knot_t[k] > t_ref:
        k -= 1
    _gyro_step(knot_w[k], (t_ref - knot_t[k]) * 1e-6, step)
    R_ref_T = (Rk[k] @ step).T.copy()
    out = np.empty((t.shape[0], 3, 3))
    k = 0
    for i in range(t.shape[0]):
        while k + 1 < m and knot_t[k + 1] <= t[i]:
            k += 1
        _gyro_step(knot_w[k], (t[i] - knot_t[k]) * 1e-6, step)
        out[i] = R_ref_T @ (Rk[k] @ step)
    return out


@njit(cache=True, nogil=True)
def gyro_turn(knot_t, knot_w, t0, t1):  # type: ignore[no-untyped-def]
    """The turn ``R(t0)ᵀ R(t1)`` (3, 3) from ``t0`` to ``t1`` µs (``knot_t[0]
    <= t0 <= t1``) of an orientation following ``dR/dt = R hat(ω)``, ω held
    from each gyro knot (``knot_t`` int64 µs sorted, ``knot_w`` rad/s) to
    the next: the product of the held steps inside the span, in time order
    (knots before the one holding at ``t0`` are not read, so the result
    does not depend on how many older knots are kept)."""
    k = 0
    while k + 1 < knot_t.shape[0] and knot_t[k + 1] <= t0:
        k += 1
    out = np.eye(3)
    step = np.empty((3, 3))
    t = t0
    while t < t1:
        end = t1
        if k + 1 < knot_t.shape[0] and knot_t[k + 1] < t1:
            end = knot_t[k + 1]
        _gyro_step(knot_w[k], (end - t) * 1e-6, step)
        out = out @ step
        t = end
        k += 1
    return out


# -- loops over stacks ------------------------------------------------------------
# One loop per kernel: a loop taking the kernel as an argument is not cached by
# numba (its dispatcher type differs in each process), so it would compile anew.
@njit(cache=True, nogil=True)
def _so3_exp_many(w, out):  # type: ignore[no-untyped-def]
    for i in range(w.shape[0]):
        so3_exp_kernel(w[i], out[i])


@njit(cache=True, nogil=True)
def _so3_log_many(R, out):  # type: ignore[no-untyped-def]
    for i in range(R.shape[0]):
        so3_log_kernel(R[i], out[i])


@njit(cache=True, nogil=True)
def _quat_to_rot_many(q, out):  # type: ignore[no-untyped-def]
    for i in range(q.shape[0]):
        quat_to_rot_kernel(q[i], out[i])


@njit(cache=True, nogil=True)
def _rot_to_quat_many(R, out):  # type: ignore[no-untyped-def]
    for i in range(R.shape[0]):
        rot_to_quat_kernel(R[i], out[i])


@njit(cache=True, nogil=True)
def _quat_mul_many(a, b, out):  # type: ignore[no-untyped-def]
    for i in range(out.shape[0]):
        quat_mul_kernel(a[i % a.shape[0]], b[i % b.shape[0]], out[i])


@njit(cache=True, nogil=True)
def _quat_slerp_many(q0, q1, s, out):  # type: ignore[no-untyped-def]
    for i in range(out.shape[0]):
        quat_slerp_kernel(q0[i % q0.shape[0]], q1[i % q1.shape[0]], s[i % s.shape[0]], out[i])


@njit(cache=True, nogil=True)
def _se3_exp_many(xi, R, t):  # type: ignore[no-untyped-def]
    for i in range(xi.shape[0]):
        se3_exp_kernel(xi[i], R[i], t[i])


@njit(cache=True, nogil=True)
def _se3_log_many(R, t, out):  # type: ignore[no-untyped-def]
    for i in range(R.shape[0]):
        se3_log_kernel(R[i], t[i], out[i])


# -- typed wrappers -------------------------------------------------------------------
def _stack(a: object, shape: tuple[int, ...], name: str) -> tuple[np.ndarray, bool]:
    """``a`` as a C-contiguous float64 stack ``(N, *shape)`` of finite values,
    and whether it was a single element."""
    arr = np.asarray(a, np.float64)
    single = arr.shape == shape
    if single:
        arr = arr[None]
    if arr.ndim != len(shape) + 1 or arr.shape[1:] != shape:
        want = ", ".join(map(str, shape))
        raise ValueError(f"{name}: expected shape ({want}) or (N, {want}), got {arr.shape}")
    bad = ~np.isfinite(arr).all(axis=tuple(range(1, arr.ndim)))
    if bad.any():
        raise ValueError(f"{name}: not finite (NaN or inf) at index {int(np.argmax(bad))}")
    return np.ascontiguousarray(arr), single


def _quats(q: object, name: str) -> tuple[np.ndarray, bool]:
    """Quaternions (x, y, z, w), checked: finite and of norm 1 within :data:`QUAT_TOL`."""
    arr, single = _stack(q, (4,), name)
    err = np.abs(np.linalg.norm(arr, axis=1) - 1.0)
    if err.size and err.max() > QUAT_TOL:
        i = int(np.argmax(err))
        raise ValueError(f"{name}: quaternion {i} {arr[i].tolist()} has norm {np.linalg.norm(arr[i]):.6g}, "
                         f"not 1 (tolerance {QUAT_TOL})")
    return arr, single


def _rotations(R: object, name: str) -> tuple[np.ndarray, bool]:
    """Rotation matrices, checked: ``RᵀR = I`` and ``det R = 1`` within :data:`ROT_TOL`."""
    arr, single = _stack(R, (3, 3), name)
    if not len(arr):
        return arr, single
    err = np.abs(np.einsum("nji,njk->nik", arr, arr) - np.eye(3)).max(axis=(1, 2))
    err = np.maximum(err, np.abs(np.linalg.det(arr) - 1.0))
    if err.max() > ROT_TOL:
        i = int(np.argmax(err))
        raise ValueError(f"{name}: matrix {i} is not a rotation (|RᵀR - I| or |det R - 1| = {err[i]:.3g})")
    return arr, single


def _out(arr: np.ndarray, single: bool) -> np.ndarray:
    return arr[0] if single else arr


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ``W`` of ``w`` (3,) or (N, 3): ``W p = w × p``."""
    arr, single = _stack(w, (3,), "hat")
    out = np.zeros((len(arr), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -arr[:, 2], arr[:, 1], -arr[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = arr[:, 2], -arr[:, 1], arr[:, 0]
    return _out(out, single)


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector ``omega`` (3,) in rad
    (axis times angle), or (N, 3, 3) of (N, 3)."""
    w, single = _stack(omega, (3,), "so3_exp")
    out = np.empty((len(w), 3, 3))
    _so3_exp_many(w, out)
    return _out(out, single)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) rad, angle in [0, π], of a rotation matrix (3, 3),
    or (N, 3) of (N, 3, 3). ValueError when ``R`` is not a rotation."""
    r, single = _rotations(R, "so3_log")
    out = np.empty((len(r), 3))
    _so3_log_many(r, out)
    return _out(out, single)


def rotation_matrix(values: object, name: str = "rotation") -> np.ndarray:
    """A rotation (3, 3) given as nothing (the identity), 3 numbers (a
    rotation vector, rad) or 9 (a matrix, row by row); ValueError naming
    ``name`` otherwise (an operator's parameter, e.g. ``imu_rotation``)."""
    v = np.asarray(values, np.float64).ravel()
    if not v.size:
        return np.eye(3)
    if not np.isfinite(v).all():
        raise ValueError(f"{name}: the numbers must be finite")
    if v.size == 3:
        return np.asarray(so3_exp(v))
    if v.size == 9:
        R = v.reshape(3, 3)
        if not np.allclose(R @ R.T, np.eye(3), atol=ROT_TOL) or np.linalg.det(R) < 0:
            raise ValueError(f"{name} as 9 numbers must be a rotation matrix (row by row)")
        return R
    raise ValueError(f"{name} takes 3 numbers (a rotation vector, rad) or 9 (a matrix), got {v.size}")


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (x, y, z, w), or (N, 3, 3) of (N, 4)."""
    a, single = _quats(q, "quat_to_rot")
    out = np.empty((len(a), 3, 3))
    _quat_to_rot_many(a, out)
    return _out(out, single)


def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w), ``w >= 0``, of a rotation matrix (3, 3),
    or (N, 4) of (N, 3, 3)."""
    r, single = _rotations(R, "rot_to_quat")
    out = np.empty((len(r), 4))
    _rot_to_quat_many(r, out)
    return _out(out, single)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` (the rotation ``a`` after ``b``); (4,) or
    (N, 4) each, a single one broadcast against a stack."""
    qa, sa = _quats(a, "quat_mul a")
    qb, sb = _quats(b, "quat_mul b")
    n = _common_length((qa, qb), "quat_mul")
    out = np.empty((n, 4))
    _quat_mul_many(qa, qb, out)
    return _out(out, sa and sb)


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (x, y, z, w) -> (-x, -y, -z, w): the inverse rotation of a unit quaternion."""
    a, single = _quats(q, "quat_conj")
    out = a * np.array([-1.0, -1.0, -1.0, 1.0])
    return _out(out, single)


def quat_slerp(q0: np.ndarray, q1: np.ndarray, s: float | np.ndarray) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc, ``q0`` at
    ``s = 0`` and ``q1`` at ``s = 1``; quaternions (4,) or (N, 4), ``s``
    scalar or (N,), single ones broadcast."""
    a, sa = _quats(q0, "quat_slerp q0")
    b, sb = _quats(q1, "quat_slerp q1")
    ss = np.ascontiguousarray(np.atleast_1d(np.asarray(s, np.float64)))
    if ss.ndim != 1 or not np.isfinite(ss).all():
        raise ValueError(f"quat_slerp: s must be a finite scalar or (N,) array, got shape {ss.shape}")
    n = _common_length((a, b, ss), "quat_slerp")
    out = np.empty((n, 4))
    _quat_slerp_many(a, b, ss, out)
    return _out(out, sa and sb and np.ndim(s) == 0)


def _common_length(arrays: tuple[np.ndarray, ...], name: str) -> int:
    lengths = {len(a) for a in arrays} - {1}
    if len(lengths) > 1:
        raise ValueError(f"{name}: stacks of different lengths {sorted(lengths)}")
    return lengths.pop() if lengths else 1


def interpolate_poses(t_query: np.ndarray, t: np.ndarray, position: np.ndarray,
                      orientation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses at the times ``t_query`` (M,) µs from samples at the times
    ``t`` (N,) µs, non-decreasing, with ``position`` (N, 3) m and unit
    ``orientation`` (N, 4) (x, y, z, w), as a :class:`~tectum.PosePacket`
    holds them.

    Returns ``(position (M, 3), orientation (M, 4), valid (M,) bool)``: at a
    sample time the sample itself, bit for bit; between samples, linear in
    position and slerp in orientation; outside ``[t[0], t[-1]]`` never
    extrapolated: ``valid`` is false and the values NaN."""
    tq, ts = np.asarray(t_query), np.asarray(t)
    for name, a in (("t_query", tq), ("t", ts)):
        if a.ndim != 1 or not (np.issubdtype(a.dtype, np.integer) or a.size == 0):
            raise ValueError(f"interpolate_poses: {name} must be 1-D integer µs, got {a.dtype} {a.shape}")
    tq, ts = np.ascontiguousarray(tq, np.int64), np.ascontiguousarray(ts, np.int64)
    pos, _ = _stack(position, (3,), "interpolate_poses position")
    ori, _ = _quats(orientation, "interpolate_poses orientation")
    if not len(ts) == len(pos) == len(ori):
        raise ValueError(f"interpolate_poses: {len(ts)} times, {len(pos)} positions, {len(ori)} orientations")
    back = np.flatnonzero(np.diff(ts) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise ValueError(f"interpolate_poses: sample times go back at index {i} ({ts[i - 1]} -> {ts[i]} µs)")
    out_pos, out_ori, valid = np.empty((len(tq), 3)), np.empty((len(tq), 4)), np.empty(len(tq), np.bool_)
    interpolate_poses_kernel(tq, ts, pos, ori, out_pos, out_ori, valid)
    return out_pos, out_ori, valid


def se3_exp(xi: np.ndarray) -> Pose:
    """Pose ``(R (3, 3), t (3,))`` of a twist ``xi = (ω, v)`` (6,): rotation
    first (rad), then translation (m); stacks (N, 6) give (N, 3, 3), (N, 3)."""
    x, single = _stack(xi, (6,), "se3_exp")
    R, t = np.empty((len(x), 3, 3)), np.empty((len(x), 3))
    _se3_exp_many(x, R, t)
    return _out(R, single), _out(t, single)


def se3_log(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Twist ``(ω, v)`` (6,), rotation first, of the pose ``(R, t)``; the
    inverse of :func:`se3_exp` for rotation angles below π."""
    r, single = _rotations(R, "se3_log R")
    tt, _ = _stack(t, (3,), "se3_log t")
    if len(tt) != len(r):
        raise ValueError(f"se3_log: {len(r)} rotations, {len(tt)} translations")
    out = np.empty((len(r), 6))
    _se3_log_many(r, tt, out)
    return _out(out, single)


def transform_points(R: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``R p + t`` for each point of ``points`` (N, 3) (or one (3,)): with a
    world-from-camera pose, camera-frame points to world points (m)."""
    P = np.asarray(points, np.float64)
    if P.shape[-1:] != (3,) or P.ndim > 2:
        raise ValueError(f"transform_points: points must be (N, 3) or (3,), got {P.shape}")
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"transform_points: R must be (3, 3) and t (3,), got {R.shape} and {t.shape}")
    return P @ R.T + t


@overload
def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray: ...
@overload
def compose(a: Pose, b: Pose) -> Pose: ...
def compose(a: np.ndarray | Pose, b: np.ndarray | Pose) -> np.ndarray | Pose:
    """``a ∘ b``: ``T_ac = compose(T_ab, T_bc)``, as 4x4 matrices (or stacks
    (N, 4, 4)) or as ``(R, t)`` pairs: ``(R_a R_b, R_a t_b + t_a)``."""
    if isinstance(a, tuple) and isinstance(b, tuple):
        Ra, ta = _pose(a, "compose a")
        Rb, tb = _pose(b, "compose b")
        return Ra @ Rb, Ra @ tb + ta
    if isinstance(a, tuple) or isinstance(b, tuple):
        raise ValueError("compose: both poses must be 4x4 matrices or both (R, t) pairs")
    return _matrix4(a, "compose a") @ _matrix4(b, "compose b")


@overload
def invert(T: np.ndarray) -> np.ndarray: ...
@overload
def invert(T: Pose) -> Pose: ...
def invert(T: np.ndarray | Pose) -> np.ndarray | Pose:
    """Inverse pose ``(Rᵀ, -Rᵀ t)``, as a 4x4 matrix (or a stack) or an ``(R, t)`` pair."""
    if isinstance(T, tuple):
        R, t = _pose(T, "invert")
        return R.T, -(R.T @ t)
    M = _matrix4(T, "invert")
    out = np.zeros_like(M)
    Rt = np.swapaxes(M[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ M[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def _pose(T: Pose, name: str) -> Pose:
    R, t = (np.asarray(v, np.float64) for v in T)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"{name}: expected (R (3, 3), t (3,)), got {R.shape} and {t.shape}")
    return R, t


def _matrix4(T: np.ndarray, name: str) -> np.ndarray:
    M = np.asarray(T, np.float64)
    if M.shape[-2:] != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 matrix or a (N, 4, 4) stack, got {M.shape}")
    return M
