"""Kernels of ``map.emvs``: the disparity space image (DSI) of event-based
multi-view stereo (Rebecq, Gallego, Mueggler, Scaramuzza, "EMVS: Event-based
Multi-View Stereo", BMVC 2016 / IJCV 2018, Sec. 3-4).

The DSI is a stack of ``P`` fronto-parallel planes at depths ``Z_k`` (m) in
the reference view (pinhole ``fx, fy, cx, cy`` px, no distortion), one
float32 image (H, W) per plane; a cell counts the event rays that pass
through it.

Plane sweep (IJCV 2018 Sec. 3): the paper maps an event into the reference
view through the homography of one reference plane ``Z0`` and transfers it
to every other plane with a per-plane affine map. Here the reference plane
is the plane at infinity (``Z0 -> inf``: the pure-rotation homography
``K R_re K^-1``), which makes that transfer exact and linear in the inverse
depth ``rho = 1/Z``: with ``m = (mx, my, 1)`` the event's ray in the
reference frame (``R_re @ K^-1 x``, scaled to z = 1) and ``C`` the event
camera's centre in the reference frame (m), the ray meets the plane ``Z``
at the reference pixel

    u(rho) = cx + fx mx + rho * fx (Cx - mx Cz)
    v(rho) = cy + fy my + rho * fy (Cy - my Cz)

(the point ``C + (Z - Cz) m`` projected), so each vote costs two
multiply-adds. The point lies in front of the event camera when
``Z > Cz`` (``m`` points forward): planes nearer than ``Cz`` get no vote.
Choosing infinity rather than a finite ``Z0`` avoids the case ``Cz = Z0``,
where the finite-plane homography is singular.

Votes are bilinear (the four pixels around the sub-pixel point share 1),
loops run plane by plane so that the votes of a block of events land in
one plane image at a time (a 240x180 plane is 173 kB: it stays in cache);
per plane, a branch-free SIMD loop computes a chunk's cells and weights,
then a scalar loop adds them (about 2 ns a vote, 3x the one-loop form,
whose branches and index arithmetic cost more than the memory traffic).
Traces are float32: 240 px at float32 resolution is 1.5e-5 px.
Each DSI cell receives its votes in event order whatever the loop order or
the packet split, so the float32 sums are bit-identical for any split.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["ray_traces", "vote", "argmax_depth", "focus_argmax", "masked_median"]


@njit(cache=True, nogil=True)
def ray_traces(x, y, seg, rays, R, C, fx, fy, cx, cy, trace):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Per event ``i`` (pixel ``x[i], y[i]``, pose segment ``seg[i]``),
    its trace in the reference view: ``trace[:, i] = (u_inf, v_inf, du, dv)``
    px (float32, (4, N)) with ``u(rho) = u_inf + rho du`` (see the module
    doc), from the undistorted normalised ray ``rays[y, x] = (X/Z, Y/Z)``,
    the segment's reference-from-event rotation ``R[s]`` (3x3) and event
    camera centre ``C[s]`` (m, reference frame). Events whose ray has no
    inverse (NaN) or points away from the reference view get NaN. Returns
    how many are valid."""
    n_ok = 0
    for i in range(x.shape[0]):
        xn = rays[y[i], x[i], 0]
        yn = rays[y[i], x[i], 1]
        s = seg[i]
        Ri = R[s]
        dx = Ri[0, 0] * xn + Ri[0, 1] * yn + Ri[0, 2]
        dy = Ri[1, 0] * xn + Ri[1, 1] * yn + Ri[1, 2]
        dz = Ri[2, 0] * xn + Ri[2, 1] * yn + Ri[2, 2]
        if not dz > 1e-9:  # NaN ray, or a ray leaving the reference view's half space
            for c in range(4):
                trace[c, i] = np.nan
            continue
        mx = dx / dz
        my = dy / dz
        trace[0, i] = cx + fx * mx
        trace[1, i] = cy + fy * my
        trace[2, i] = fx * (C[s, 0] - mx * C[s, 2])
        trace[3, i] = fy * (C[s, 1] - my * C[s, 2])
        n_ok += 1
    return n_ok


#: Events per block of :func:`vote`: the block's traces (16 bytes an event)
#: stay in cache while the planes go by.
BLOCK = 1 << 16
#: Events per chunk of a plane pass: the chunk's votes (20 bytes an event)
#: are computed into a buffer that stays in L1, then scattered.
CHUNK = 1024


