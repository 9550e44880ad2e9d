"""The per-point math of :class:`tectum.camera.Camera`: numba kernels on one
point, parameters packed in one float64 array (:func:`pack`).

Models (``x, y`` undistorted normalised coordinates ``X/Z, Y/Z``; ``xd, yd``
distorted; pixels ``u = fx xd + cx``, ``v = fy yd + cy``):

* ``radtan``, OpenCV's full model: ``r² = x² + y²``,
  ``g = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)``,
  ``xd = x g + 2 p1 x y + p2 (r² + 2 x²) + s1 r² + s2 r⁴``,
  ``yd = y g + p1 (r² + 2 y²) + 2 p2 x y + s3 r² + s4 r⁴``, then the tilt
  homography of ``τx, τy`` (identity without them). Coefficients in OpenCV
  order ``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [τx τy]]]]``.
* ``equidistant``, OpenCV's fisheye (Kannala-Brandt with four terms):
  ``θ = atan r``, ``θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)``,
  ``(xd, yd) = (θd / r) (x, y)``.

Undistortion inverts the model on its first branch, the part around the
optical axis where it increases (for radtan both eigenvalues of the
Jacobian positive, for equidistant ``dθd/dθ > 0``): polynomial models fold
back beyond it, and a pixel farther out than the fold is the image of no
ray the calibration describes. Newton's method (2-D on the radtan model, on
``θ`` for the equidistant one) starts at ``(xd, yd)``, pulled towards the
axis until the model increases there; a step is halved until it lands
where the model still increases and the residual has not grown (plain
Newton can cycle across the inflection of a pincushion lens), and the
iteration stops when the step is below ``1e-12`` (the error, quadratic in
the step, is then at rounding level). The result is NaN unless the residual
is below ``RES_TOL``, there is no fold between the root and the axis
(checked at ``FOLD_CHECKS`` points) and ``θ < π/2``. OpenCV's fixed-point
iteration (five steps by default) returns a point there too, one that does
not map back to the pixel.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["pack", "project_kernel", "distort_kernel", "undistort_kernel", "pixel_to_normalized_kernel",
           "RADTAN", "EQUIDISTANT", "MODELS"]

#: model codes in ``params[MODEL]``
RADTAN, EQUIDISTANT = 0, 1
MODELS = {"radtan": RADTAN, "equidistant": EQUIDISTANT}
#: layout of ``params``: fx fy cx cy, model, 12 coefficients, tilt and its inverse (3x3 row-major)
FX, FY, CX, CY, MODEL, COEF, TILT, UNTILT, NPARAMS = 0, 1, 2, 3, 4, 5, 17, 26, 35
#: Newton steps, and halvings of one step, before a point is given up (NaN)
MAX_ITER, MAX_HALVINGS = 50, 40
#: largest residual |distort(x) - xd| (normalised) of an accepted inverse
RES_TOL = 1e-10
#: points checked for a fold between a solution and the optical axis
FOLD_CHECKS = 8
_STEP = 1e-12


def tilt_matrix(tau_x: float, tau_y: float) -> np.ndarray:
    """OpenCV's tilted-sensor homography for the angles ``τx, τy`` (rad):
    the rotation ``Ry(τy) Rx(τx)`` followed by the projection back onto
    ``z = 1`` along the optical axis."""
    cx, sx, cy, sy = math.cos(tau_x), math.sin(tau_x), math.cos(tau_y), math.sin(tau_y)
    rot = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]]) @ np.array([[1, 0, 0], [0, cx, sx], [0, -sx, cx]])
    proj = np.array([[rot[2, 2], 0, -rot[0, 2]], [0, rot[2, 2], -rot[1, 2]], [0, 0, 1]])
    return np.asarray(proj @ rot)


def pack(K: np.ndarray, D: np.ndarray, model: str) -> np.ndarray:
    """The kernels' parameter array of a camera matrix ``K``, coefficients
    ``D`` (already validated for ``model``)."""
    params = np.zeros(NPARAMS)
    params[[FX, FY, CX, CY]] = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    params[MODEL] = MODELS[model]
    n = min(D.size, 12)
    params[COEF:COEF + n] = D[:n]
    tilt = tilt_matrix(D[12], D[13]) if D.size == 14 else np.eye(3)
    params[TILT:TILT + 9] = tilt.ravel()
    params[UNTILT:UNTILT + 9] = np.linalg.inv(tilt).ravel()
    return params


# -- the models ---------------------------------------------------------------------
@njit(cache=True, nogil=True)
def _homography(params, at, x, y):  # type: ignore[no-untyped-def]
    """The 3x3 matrix at ``params[at:at + 9]`` applied to ``(x, y, 1)``, dehomogenised."""
    a = params[at] * x + params[at + 1] * y + params[at + 2]
    b = params[at + 3] * x + params[at + 4] * y + params[at + 5]
    c = params[at + 6] * x + params[at + 7] * y + params[at + 8]
    return a / c, b / c


@njit(cache=True, nogil=True)
def _radtan(params, x, y):  # type: ignore[no-untyped-def]
    """Radtan distortion before the tilt, and its Jacobian ``d(xd, yd)/d(x, y)``."""
    k = params[COEF:COEF + 12]
    x2, y2, xy = x * x, y * y, x * y
    r2 = x2 + y2
    num = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))
    den = 1.0 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
    g = num / den
    dg = ((k[0] + r2 * (2.0 * k[1] + 3.0 * r2 * k[4])) * den
          - (k[5] + r2 * (2.0 * k[6] + 3.0 * r2 * k[7])) * num) / (den * den)  # dg/d(r²)
    p1, p2 = k[2], k[3]
    xd = x * g + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2) + r2 * (k[8] + k[9] * r2)
    yd = y * g + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy + r2 * (k[10] + k[11] * r2)
    ex = 2.0 * (k[8] + 2.0 * k[9] * r2)  # d(s1 r² + s2 r⁴)/d(r²) times 2
    ey = 2.0 * (k[10] + 2.0 * k[11] * r2)
    j00 = g + 2.0 * x2 * dg + 2.0 * p1 * y + 6.0 * p2 * x + x * ex
    j01 = 2.0 * xy * dg + 2.0 * p1 * x + 2.0 * p2 * y + y * ex
    j10 = 2.0 * xy * dg + 2.0 * p1 * x + 2.0 * p2 * y + x * ey
    j11 = g + 2.0 * y2 * dg + 6.0 * p1 * y + 2.0 * p2 * x + y * ey
    return xd, yd, j00, j01, j10, j11


@njit(cache=True, nogil=True)
def _theta_d(params, th):  # type: ignore[no-untyped-def]
    """Equidistant ``θd(θ)`` and ``dθd/dθ``."""
    k = params[COEF:COEF + 4]
    t2 = th * th
    poly = 1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))
    deriv = 1.0 + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])))
    return th * poly, deriv


@njit(cache=True, nogil=True)
def distort_kernel(params, x, y):  # type: ignore[no-untyped-def]
    """Distorted normalised coordinates ``(xd, yd)`` of the undistorted ``(x, y)``."""
    if params[MODEL] == EQUIDISTANT:
        r = math.sqrt(x * x + y * y)
        if r <= 1e-8:
            return x, y
        td, _ = _theta_d(params, math.atan(r))
        return x * td / r, y * td / r
    xd, yd, _, _, _, _ = _radtan(params, x, y)
    return _homography(params, TILT, xd, yd)


@njit(cache=True, nogil=True)
def _increasing(j00, j01, j10, j11):  # type: ignore[no-untyped-def]
    """Whether both eigenvalues of the Jacobian have positive real parts
    (determinant and trace positive): for a radial model, both the radial
    derivative and the scale ``g``; the determinant alone is positive past
    the fold too, where both are negative."""
    return j00 * j11 - j01 * j10 > 0.0 and j00 + j11 > 0.0


@njit(cache=True, nogil=True)
def _increasing_at(params, x, y):  # type: ignore[no-untyped-def]
    """Whether the model increases at ``(x, y)`` (the equidistant one at ``θ = x``)."""
    if params[MODEL] == EQUIDISTANT:
        return _theta_d(params, x)[1] > 0.0
    _, _, j00, j01, j10, j11 = _radtan(params, x, y)
    return _increasing(j00, j01, j10, j11)


@njit(cache=True, nogil=True)
def _on_first_branch(params, x, y):  # type: ignore[no-untyped-def]
    """Whether the model increases at ``(x, y)`` and at ``FOLD_CHECKS - 1``
    points between it and the optical axis: a root past a fold is no inverse."""
    for i in range(1, FOLD_CHECKS + 1):
        f = i / FOLD_CHECKS
        if not _increasing_at(params, f * x, f * y):
            return False
    return True


@njit(cache=True, nogil=True)
def _invert_radtan(params, xd, yd):  # type: ignore[no-untyped-def]
    x0, y0 = _homography(params, UNTILT, xd, yd)
    x, y = x0, y0
    while not _increasing_at(params, x, y) and x * x + y * y > 1e-300:
        x, y = 0.5 * x, 0.5 * y
    fx, fy, j00, j01, j10, j11 = _radtan(params, x, y)
    rx, ry = fx - x0, fy - y0
    for _ in range(MAX_ITER):
        det = j00 * j11 - j01 * j10
        dx, dy = (j11 * rx - j01 * ry) / det, (j00 * ry - j10 * rx) / det
        accepted = False
        for _ in range(MAX_HALVINGS):
            fx, fy, j00, j01, j10, j11 = _radtan(params, x - dx, y - dy)
            if _increasing(j00, j01, j10, j11) and (fx - x0) ** 2 + (fy - y0) ** 2 <= rx * rx + ry * ry:
                accepted = True
                break
            dx, dy = 0.5 * dx, 0.5 * dy
        if not accepted:
            break
        x, y, rx, ry = x - dx, y - dy, fx - x0, fy - y0
        if dx * dx + dy * dy < _STEP * _STEP:
            break
    if rx * rx + ry * ry < RES_TOL * RES_TOL and _on_first_branch(params, x, y):
        return x, y
    return np.nan, np.nan


@njit(cache=True, nogil=True)
def _invert_equidistant(params, xd, yd):  # type: ignore[no-untyped-def]
    td = math.sqrt(xd * xd + yd * yd)
    if td == 0.0:
        return xd, yd
    th = td
    while not _increasing_at(params, th, 0.0) and th > 1e-300:
        th *= 0.5
    f, d = _theta_d(params, th)
    r = f - td
    for _ in range(MAX_ITER):
        step = r / d
        accepted = False
        for _ in range(MAX_HALVINGS):
            f, d = _theta_d(params, th - step)
            if d > 0.0 and abs(f - td) <= abs(r):
                accepted = True
                break
            step *= 0.5
        if not accepted:
            break
        th, r = th - step, f - td
        if abs(step) < _STEP:
            break
    if abs(r) < RES_TOL and 0.0 <= th < 0.5 * math.pi and _on_first_branch(params, th, 0.0):
        s = math.tan(th) / td
        return xd * s, yd * s
    return np.nan, np.nan


@njit(cache=True, nogil=True)
def undistort_kernel(params, xd, yd):  # type: ignore[no-untyped-def]
    """Undistorted normalised ``(x, y)`` of the distorted ``(xd, yd)``; NaN
    where the model has no inverse there (see the module notes)."""
    if params[MODEL] == EQUIDISTANT:
        return _invert_equidistant(params, xd, yd)
    return _invert_radtan(params, xd, yd)


@njit(cache=True, nogil=True)
def project_kernel(params, X, Y, Z):  # type: ignore[no-untyped-def]
    """Pixel ``(u, v)`` of the camera-frame point ``(X, Y, Z)`` (m); NaN
    unless ``Z > 0``."""
    if not Z > 0.0:
        return np.nan, np.nan
    xd, yd = distort_kernel(params, X / Z, Y / Z)
    return params[FX] * xd + params[CX], params[FY] * yd + params[CY]


@njit(cache=True, nogil=True)
def pixel_to_normalized_kernel(params, u, v):  # type: ignore[no-untyped-def]
    """Undistorted normalised ``(x, y)`` of the pixel ``(u, v)``: the ray
    ``(x, y, 1)``; NaN where the model has no inverse."""
    return undistort_kernel(params, (u - params[CX]) / params[FX], (v - params[CY]) / params[FY])


# -- loops over points --------------------------------------------------------------
@njit(cache=True, nogil=True)
def project_many(params, points, out):  # type: ignore[no-untyped-def]
    for i in range(points.shape[0]):
        out[i, 0], out[i, 1] = project_kernel(params, points[i, 0], points[i, 1], points[i, 2])


@njit(cache=True, nogil=True)
def distort_many(params, xy, out):  # type: ignore[no-untyped-def]
    for i in range(xy.shape[0]):
        out[i, 0], out[i, 1] = distort_kernel(params, xy[i, 0], xy[i, 1])


@njit(cache=True, nogil=True)
def undistort_many(params, xy, out):  # type: ignore[no-untyped-def]
    for i in range(xy.shape[0]):
        out[i, 0], out[i, 1] = undistort_kernel(params, xy[i, 0], xy[i, 1])


@njit(cache=True, nogil=True)
def undistort_pixels_many(params, uv, H, out):  # type: ignore[no-untyped-def]
    """Each pixel undistorted to its normalised ray ``(x, y, 1)``, then
    through the homography ``H`` (3, 3): ``H (x, y, 1)`` dehomogenised;
    NaN where undistortion fails or the ray falls behind ``H``'s plane."""
    for i in range(uv.shape[0]):
        x, y = pixel_to_normalized_kernel(params, uv[i, 0], uv[i, 1])
        c = H[2, 0] * x + H[2, 1] * y + H[2, 2]
        if c > 0.0:
            out[i, 0] = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / c
            out[i, 1] = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / c
        else:
            out[i, 0] = out[i, 1] = np.nan
