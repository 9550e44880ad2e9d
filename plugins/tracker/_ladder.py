"""The model ladder's contrast-maximisation core: warps, image of warped
events (IWE), focus and its gradient, held-out likelihood (numba kernels),
and the per-window fit and choice (plain Python around them).

**One warp for every rung.** Each motion model is a set of generators
``G_k`` (3x3) acting on an event's homogeneous normalised coordinates
``x~ = (x, y, 1)`` (``x = (u - cx) / fx`` on undistorted pixels); with
parameters ``theta`` the generator is ``A = sum_k theta_k G_k`` and the
event at ``dt`` seconds from the reference time is carried to it by
``M(dt) = exp(dt A)``, kept to second order,
``M = I + dt A + dt^2 A^2 / 2`` (the third-order term is below 0.1 % of the
displacement up to 0.2 rad of rotation per half window), then projected:
``x' = m1 / m3, y' = m2 / m3`` with ``m = M x~``. The rungs
(:data:`MODELS`, parameters in the user's units; see :func:`generators`):

* ``translation`` (vx, vy) px/s: the image content's velocity;
* ``rotation`` (wx, wy, wz) rad/s, camera frame, OpenCV axes: ``A =
  [w]x``, the exact rotational warp ``K R K^-1`` (Gallego & Scaramuzza,
  RA-L 2017); needs the calibration;
* ``similarity`` (vx, vy px/s, r rad/s, s 1/s): content velocity, its
  rotation rate about the principal point (from +x toward +y) and its
  scale rate (expansion positive);
* ``6dof`` (wx, wy, wz rad/s, ux, uy, uz 1/s): rigid motion in front of a
  fronto-parallel scene at one depth ``Z`` (the depth prior), ``u = v / Z``
  the camera velocity over that depth: ``A = [w]x + u e3^T``, the
  instantaneous homography of the plane ``Z = const``; needs the calibration;
* ``homography`` (8): the content's homography rate ``D`` in normalised
  coordinates (1/s; ``A = -D``, ``D22 = 0`` since a multiple of the
  identity moves nothing), rows ``d00 d01 d02 d10 d11 d12 d20 d21``.

They nest: translation in similarity in 6dof in homography, rotation in
6dof (for a translation in front of a fronto-parallel plane, 6dof with
``w = 0, uz = 0`` is the translation), so the held-out score can only tell
the simplest adequate one by the data, not by construction.

**Focus, guarded against collapse.** The IWE votes each warped event
bilinearly with the weight ``sqrt(|det dx'/dx|)`` (``log det = dt tr A -
3 log m3``, consistent with ``M`` to second order): under a warp that
shrinks an area by ``c`` the plain IWE's sum of squares grows as ``1/c``
(events collapse to a point or a line and the contrast soars; Shiba et al.,
"Event collapse in contrast maximization frameworks", Sensors 2022); with
``sqrt(c)`` weights it is unchanged, so a contraction earns nothing by
itself. The focus is the sum of squares of the IWE smoothed by a Gaussian
of ``sigma`` px, ``F = sum_p I (g2 * I)`` (``g2`` the Gaussian of
``sigma sqrt 2``), over the number of events; its gradient is exact for
the bilinear votes: ``dF = 2 sum_i [w_i grad(Q)(x'_i) . dx'_i + Q(x'_i)
dw_i]`` with ``Q = g2 * I`` interpolated bilinearly.

**Held-out score.** The focus of the training half cannot compare rungs
(a richer warp never focuses less). Each rung is fitted on the even-indexed
events of the window and scored on the odd ones by a likelihood in the
spirit of ST-PPP (Gu, Learned-Miller et al., ICCV 2021): the warped
training events, smoothed (``sigma`` px) and normalised, are a density
``p`` in the reference image (mixed with a uniform floor ``alpha``); a
held-out event's log-likelihood is ``log p(W(x)) + log |det dW/dx|``: the
change of variables makes it a density of the *observed* positions, so a
collapsing warp gains in ``p`` exactly what it loses in the Jacobian, and
a warp that fits noise of the training half gains nothing on the other.
Per-event values are additive, so the held-out events in ``blocks``
time-ordered blocks give a paired standard error of the difference between
two rungs, and the choice is the simplest rung (fewest parameters) whose
mean falls short of the best by at most ``k_se`` standard errors (the
one-standard-error rule of Breiman et al., 1984). A penalty instead (BIC,
GRIC) would need a likelihood of the events under each warp with a known
number of effective observations; the events of one edge are far from
independent, so such penalties are off by large factors, while held-out
events need no such count.

**Cost.** One evaluation: the warp and the votes, O(events x parameters);
one separable blur of the canvas (sensor plus margin, at 1/4, 1/2 and 1 of
the pixel pitch in the coarse-to-fine fit); the gradient pass. A rung's
fit is a quasi-Newton ascent (BFGS) on parameters scaled to about 1 px of
displacement each, 3 levels of 30 iterations at most (:func:`maximise`).

Duplicates, to merge with the shared CMax core (``tectum.plugins._cmax``)
later: the bilinear IWE, the separable Gaussian blur and the focus
gradient through the smoothed image are the same ideas as there; the warp
here is generic (generators), where the core's is rotation-specific.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["MODELS", "N_PARAMS", "NEEDS_CALIBRATION", "SIMPLEST_FIRST", "generators", "warp", "vote", "blur",
           "gaussian_taps", "focus_grad", "heldout_loglik", "Frame", "Fit", "LadderResult", "fit_rung",
           "run_ladder", "choose"]

#: Rungs in the order of their codes (the ``model`` field: 0 translation ... 4 6dof).
MODELS = ("translation", "rotation", "similarity", "homography", "6dof")
#: Number of parameters per rung.
N_PARAMS = {"translation": 2, "rotation": 3, "similarity": 4, "homography": 8, "6dof": 6}
#: Rungs that need the camera calibration (a physical rotation needs the focal length).
NEEDS_CALIBRATION = frozenset({"rotation", "6dof"})
#: The order of the choice: fewest parameters first.
SIMPLEST_FIRST = tuple(sorted(MODELS, key=lambda m: (N_PARAMS[m], MODELS.index(m))))


def _e(i: int, j: int) -> np.ndarray:
    m = np.zeros((3, 3))
    m[i, j] = 1.0
    return m


def _cross(k: int) -> np.ndarray:
    """``[e_k]x``: the generator of a rotation about axis k."""
    m = np.zeros((3, 3))
    a, b = (k + 1) % 3, (k + 2) % 3
    m[b, a], m[a, b] = 1.0, -1.0
    return m


def generators(model: str, fx: float, fy: float) -> np.ndarray:
    """The generators (P, 3, 3) of a rung in normalised coordinates, for
    parameters in the user's units (see the module docstring); ``fx, fy``
    px convert pixel velocities."""
    if model == "translation":
        g = [-_e(0, 2) / fx, -_e(1, 2) / fy]
    elif model == "rotation":
        g = [_cross(0), _cross(1), _cross(2)]
    elif model == "similarity":
        g = [-_e(0, 2) / fx, -_e(1, 2) / fy, -(_e(1, 0) - _e(0, 1)), -(_e(0, 0) + _e(1, 1))]
    elif model == "6dof":
        g = [_cross(0), _cross(1), _cross(2), _e(0, 2), _e(1, 2), _e(2, 2)]
    elif model == "homography":
        g = [-_e(i, j) for i in range(3) for j in range(3) if (i, j) != (2, 2)]
    else:
        raise ValueError(f"unknown motion model {model!r} (one of {', '.join(MODELS)})")
    return np.ascontiguousarray(np.stack(g))


# -- kernels -------------------------------------------------------------------------------------
@njit(cache=True, nogil=True)
def warp(x, y, dt, A, A2, G, C, trG, grad, xw, yw, logdet, J, dlogdet):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Events at normalised ``(x, y)`` and ``dt`` s from the reference,
    carried by ``M = I + dt A + dt^2 A^2 / 2`` to ``(xw, yw)``; ``logdet``
    the log of the area ratio ``dt tr A - 3 log|m3|``. With ``grad``, ``J``
    (N, 2, P) receives d(xw, yw)/d theta and ``dlogdet`` (N, P) its
    derivative, from the generators ``G`` (P, 3, 3), ``C_k = G_k A + A
    G_k`` and ``trG`` (P). Events whose ``m3 <= 0`` (behind the camera)
    get NaN positions."""
    n = x.shape[0]
    P = G.shape[0]
    trA = A[0, 0] + A[1, 1] + A[2, 2]
    for i in range(n):
        t = dt[i]
        h = 0.5 * t * t
        a, b = x[i], y[i]
        m0 = a + t * (A[0, 0] * a + A[0, 1] * b + A[0, 2]) + h * (A2[0, 0] * a + A2[0, 1] * b + A2[0, 2])
        m1 = b + t * (A[1, 0] * a + A[1, 1] * b + A[1, 2]) + h * (A2[1, 0] * a + A2[1, 1] * b + A2[1, 2])
        m2 = 1.0 + t * (A[2, 0] * a + A[2, 1] * b + A[2, 2]) + h * (A2[2, 0] * a + A2[2, 1] * b + A2[2, 2])
        if not m2 > 1e-9:
            xw[i] = np.nan
            yw[i] = np.nan
            logdet[i] = 0.0
            if grad:
                J[i] = 0.0
                dlogdet[i] = 0.0
            continue
        inv = 1.0 / m2
        u, v = m0 * inv, m1 * inv
        xw[i], yw[i] = u, v
        logdet[i] = t * trA - 3.0 * np.log(m2)
        if grad:
            for k in range(P):
                Gk, Ck = G[k], C[k]
                d0 = t * (Gk[0, 0] * a + Gk[0, 1] * b + Gk[0, 2]) + h * (Ck[0, 0] * a + Ck[0, 1] * b + Ck[0, 2])
                d1 = t * (Gk[1, 0] * a + Gk[1, 1] * b + Gk[1, 2]) + h * (Ck[1, 0] * a + Ck[1, 1] * b + Ck[1, 2])
                d2 = t * (Gk[2, 0] * a + Gk[2, 1] * b + Gk[2, 2]) + h * (Ck[2, 0] * a + Ck[2, 1] * b + Ck[2, 2])
                J[i, 0, k] = (d0 - u * d2) * inv
                J[i, 1, k] = (d1 - v * d2) * inv
                dlogdet[i, k] = t * trG[k] - 3.0 * d2 * inv