@njit(cache=True, nogil=True, boundscheck=False)
def vote(trace, first, rho, dsi):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Bilinear votes of each event's trace (float32 (4, N), from
    :func:`ray_traces`) into the DSI (P, H, W) float32: on plane ``k``
    (inverse depth ``rho[k]``, 1/m) at ``u_inf + rho du``, ``v_inf + rho
    dv`` (px, pixel centres at integers), for the planes ``k >= first[i]``
    (those in front of the event's camera). Votes whose 2x2 cell is not
    wholly inside the image are dropped. Blocks of :data:`BLOCK` events,
    plane by plane within a block; returns the number of votes cast.

    Each plane pass goes in chunks of :data:`CHUNK` events, in two loops:
    the first, branch-free (SIMD), computes every event's cell (flat index
    of its top-left pixel) and four weights; the second adds them into the
    plane. A dropped vote gets weight 0 at cell 0: adding +0.0 leaves a
    non-negative float32 unchanged, so this is exactly the same as not
    voting, and each cell still receives its votes in event order."""
    P, H, W = dsi.shape
    n = trace.shape[1]
    wmax = np.float32(W - 1)
    hmax = np.float32(H - 1)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    right = np.uint32(1)  # flat offsets (unsigned: no negative-index wraparound) of the other 3 pixels
    down = np.uint32(W)
    diag = np.uint32(W + 1)
    cell = np.empty(CHUNK, np.uint32)
    w00 = np.empty(CHUNK, np.float32)
    w01 = np.empty(CHUNK, np.float32)
    w10 = np.empty(CHUNK, np.float32)
    w11 = np.empty(CHUNK, np.float32)
    cast = 0
    for a in range(0, n, BLOCK):
        b = min(n, a + BLOCK)
        for k in range(P):
            r = np.float32(rho[k])
            plane = dsi[k].reshape(H * W)
            for c in range(a, b, CHUNK):
                m = min(CHUNK, b - c)
                u_inf, v_inf = trace[0, c:c + m], trace[1, c:c + m]
                du, dv = trace[2, c:c + m], trace[3, c:c + m]
                fc = first[c:c + m]
                for j in range(m):
                    u = u_inf[j] + r * du[j]
                    v = v_inf[j] + r * dv[j]
                    # also rejects NaN
                    ok = (u >= zero) & (v >= zero) & (u < wmax) & (v < hmax) & (k >= fc[j])
                    u = u if ok else zero
                    v = v if ok else zero
                    iu = np.int32(u)
                    iv = np.int32(v)
                    fu = u - np.float32(iu)
                    fv = v - np.float32(iv)
                    gu = (one if ok else zero) - fu  # 1 - fu, or 0 for a dropped vote (fu = fv = 0)
                    w00[j] = gu * (one - fv)
                    w01[j] = fu * (one - fv)
                    w10[j] = gu * fv
                    w11[j] = fu * fv
                    cell[j] = np.uint32(iv * W + iu)
                    cast += ok
                for j in range(m):
                    p = cell[j]
                    plane[p] += w00[j]
                    plane[p + right] += w01[j]
                    plane[p + down] += w10[j]
                    plane[p + diag] += w11[j]
    return cast


@njit(cache=True, nogil=True)
def argmax_depth(dsi, refine, index, score):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Per pixel, the plane with the most votes: ``score`` (H, W) its votes
    (the confidence) and ``index`` (H, W) float64 its plane index, refined
    (``refine``) by the vertex of the parabola through the scores of the
    planes either side (|offset| <= 1/2; ties keep the nearer plane)."""
    P, H, W = dsi.shape
    best = np.zeros((H, W), np.int64)
    for j in range(H):
        for i in range(W):
            score[j, i] = dsi[0, j, i]
    for k in range(1, P):
        plane = dsi[k]
        for j in range(H):
            for i in range(W):
                if plane[j, i] > score[j, i]:
                    score[j, i] = plane[j, i]
                    best[j, i] = k
    for j in range(H):
        for i in range(W):
            k = best[j, i]
            off = 0.0
            if refine and 0 < k < P - 1:
                off = _vertex(dsi[k - 1, j, i], dsi[k, j, i], dsi[k + 1, j, i])
            index[j, i] = k + off


