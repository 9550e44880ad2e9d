"""EKLT's generative alignment (Gehrig, Rebecq, Gallego, Scaramuzza, "EKLT:
Asynchronous photometric feature tracking using events and frames", IJCV
128, 2020; ECCV 2018): numba kernels.

A patch of ``P x P`` px around a feature collects the polarities of its
latest events (the *observed* brightness increment ``ΔL``, up to the
contrast ``C``). The frame predicts it: an edge moving with image velocity
``v`` for a time ``Δτ`` changes the log intensity by ``ΔL̂(u) = -∇L(W(u; p))
· v Δτ``. Both patches are normalised to unit L2 norm, which cancels the
unknown ``C`` and ``|v| Δτ`` and leaves the flow *direction* ``φ`` (rad,
image axes: 0 = +x, π/2 = +y) and the warp ``W`` (translation, optionally a
rotation ``θ``) as unknowns. Cost: ``|ΔL/|ΔL| - ΔL̂/|ΔL̂||²`` in [0, 4]
(``2 - 2ρ`` with ρ the patches' correlation), minimised by Levenberg-
Marquardt (Gauss-Newton damped when a step does not lower the cost) with
analytic derivatives (the template stores the smoothed log image's
gradient and Hessian).

Warp: event-patch pixel ``u`` (absolute px) maps into the detection frame
at ``W(u) = x_ref + R(θ) (u - x)`` where ``x`` (px) is the feature's current
position and ``x_ref`` its position in the frame; a frame gradient ``g`` at
``W(u)`` seen in the patch's axes is ``R(θ)ᵀ g``, so the prediction is
``-g · R(θ) v``. The template (the frame's log-intensity gradient and Hessian
around ``x_ref``, σ 1 px) is stored per feature: tracking is against the
detection frame, so no error accumulates from one frame to the next.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["observed_patch", "eklt_cost", "eklt_align", "event_target"]

#: The observed patch is blurred with this 5-tap Gaussian (σ 1 px) in x and y.
_BLUR = (0.05448868, 0.24420134, 0.40261995, 0.24420134, 0.05448868)


@njit(cache=True)
def observed_patch(ex: np.ndarray, ey: np.ndarray, ep: np.ndarray, n: int, cx: int, cy: int, half: int,
                   out: np.ndarray) -> int:
    """The polarity sum of the first ``n`` events (``ex``, ``ey`` px, ``ep``
    ±1) in the patch of side ``2 half + 1`` centred on pixel ``(cx, cy)``,
    blurred (σ 1 px) and normalised to unit norm, into ``out`` (P*P, row
    major); returns how many of the events fell in the patch (0: ``out``
    is all zero)."""
    P = 2 * half + 1
    raw = np.zeros((P + 4, P + 4))
    inside = 0
    for e in range(n):
        i = int(ex[e]) - cx + half
        j = int(ey[e]) - cy + half
        if 0 <= i < P and 0 <= j < P:
            raw[j + 2, i + 2] += ep[e]
            inside += 1
    tmp = np.zeros((P + 4, P))
    for j in range(P + 4):
        for i in range(P):
            s = 0.0
            for k in range(5):
                s += _BLUR[k] * raw[j, i + k]
            tmp[j, i] = s
    ss = 0.0
    for j in range(P):
        for i in range(P):
            s = 0.0
            for k in range(5):
                s += _BLUR[k] * tmp[j + k, i]
            out[j * P + i] = s
            ss += s * s
    if ss <= 0.0:
        out[:] = 0.0
        return 0
    nrm = 1.0 / math.sqrt(ss)
    for k in range(P * P):
        out[k] *= nrm
    return inside


@njit(cache=True)
def eklt_cost(obs: np.ndarray, tmpl: np.ndarray, ox: float, oy: float, xref: float, yref: float, cx: int,
              cy: int, half: int, q: np.ndarray, rotation: bool, res: np.ndarray, J: np.ndarray,
              jac: bool) -> float:
    """The cost ``|obs - pred(q)|²`` for parameters ``q`` = (x, y, φ) or
    (x, y, θ, φ) with ``rotation``; 4.0 (the worst) for a flat prediction.
    Leaves the residual ``obs - pred`` in ``res`` (P*P) and, with ``jac``,
    its Jacobian in ``J`` (P*P, len(q)), analytic: the template ``tmpl``
    holds gx, gy, gxx, gxy, gyy (5, S, S), pixel (0, 0) at frame pixel
    ``(ox, oy)``."""
    P = 2 * half + 1
    theta = q[2] if rotation else 0.0
    phi = q[3] if rotation else q[2]
    x = q[0]
    y = q[1]
    c = math.cos(theta)
    s = math.sin(theta)
    vx = math.cos(phi + theta)
    vy = math.sin(phi + theta)
    bx = xref - ox
    by = yref - oy
    S = tmpl.shape[1]
    npar = q.shape[0]
    ss = 0.0
    for j in range(P):
        dy = cy - half + j - y
        for i in range(P):
            dx = cx - half + i - x
            k = j * P + i
            wx = bx + c * dx - s * dy
            wy = by + s * dx + c * dy
            if not (0.0 <= wx <= S - 1.0 and 0.0 <= wy <= S - 1.0):
                res[k] = 0.0
                if jac:
                    J[k, :] = 0.0
                continue
            a = min(int(wx), S - 2)
            b = min(int(wy), S - 2)
            fx = wx - a
            fy = wy - b
            w00 = (1 - fx) * (1 - fy)
            w10 = fx * (1 - fy)
            w01 = (1 - fx) * fy
            w11 = fx * fy
            g0 = w00 * tmpl[0, b, a] + w10 * tmpl[0, b, a + 1] + w01 * tmpl[0, b + 1, a] + w11 * tmpl[0, b + 1, a + 1]
            g1 = w00 * tmpl[1, b, a] + w10 * tmpl[1, b, a + 1] + w01 * tmpl[1, b + 1, a] + w11 * tmpl[1, b + 1, a + 1]
            v = -(g0 * vx + g1 * vy)
            res[k] = v
            ss += v * v
            if jac:
                # d pred / d W = -(H v'), H the Hessian at W
                gxx = (w00 * tmpl[2, b, a] + w10 * tmpl[2, b, a + 1] + w01 * tmpl[2, b + 1, a]
                       + w11 * tmpl[2, b + 1, a + 1])
                gxy = (w00 * tmpl[3, b, a] + w10 * tmpl[3, b, a + 1] + w01 * tmpl[3, b + 1, a]
                       + w11 * tmpl[3, b + 1, a + 1])
                gyy = (w00 * tmpl[4, b, a] + w10 * tmpl[4, b, a + 1] + w01 * tmpl[4, b + 1, a]
                       + w11 * tmpl[4, b + 1, a + 1])
                hx = -(gxx * vx + gxy * vy)
                hy = -(gxy * vx + gyy * vy)
                J[k, 0] = hx * (-c) + hy * (-s)       # dW/dx = -R e_x
                J[k, 1] = hx * s + hy * (-c)          # dW/dy = -R e_y
                dphi = g0 * vy - g1 * vx          # v' turns with φ (and θ)
                if rotation:
                    J[k, 2] = hx * (-s * dx - c * dy) + hy * (c * dx - s * dy) + dphi
                J[k, npar - 1] = dphi
    if ss <= 0.0:
        return 4.0
    nrm = 1.0 / math.sqrt(ss)
    cost = 0.0
    m = P * P
    if jac:
        # normalised n = p/|p|: dn = (dp - n (n . dp)) / |p|; the residual obs - n has Jacobian -dn
        for a in range(npar):
            dot = 0.0
            for k in range(m):
                dot += res[k] * J[k, a]
            dot *= nrm * nrm
            for k in range(m):
                J[k, a] = -(J[k, a] - res[k] * dot) * nrm
    for k in range(m):
        r = obs[k] - res[k] * nrm
        res[k] = r
        cost += r * r
    return cost


@njit(cache=True)
def eklt_align(obs: np.ndarray, tmpl: np.ndarray, ox: float, oy: float, xref: float, yref: float, cx: int,
               cy: int, half: int, q: np.ndarray, rotation: bool, search_phi: bool, max_iter: int) -> float:
    """Minimise :func:`eklt_cost` over ``q`` (updated in place) from its
    value, by Gauss-Newton damped as Levenberg-Marquardt when a step does
    not lower the cost; with ``search_phi`` the flow direction starts from
    the best of 16 directions. Stops when a step moves less than 0.01 px
    (and 0.001 rad). Returns the final cost."""
    m = obs.shape[0]
    npar = q.shape[0]
    ip = npar - 1  # φ's index
    r0 = np.empty(m)
    r1 = np.empty(m)
    J = np.empty((m, npar))
    J1 = np.empty((m, npar))
    if search_phi:
        best = 1e9
        bphi = 0.0
        for a in range(16):
            q[ip] = a * (2.0 * math.pi / 16.0)
            cst = eklt_cost(obs, tmpl, ox, oy, xref, yref, cx, cy, half, q, rotation, r0, J, False)
            if cst < best:
                best = cst
                bphi = q[ip]
        q[ip] = bphi
    cost = eklt_cost(obs, tmpl, ox, oy, xref, yref, cx, cy, half, q, rotation, r0, J, True)
    qt = q.copy()
    lam = 0.0
    for _ in range(max_iter):
        A = J.T @ J
        b = J.T @ r0
        done = True
        for _t in range(5):
            H = A.copy()
            for a in range(npar):
                H[a, a] += lam * A[a, a] + 1e-9
            d = np.linalg.solve(H, -b)
            qt[:] = q + d
            c1 = eklt_cost(obs, tmpl, ox, oy, xref, yref, cx, cy, half, qt, rotation, r1, J1, True)
            if c1 < cost:
                q[:] = qt
                cost = c1
                r0[:] = r1
                J[:, :] = J1
                lam *= 0.1
                small = d[0] * d[0] + d[1] * d[1] < 1e-4
                for a in range(2, npar):
                    small = small and abs(d[a]) < 1e-3
                done = small
                break
            lam = max(lam * 10.0, 1e-3)
        if done:
            break
    return cost


@njit(cache=True)
def event_target(gx: np.ndarray, gy: np.ndarray, phi: float, contrast: float) -> float:
    """Events a patch is expected to fire while it moves 1 px in direction
    ``phi`` (rad): ``Σ |∇L · v̂| / C`` over the template (EKLT's choice of
    the window size); with ``phi`` NaN (unknown), the mean over directions
    (``2/π Σ |∇L| / C``)."""
    s = 0.0
    h, w = gx.shape
    if math.isnan(phi):
        for j in range(h):
            for i in range(w):
                s += math.sqrt(gx[j, i] ** 2 + gy[j, i] ** 2) * (2.0 / math.pi)
    else:
        vx = math.cos(phi)
        vy = math.sin(phi)
        for j in range(h):
            for i in range(w):
                s += abs(gx[j, i] * vx + gy[j, i] * vy)
    return s / contrast