@njit(cache=True, nogil=True)
def vote(px, py, w, img):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Add each point at ``(px[i], py[i])`` (canvas pixels) bilinearly with
    weight ``w[i]`` into ``img`` (H, W); points whose 2x2 cell is not
    wholly inside (or NaN) are left out. Returns how many landed."""
    h, wd = img.shape
    landed = 0
    for i in range(px.shape[0]):
        fx = np.floor(px[i])
        fy = np.floor(py[i])
        if not (fx >= 0.0 and fy >= 0.0 and fx < wd - 1 and fy < h - 1):
            continue
        c, r = int(fx), int(fy)
        ax, ay = px[i] - fx, py[i] - fy
        wi = w[i]
        img[r, c] += wi * (1.0 - ax) * (1.0 - ay)
        img[r, c + 1] += wi * ax * (1.0 - ay)
        img[r + 1, c] += wi * (1.0 - ax) * ay
        img[r + 1, c + 1] += wi * ax * ay
        landed += 1
    return landed


@njit(cache=True, nogil=True)
def blur(img, taps, tmp, out, r0=0, r1=-1, c0=0, c1=-1):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Separable convolution of ``img`` (H, W) with the symmetric ``taps``
    (2R+1) in both directions, zero outside; ``tmp`` and ``out`` (H, W).
    With a box ``r0..r1, c0..c1`` (inclusive) holding every non-zero pixel
    of ``img``, only the box grown by R is computed (``out`` is zero
    elsewhere)."""
    h, w = img.shape
    R = taps.shape[0] // 2
    if r1 < 0:
        r0, r1, c0, c1 = 0, h - 1, 0, w - 1
    out[:] = 0.0
    if r1 < r0 or c1 < c0:
        return
    ra, rb = max(0, r0 - R), min(h - 1, r1 + R)
    ca, cb = max(0, c0 - R), min(w - 1, c1 + R)
    for r in range(r0, r1 + 1):  # rows: only rows of the box hold anything
        for c in range(ca, cb + 1):
            s = 0.0
            if c - R >= c0 and c + R <= c1:
                for k in range(2 * R + 1):
                    s += taps[k] * img[r, c - R + k]
            else:
                for k in range(max(-R, c0 - c), min(R, c1 - c) + 1):
                    s += taps[k + R] * img[r, c + k]
            tmp[r, c] = s
    for r in range(ra, rb + 1):
        ka, kb = max(-R, r0 - r), min(R, r1 - r)
        for k in range(ka, kb + 1):
            tk = taps[k + R]
            src = tmp[r + k]
            dst = out[r]
            for c in range(ca, cb + 1):
                dst[c] += tk * src[c]