@njit(cache=True, nogil=True)
def _vertex(a, b, c):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Where (planes, within +-0.5) the parabola through three neighbouring
    scores ``a, b, c`` peaks, ``b`` the middle's: 0 unless it curves down."""
    den = a - 2.0 * b + c
    if den >= 0.0:
        return 0.0
    return min(0.5, max(-0.5, 0.5 * (a - c) / den))


@njit(cache=True, nogil=True)
def masked_median(depth, mask, radius, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Median of ``depth`` over the ``mask``ed pixels of the (2r+1)^2 window
    around each masked pixel (``out`` NaN elsewhere): the paper's median
    filter, kept off the pixels the threshold rejected."""
    H, W = depth.shape
    buf = np.empty((2 * radius + 1) ** 2)
    for j in range(H):
        for i in range(W):
            if not mask[j, i]:
                out[j, i] = np.nan
                continue
            n = 0
            for jj in range(max(0, j - radius), min(H, j + radius + 1)):
                for ii in range(max(0, i - radius), min(W, i + radius + 1)):
                    if mask[jj, ii]:
                        buf[n] = depth[jj, ii]
                        n += 1
            s = np.sort(buf[:n])
            out[j, i] = s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


@njit(cache=True, nogil=True)
def focus_argmax(dsi, radius, refine, index):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Per pixel, the plane where the DSI is sharpest around it: the local
    variance of each plane's votes over the (2 ``radius`` + 1)^2 window
    about the pixel (clipped at the borders), and ``index`` (H, W) float64
    the plane where it is largest, refined (``refine``) by the vertex of
    the parabola through the variances of the planes either side
    (|offset| <= 1/2).

    Rays of one scene point meet in one cell of its true plane, so that
    plane's slice is the sharpest image of the events about it (depth from
    focus: the local variance is one of the focus measures of Gallego,
    Gehrig, Scaramuzza, "Focus Is All You Need", CVPR 2019). Where the
    texture is smooth next to the baseline (blobs wider than the disparity
    across the DSI), the single cell with most votes is as often where the
    smeared rays of the neighbouring points pile up on a wrong plane."""
    P, H, W = dsi.shape
    r = radius
    row = np.empty((H, W + 1))
    row2 = np.empty((H, W + 1))
    box = np.empty((H, W))
    box2 = np.empty((H, W))
    prev = np.zeros((H, W))  # the variance of the plane before
    best = np.full((H, W), -1.0)  # the best variance so far
    before = np.zeros((H, W))  # the variance of the plane before the best
    after = np.zeros((H, W))  # the variance of the plane after the best
    kbest = np.zeros((H, W), np.int64)
    col = np.empty(H + 1)
    col2 = np.empty(H + 1)
    for k in range(P):
        plane = dsi[k]
        for j in range(H):  # horizontal running sums
            row[j, 0] = 0.0
            row2[j, 0] = 0.0
            for i in range(W):
                v = np.float64(plane[j, i])
                row[j, i + 1] = row[j, i] + v
                row2[j, i + 1] = row2[j, i] + v * v
            for i in range(W):
                a = max(0, i - r)
                b = min(W, i + r + 1)
                box[j, i] = row[j, b] - row[j, a]
                box2[j, i] = row2[j, b] - row2[j, a]
        for i in range(W):  # vertical running sums of the horizontal boxes
            col[0] = 0.0
            col2[0] = 0.0
            for j in range(H):
                col[j + 1] = col[j] + box[j, i]
                col2[j + 1] = col2[j] + box2[j, i]
            na = min(W, i + r + 1) - max(0, i - r)
            for j in range(H):
                a = max(0, j - r)
                b = min(H, j + r + 1)
                n = na * (b - a)
                m = (col[b] - col[a]) / n
                var = (col2[b] - col2[a]) / n - m * m
                if k > 0 and kbest[j, i] == k - 1:
                    after[j, i] = var
                if var > best[j, i]:
                    best[j, i] = var
                    kbest[j, i] = k
                    before[j, i] = prev[j, i]
                prev[j, i] = var
    for j in range(H):
        for i in range(W):
            k = kbest[j, i]
            off = 0.0
            if refine and 0 < k < P - 1:
                off = _vertex(before[j, i], best[j, i], after[j, i])
            index[j, i] = k + off