def gaussian_taps(sigma: float) -> np.ndarray:
    """Normalised Gaussian taps of ``sigma`` px, radius ``ceil(3 sigma)``."""
    r = max(1, int(math.ceil(3.0 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    return k / k.sum()


@njit(cache=True, nogil=True)
def _box(px, py, shape):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Rows and columns (inclusive) the bilinear votes of (px, py) may touch, clipped to ``shape``."""
    h, w = shape
    r0, r1, c0, c1 = h, -1, w, -1
    for i in range(px.shape[0]):
        fx = np.floor(px[i])
        fy = np.floor(py[i])
        if fx >= 0.0 and fy >= 0.0 and fx < w - 1 and fy < h - 1:
            c, r = int(fx), int(fy)
            r0, r1, c0, c1 = min(r0, r), max(r1, r + 1), min(c0, c), max(c1, c + 1)
    return r0, r1, c0, c1


@njit(cache=True, nogil=True)
def _interp(img, px, py):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Bilinear value of ``img`` at (px, py) and its derivatives; zeros
    where the vote would have been left out."""
    h, w = img.shape
    fx = np.floor(px)
    fy = np.floor(py)
    if not (fx >= 0.0 and fy >= 0.0 and fx < w - 1 and fy < h - 1):
        return 0.0, 0.0, 0.0, False
    c, r = int(fx), int(fy)
    ax, ay = px - fx, py - fy
    q00, q01, q10, q11 = img[r, c], img[r, c + 1], img[r + 1, c], img[r + 1, c + 1]
    val = (q00 * (1 - ax) + q01 * ax) * (1 - ay) + (q10 * (1 - ax) + q11 * ax) * ay
    gx = (q01 - q00) * (1 - ay) + (q11 - q10) * ay
    gy = (q10 - q00) * (1 - ax) + (q11 - q01) * ax
    return val, gx, gy, True


@njit(cache=True, nogil=True)
def focus_grad(xw, yw, logdet, J, dlogdet, sx, sy, ox, oy, taps, grad, img, tmp, q, g):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """The focus ``F = sum_p I (g2 * I) / N`` of warped events ``(xw, yw)``
    (normalised) drawn on the canvas at ``(sx x + ox, sy y + oy)`` with
    weights ``exp(logdet / 2)``, ``taps`` the Gaussian ``g2``; with
    ``grad`` its gradient into ``g`` (P) from ``J``, ``dlogdet``. ``img``,
    ``tmp``, ``q`` are canvas-sized scratch arrays (``img`` is cleared)."""
    n = xw.shape[0]
    img[:] = 0.0
    px = sx * xw + ox
    py = sy * yw + oy
    w = np.exp(0.5 * logdet)
    vote(px, py, w, img)
    r0, r1, c0, c1 = _box(px, py, img.shape)
    blur(img, taps, tmp, q, r0, r1, c0, c1)
    F = 0.0
    for r in range(max(r0, 0), r1 + 1):
        for c in range(max(c0, 0), c1 + 1):
            F += img[r, c] * q[r, c]
    inv_n = 1.0 / max(n, 1)
    if grad:
        P = g.shape[0]
        g[:] = 0.0
        for i in range(n):
            val, gx, gy, ok = _interp(q, px[i], py[i])
            if not ok:
                continue
            for k in range(P):
                g[k] += w[i] * (gx * sx * J[i, 0, k] + gy * sy * J[i, 1, k] + 0.5 * val * dlogdet[i, k])
        for k in range(P):
            g[k] *= 2.0 * inv_n
    return F * inv_n


@njit(cache=True, nogil=True)
def heldout_loglik(xw, yw, logdet, dens, sx, sy, ox, oy, floor, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Per held-out event: ``log(p(x') + floor) + logdet`` with ``p`` the
    bilinear value of ``dens`` (a density per canvas pixel, summing to at
    most 1 - floor * area) at the canvas point of ``(xw, yw)``; ``floor``
    the uniform density per canvas pixel. Values are per unit of the
    sensor's pixel area (``log(sx * sy)`` added)."""
    shift = np.log(sx * sy)
    for i in range(xw.shape[0]):
        val, _gx, _gy, ok = _interp(dens, sx * xw[i] + ox, sy * yw[i] + oy)
        out[i] = np.log(max(val, 0.0) + floor) + logdet[i] + shift


# -- fitting -------------------------------------------------------------------------------------
@dataclass
class Frame:
    """A window's events in normalised coordinates: ``x, y`` (undistorted,
    ``(u - cx) / fx``), ``dt`` s from the reference time; ``fx, fy, cx,
    cy`` px the (nominal, without calibration) intrinsics; ``width,
    height`` the sensor (px); ``margin`` px of canvas around it."""

    x: np.ndarray
    y: np.ndarray
    dt: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    margin: int

    def take(self, idx: np.ndarray | slice) -> Frame:
        return Frame(np.ascontiguousarray(self.x[idx]), np.ascontiguousarray(self.y[idx]),
                     np.ascontiguousarray(self.dt[idx]), self.fx, self.fy, self.cx, self.cy, self.width,
                     self.height, self.margin)

    def canvas(self, scale: float) -> tuple[tuple[int, int], float, float, float, float]:
        """(shape, sx, sy, ox, oy) of the canvas at ``scale`` sensor pixels per canvas pixel."""
        w = int(math.ceil((self.width + 2 * self.margin) / scale))
        h = int(math.ceil((self.height + 2 * self.margin) / scale))
        return (h, w), self.fx / scale, self.fy / scale, (self.cx + self.margin) / scale, \
            (self.cy + self.margin) / scale


class _Objective:
    """The focus of one rung on one set of events at one canvas scale, in
    scaled parameters ``z = theta / scale``."""

    def __init__(self, fr: Frame, G: np.ndarray, pscale: np.ndarray, scale: float, sigma: float) -> None:
        self.fr, self.G, self.pscale = fr, G, pscale
        n, P = fr.x.shape[0], G.shape[0]
        self.shape, self.sx, self.sy, self.ox, self.oy = fr.canvas(scale)
        self.taps = gaussian_taps(sigma * math.sqrt(2.0))
        self.img, self.tmp, self.q = (np.zeros(self.shape) for _ in range(3))
        self.xw, self.yw, self.ld = np.empty(n), np.empty(n), np.empty(n)
        self.J, self.dld = np.empty((n, 2, P)), np.empty((n, P))
        self.trG = np.ascontiguousarray(np.trace(G, axis1=1, axis2=2))
        self.g = np.zeros(P)

    def theta(self, z: np.ndarray) -> np.ndarray:
        return np.asarray(z, np.float64) * self.pscale

    def warp(self, theta: np.ndarray, grad: bool) -> None:
        A = np.tensordot(theta, self.G, axes=1)
        C = np.ascontiguousarray(self.G @ A + A @ self.G)
        warp(self.fr.x, self.fr.y, self.fr.dt, A, A @ A, self.G, C, self.trG, grad, self.xw, self.yw, self.ld,
             self.J, self.dld)

    def focus(self, theta: np.ndarray, grad: bool = False) -> float:
        self.warp(theta, grad)
        return float(focus_grad(self.xw, self.yw, self.ld, self.J, self.dld, self.sx, self.sy, self.ox, self.oy,
                                self.taps, grad, self.img, self.tmp, self.q, self.g))

    def __call__(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        """The focus and its gradient in scaled parameters."""
        f = self.focus(self.theta(z), True)
        return f, self.g * self.pscale


def maximise(obj: _Objective, z0: np.ndarray, bound: float, max_iter: int,
             xtol: float = 1e-3) -> tuple[np.ndarray, float]:
    """Quasi-Newton ascent (BFGS on the inverse Hessian, Armijo
    backtracking) of ``obj`` from ``z0`` inside the box ``|z_k| <= bound``
    (steps are clipped to it); stops after ``max_iter`` steps or a step
    shorter than ``xtol`` (scaled units: px). Returns (z, focus). Written
    out rather than scipy's L-BFGS-B, whose Fortran core calls a threaded
    BLAS on 8x8 problems (ten times slower on a busy machine)."""
    z = np.clip(np.asarray(z0, np.float64), -bound, bound)
    f, g = obj(z)
    n = z.shape[0]
    H = np.eye(n) / max(float(np.abs(g).max()), 1e-12)  # first step: 1 unit along the steepest component
    for _ in range(max_iter):
        d = H @ g
        if not d @ g > 0:
            H = np.eye(n) / max(float(np.abs(g).max()), 1e-12)
            d = H @ g
        d *= min(1.0, 4.0 / max(float(np.abs(d).max()), 1e-12))  # at most 4 px per step
        step, ok = 1.0, False
        for _ in range(12):
            zn = np.clip(z + step * d, -bound, bound)
            fn, gn = obj(zn)
            if fn >= f + 1e-4 * float(g @ (zn - z)):
                ok = True
                break
            step *= 0.5
        if not ok:
            break
        s, y = zn - z, g - gn
        z, f, g = zn, fn, gn
        sy = float(s @ y)
        if sy > 1e-12:
            rho = 1.0 / sy
            V = np.eye(n) - rho * np.outer(s, y)
            H = V @ H @ V.T + rho * np.outer(s, s)
        if float(np.abs(s).max()) < xtol:
            break
    return z, f


def param_scales(fr: Frame, G: np.ndarray) -> np.ndarray:
    """Per parameter, the value that moves the events by 1 px rms (to first
    order), so that scaled parameters are equally conditioned."""
    x, y, dt = fr.x, fr.y, fr.dt
    out = np.empty(G.shape[0])
    for k in range(G.shape[0]):
        d = G[k] @ np.stack([x, y, np.ones_like(x)])
        du = fr.fx * dt * (d[0] - x * d[2])
        dv = fr.fy * dt * (d[1] - y * d[2])
        rms = math.sqrt(float(np.mean(du * du + dv * dv))) if len(x) else 0.0
        out[k] = 1.0 / rms if rms > 0 else 1.0
    return out


@dataclass
class Fit:
    """One rung's fit: parameters (user units), the training focus, the
    per-event held-out log-likelihood."""

    model: str
    theta: np.ndarray
    focus: float
    loglik: np.ndarray


#: Coarse-to-fine levels: (sensor pixels per canvas pixel, smoothing sigma in canvas px).
LEVELS = ((4.0, 1.0), (2.0, 1.0), (1.0, 1.0))


def fit_rung(model: str, train: Frame, starts: Sequence[np.ndarray], max_disp_px: float,
             levels: Sequence[tuple[float, float]] = LEVELS, max_iter: int = 30) -> tuple[np.ndarray, float]:
    """Fit one rung on ``train``: from the two most focused of ``starts``
    (parameters in user units) at the first level, then from the better
    result level by level (BFGS ascent, :func:`maximise`), the
    parameters bounded to ``max_disp_px`` px rms of displacement each.
    Returns (theta, focus at the finest level)."""
    G = generators(model, train.fx, train.fy)
    ps = param_scales(train, G)
    z = None
    for li, (scale, sigma) in enumerate(levels):
        obj = _Objective(train, G, ps, scale, sigma)
        if z is None:  # the first level: from the two most focused starts
            cands = [np.clip(np.asarray(s, np.float64) / ps, -max_disp_px, max_disp_px) for s in starts]
            cands.sort(key=lambda c: -obj.focus(obj.theta(c)))
            z, f = max((maximise(obj, c, max_disp_px, max_iter, xtol=0.02 * scale) for c in cands[:2]),
                       key=lambda r: r[1])
        else:
            z, f = maximise(obj, z, max_disp_px, max_iter, xtol=0.02 * scale)
        if li == len(levels) - 1:
            return obj.theta(z), f
    raise ValueError("no levels")


def heldout(model: str, theta: np.ndarray, train: Frame, test: Frame, sigma: float, alpha: float) -> np.ndarray:
    """Per held-out event, its log-likelihood (nats, per sensor px²) under
    the density of the training events warped by ``theta`` (see the module
    docstring)."""
    G = generators(model, train.fx, train.fy)
    shape, sx, sy, ox, oy = train.canvas(1.0)
    obj = _Objective(train, G, np.ones(G.shape[0]), 1.0, sigma)
    obj.warp(theta, False)
    img = np.zeros(shape)
    vote(sx * obj.xw + ox, sy * obj.yw + oy, np.ones(len(obj.xw)), img)
    dens = np.zeros(shape)
    blur(img, gaussian_taps(sigma), np.zeros(shape), dens)
    area = float(shape[0] * shape[1])
    dens *= (1.0 - alpha) / max(len(train.x), 1)
    ot = _Objective(test, G, np.ones(G.shape[0]), 1.0, sigma)
    ot.warp(theta, False)
    out = np.empty(len(test.x))
    heldout_loglik(ot.xw, ot.yw, ot.ld, dens, sx, sy, ox, oy, alpha / area, out)
    return out


@dataclass
class LadderResult:
    """A window's outcome: the chosen rung, every rung's fit (None where
    skipped), the mean held-out log-likelihood per rung (NaN where skipped)
    and the paired standard error of each rung's shortfall from the best."""

    model: str
    fits: dict[str, Fit | None]
    scores: dict[str, float]
    shortfall_se: dict[str, float]
    still: float


def choose(loglik: dict[str, np.ndarray], still: float, blocks: int, k_se: float, tol: float,
           tol_rel: float) -> tuple[str, dict[str, float]]:
    """The simplest rung whose mean held-out log-likelihood falls short of
    the best by at most ``max(k_se * SE, tol * (best - still), tol_rel *
    (best - simplest))``: ``SE`` the paired standard error of the shortfall
    (per-event values cut into ``blocks`` consecutive blocks); ``still``
    the score of no motion, so ``tol`` is a share of what the best warp
    gains over none; ``simplest`` the score of the simplest rung scored, so
    ``tol_rel`` is a share of what the richer rungs add to it. Also each
    rung's standard error."""
    means = {m: float(v.mean()) for m, v in loglik.items()}
    best = max(means, key=lambda m: means[m])
    base = next(m for m in SIMPLEST_FIRST if m in means)
    margin = max(tol * (means[best] - still), tol_rel * (means[best] - means[base]), 0.0)
    ses: dict[str, float] = {}
    pick = None
    for m in SIMPLEST_FIRST:
        if m not in loglik:
            continue
        d = np.array([b.mean() for b in np.array_split(loglik[best] - loglik[m], blocks)])
        ses[m] = float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else 0.0
        if pick is None and d.mean() <= max(k_se * ses[m], margin):
            pick = m
    return pick or best, ses


def _starts(model: str, done: dict[str, np.ndarray], prev: dict[str, np.ndarray], fx: float,
            fy: float) -> list[np.ndarray]:
    """Starting points of a rung: zero, its previous window's result, and
    the equivalents of the simpler rungs already fitted."""
    P = N_PARAMS[model]
    out = [np.zeros(P)]
    if model in prev:
        out.append(prev[model])
    tr, rot, sim, six = (done.get(m) for m in ("translation", "rotation", "similarity", "6dof"))
    if model == "rotation" and tr is not None:  # image velocity (vx, vy) ~ (-wy fx, wx fy)
        out.append(np.array([tr[1] / fy, -tr[0] / fx, 0.0]))
    if model == "similarity" and tr is not None:
        out.append(np.array([tr[0], tr[1], 0.0, 0.0]))
    if model == "6dof":
        if rot is not None:
            out.append(np.r_[rot, 0.0, 0.0, 0.0])
        if tr is not None:  # u = v / Z, image velocity -fx ux
            out.append(np.array([0.0, 0.0, 0.0, -tr[0] / fx, -tr[1] / fy, 0.0]))
        if sim is not None:
            out.append(np.array([0.0, 0.0, -sim[2], -sim[0] / fx, -sim[1] / fy, sim[3]]))
    if model == "homography":
        # D = -A: rows d00 d01 d02 d10 d11 d12 d20 d21 (D22 = 0: subtract D22 times the identity)
        def from_a(A: np.ndarray) -> np.ndarray:
            D = -(A - A[2, 2] * np.eye(3))
            return np.delete(D.ravel(), 8)
        for m, th in (("similarity", sim), ("6dof", six), ("rotation", rot)):
            if th is not None:
                out.append(from_a(np.tensordot(th, generators(m, fx, fy), axes=1)))
    return out


def run_ladder(fr: Frame, models: Sequence[str], prev: dict[str, np.ndarray], *, max_disp_px: float = 30.0,
               sigma: float = 1.0, alpha: float = 0.05, blocks: int = 10, k_se: float = 1.0, tol: float = 0.01,
               tol_rel: float = 0.1,
               max_fit_events: int = 8000) -> LadderResult:
    """Fit every rung of ``models`` on the even-indexed events of ``fr``
    (evenly thinned to ``max_fit_events``), score each on the odd-indexed
    ones and choose (see the module docstring and :func:`choose`). ``prev``
    holds the previous window's parameters per rung (starting points)."""
    train, test = fr.take(slice(0, None, 2)), fr.take(slice(1, None, 2))
    fit_on = train.take(slice(0, None, -(-len(train.x) // max_fit_events))) if len(train.x) > max_fit_events else train
    done: dict[str, np.ndarray] = {}
    fits: dict[str, Fit | None] = {m: None for m in MODELS}
    ll: dict[str, np.ndarray] = {}
    for m in SIMPLEST_FIRST:
        if m not in models:
            continue
        theta, f = fit_rung(m, fit_on, _starts(m, done, prev, fr.fx, fr.fy), max_disp_px,
                            LEVELS if m == "translation" else LEVELS[1:])
        done[m] = theta
        ll[m] = heldout(m, theta, train, test, sigma, alpha)
        fits[m] = Fit(m, theta, f, ll[m])
    still = float(heldout("translation", np.zeros(2), train, test, sigma, alpha).mean())
    pick, ses = choose(ll, still, blocks, k_se, tol, tol_rel)
    scores = {m: (float(ll[m].mean()) if m in ll else math.nan) for m in MODELS}
    return LadderResult(pick, fits, scores, ses, still)
