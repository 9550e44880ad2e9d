"""Rendering kernels: the true intensity image and the true image motion.

A compiled scene is a few flat arrays (see :mod:`.scenes`):

* ``patches`` (n, 18) float64, textured planar patches in the world:
  centre (3), axis a1 (3), axis a2 (3), normal (3), half sizes (2; inf =
  unbounded), texture id, texel size (m), intensity (when no texture),
  object id.
* ``pano`` (3,): texture id (-1 = none), texel size (rad), object id: an
  equirectangular panorama at infinity.
* ``bg`` (7,): the image-plane background when there is no world: intensity,
  texture id, texel (px), vx, vy (px/s), log slope (1/s: the intensity is
  multiplied by ``exp(slope t)``), object id.
* ``sprites`` (m, 18) float64, image-plane objects drawn over everything in
  order: shape (0 disk, 1 rect, 2 edge), centre x, y (px at t = 0), vx, vy
  (px/s), angle (rad), spin (rad/s), size a, b (px; radius / width, height),
  intensity on, intensity off, texture id, texel (px), blink Hz, duty, rise
  (s), phase, object id.

Pixel centres are at integer coordinates; every shape is anti-aliased with a
one-pixel linear ramp of its signed distance, so intensity varies smoothly
while an edge crosses a pixel. The camera is a pinhole ``(f, cx, cy)`` in
pixels; a pose is world-from-camera ``(R, p)``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .textures import bilinear, sample_texture, texel_taps

__all__ = ["render", "pixel_value", "probe", "gradient_at", "lifetimes", "sprite_states", "frame_patches", "background",
           "SPRITE_STATE"]

DISK, RECT, EDGE = 0, 1, 2
#: Columns of a sprite's state (see :func:`sprite_states`).
SPRITE_STATE = 8


@njit(cache=True, inline="always")
def _clip01(v: float) -> float:
    return 0.0 if v < 0.0 else (1.0 if v > 1.0 else v)


@njit(cache=True, inline="always")
def _bounce(u0: float, v: float, t: float, lo: float, hi: float) -> tuple[float, float]:
    """Position and velocity at ``t`` (s) of a point starting at ``u0`` (px)
    with speed ``v`` (px/s) that bounces elastically between ``lo`` and
    ``hi`` (a triangle wave; no bounds when ``hi <= lo``)."""
    u = u0 + v * t
    if hi <= lo:
        return u, v
    span = hi - lo
    q = (u - lo) - 2.0 * span * math.floor((u - lo) / (2.0 * span))
    if q <= span:
        return lo + q, v
    return lo + 2.0 * span - q, -v


@njit(cache=True)
def sprite_states(sprites: np.ndarray, t: float, st: np.ndarray) -> np.ndarray:
    """Per sprite at time ``t`` (s), written to ``st`` (m, SPRITE_STATE) and
    returned: centre x, y (px), cos, sin of the angle, blink weight in
    [0, 1], a bounding radius (px, inf for edges) and the centre's velocity
    vx, vy (px/s; a sprite with a bounce box, columns 18-21, reflects off
    its sides)."""
    m = sprites.shape[0]
    for k in range(m):
        s = sprites[k]
        st[k, 0], st[k, 6] = _bounce(s[1], s[3], t, s[18], s[20])
        st[k, 1], st[k, 7] = _bounce(s[2], s[4], t, s[19], s[21])
        ang = s[5] + s[6] * t
        st[k, 2] = math.cos(ang)
        st[k, 3] = math.sin(ang)
        w = 1.0
        f = s[13]
        if f > 0.0:
            ph = t * f + s[16]
            ph = ph - math.floor(ph)
            rs = s[15] * f
            if ph < s[14]:
                w = 1.0 if rs <= 0.0 else min(1.0, ph / rs)
            else:
                w = 0.0 if rs <= 0.0 else max(0.0, 1.0 - (ph - s[14]) / rs)
        st[k, 4] = w
        shape = int(s[0])
        if shape == DISK:
            st[k, 5] = s[7] + 2.0
        elif shape == RECT:
            st[k, 5] = math.sqrt(0.25 * s[7] * s[7] + 0.25 * s[8] * s[8]) + 2.0
        else:
            st[k, 5] = np.inf
    return st


@njit(cache=True, inline="always")
def _coverage(shape: int, lx: float, ly: float, a: float, b: float, dilate: float) -> float:
    if shape == DISK:
        return _clip01(0.5 + a - math.sqrt(lx * lx + ly * ly) + dilate)
    if shape == RECT:
        return _clip01(0.5 + 0.5 * a - abs(lx) + dilate) * _clip01(0.5 + 0.5 * b - abs(ly) + dilate)
    return _clip01(0.5 - lx + dilate)


@njit(cache=True)
def frame_patches(R: np.ndarray, p: np.ndarray, patches: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Per patch, its plane in the camera frame of pose (R, p), so that a
    pixel's ray ``r = ((x - cx) / f, (y - cy) / f, 1)`` hits it at depth
    ``s = num / (n . r)`` with local coordinates ``o1 + s a1 . r``,
    ``o2 + s a2 . r``. Rows (written to ``out`` (n, 12), returned): n (3),
    a1 (3), a2 (3), num, o1, o2."""
    for k in range(patches.shape[0]):
        q = patches[k]
        for j in range(3):  # R^T applied to the world axes
            out[k, j] = R[0, j] * q[9] + R[1, j] * q[10] + R[2, j] * q[11]
            out[k, 3 + j] = R[0, j] * q[3] + R[1, j] * q[4] + R[2, j] * q[5]
            out[k, 6 + j] = R[0, j] * q[6] + R[1, j] * q[7] + R[2, j] * q[8]
        ox, oy, oz = p[0] - q[0], p[1] - q[1], p[2] - q[2]
        out[k, 9] = -(q[9] * ox + q[10] * oy + q[11] * oz)
        out[k, 10] = ox * q[3] + oy * q[4] + oz * q[5]
        out[k, 11] = ox * q[6] + oy * q[7] + oz * q[8]
    return out


@njit(cache=True, inline="always")
def _cast(ux: float, uy: float, pc: np.ndarray, patches: np.ndarray) -> tuple[int, float, float, float]:
    """Nearest patch hit by the ray ``(ux, uy, 1)`` (camera frame): index
    (-1 none), depth along the optical axis, local coordinates."""
    best = np.inf
    hit = -1
    ba = 0.0
    bb = 0.0
    for k in range(pc.shape[0]):
        den = pc[k, 0] * ux + pc[k, 1] * uy + pc[k, 2]
        if abs(den) < 1e-12:
            continue
        s = pc[k, 9] / den
        if s <= 1e-9 or s >= best:
            continue
        al = pc[k, 10] + s * (pc[k, 3] * ux + pc[k, 4] * uy + pc[k, 5])
        if abs(al) > patches[k, 12]:
            continue
        be = pc[k, 11] + s * (pc[k, 6] * ux + pc[k, 7] * uy + pc[k, 8])
        if abs(be) > patches[k, 13]:
            continue
        best = s
        hit = k
        ba = al
        bb = be
    return hit, best, ba, bb


@njit(cache=True, inline="always")
def _world_value(px: float, py: float, R: np.ndarray, f: float, cx: float, cy: float, pc: np.ndarray,
                 patches: np.ndarray, pano: np.ndarray, bg0: float, data: np.ndarray,
                 table: np.ndarray) -> float:
    ux = (px - cx) / f
    uy = (py - cy) / f
    hit, s, al, be = _cast(ux, uy, pc, patches)
    if hit >= 0:
        q = patches[hit]
        tid = int(q[14])
        if tid < 0:
            return q[16]
        return sample_texture(data, table, tid, al / q[15], be / q[15])
    tid = int(pano[0])
    if tid < 0:
        return bg0
    dx = R[0, 0] * ux + R[0, 1] * uy + R[0, 2]
    dy = R[1, 0] * ux + R[1, 1] * uy + R[1, 2]
    dz = R[2, 0] * ux + R[2, 1] * uy + R[2, 2]
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    az = math.atan2(dx, dz)
    el = math.asin(dy / n)
    return sample_texture(data, table, tid, az / pano[1], el / pano[1])


@njit(cache=True, inline="always")
def _atan_small(s: float) -> float:
    """atan(s) for |s| <= 0.02 (series to s^9: error below 1e-19)."""
    s2 = s * s
    return s * (1.0 - s2 * (1.0 / 3.0 - s2 * (0.2 - s2 * (1.0 / 7.0 - s2 / 9.0))))


@njit(cache=True)
def _panorama_rows(out: np.ndarray, R: np.ndarray, f: float, cx: float, cy: float, pano: np.ndarray,
                   data: np.ndarray, table: np.ndarray, gain: float) -> None:
    """The panorama alone, row by row. Along a row the ray direction is
    linear in x, so azimuth and elevation advance by small angles, taken by
    a short atan series of the cross/dot products of neighbouring rays;
    exact atan2/asin every 16 pixels and wherever the step is not small
    (near the poles). Agrees with :func:`_world_value` to ~1e-14 rad."""
    H, W = out.shape
    tid = int(pano[0])
    off, th, tw = table[tid, 0], table[tid, 1], table[tid, 2]
    inv = 1.0 / pano[1]
    ex, ey, ez = R[0, 0] / f, R[1, 0] / f, R[2, 0] / f
    ux0 = -cx / f
    for y in range(H):
        uy = (y - cy) / f
        ox = R[0, 0] * ux0 + R[0, 1] * uy + R[0, 2]
        oy = R[1, 0] * ux0 + R[1, 1] * uy + R[1, 2]
        oz = R[2, 0] * ux0 + R[2, 1] * uy + R[2, 2]
        az = 0.0
        el = 0.0
        pdx = 0.0
        pdy = 0.0
        pdz = 0.0
        ph = 0.0
        for x in range(W):
            dx = ox + x * ex
            dy = oy + x * ey
            dz = oz + x * ez
            h = math.sqrt(dx * dx + dz * dz)
            exact = (x & 15) == 0
            if not exact:
                dot = pdz * dz + pdx * dx
                crs = pdz * dx - pdx * dz
                dot2 = ph * h + pdy * dy
                crs2 = ph * dy - pdy * h
                if dot > 0.0 and abs(crs) < 0.02 * dot and dot2 > 0.0 and abs(crs2) < 0.02 * dot2:
                    az += _atan_small(crs / dot)
                    el += _atan_small(crs2 / dot2)
                else:
                    exact = True
            if exact:
                az = math.atan2(dx, dz)
                el = math.asin(dy / math.sqrt(dx * dx + dy * dy + dz * dz))
            pdx = dx
            pdy = dy
            pdz = dz
            ph = h
            c0, c1, au = texel_taps(az * inv + (tw if az < 0.0 else 0.0), tw)  # one turn on: no wrap
            r0, r1, av = texel_taps(el * inv, th)
            out[y, x] = bilinear(data, off, tw, c0, c1, au, r0, r1, av) * gain


@njit(cache=True)
def _blend_sprite(val: float, x: float, y: float, k: int, st: np.ndarray, sprites: np.ndarray,
                  data: np.ndarray, table: np.ndarray) -> float:
    """``val`` with sprite ``k`` (state ``st[k]``) drawn over it at pixel (x, y)."""
    ddx = x - st[k, 0]
    ddy = y - st[k, 1]
    r = st[k, 5]
    out = val
    if abs(ddx) <= r and abs(ddy) <= r:
        lx = st[k, 2] * ddx + st[k, 3] * ddy
        ly = -st[k, 3] * ddx + st[k, 2] * ddy
        a = _coverage(int(sprites[k, 0]), lx, ly, sprites[k, 7], sprites[k, 8], 0.0)
        if a > 0.0:
            tid = int(sprites[k, 11])
            off = sprites[k, 10]
            on = sprites[k, 9]
            if tid >= 0:
                on = sample_texture(data, table, tid, lx / sprites[k, 12], ly / sprites[k, 12])
            out = val * (1.0 - a) + (off + (on - off) * st[k, 4]) * a
    return out


@njit(cache=True, inline="always")
def background(bg: np.ndarray, t: float) -> tuple[float, float, float]:
    """Background gain and texture offset (px) at ``t`` (s)."""
    return math.exp(bg[5] * t), bg[3] * t, bg[4] * t


@njit(cache=True)
def pixel_value(x: float, y: float, R: np.ndarray, pc: np.ndarray, st: np.ndarray, gain: float, bx: float,
                by: float, f: float, cx: float, cy: float, patches: np.ndarray, pano: np.ndarray,
                bg: np.ndarray, sprites: np.ndarray, data: np.ndarray, table: np.ndarray, ss: int) -> float:
    """The true linear intensity of one pixel, given the frame's state
    (``pc`` from :func:`frame_patches`, ``st`` from :func:`sprite_states`,
    background gain and offset from :func:`background`): the same value
    :func:`render` writes there."""
    if patches.shape[0] > 0 or pano[0] >= 0:
        acc = 0.0  # (ss = 1: offsets are exactly 0, the value the pixel centre's)
        for sy in range(ss):
            for sx in range(ss):
                acc += _world_value(x + (sx + 0.5) / ss - 0.5, y + (sy + 0.5) / ss - 0.5,
                                    R, f, cx, cy, pc, patches, pano, bg[0], data, table)
        val = acc * (1.0 / (ss * ss))
    elif bg[1] >= 0:
        ibt = 1.0 / bg[2]
        val = sample_texture(data, table, int(bg[1]), (x - bx) * ibt, (y - by) * ibt)
    else:
        val = bg[0]
    val *= gain
    for k in range(sprites.shape[0]):
        val = _blend_sprite(val, x, y, k, st, sprites, data, table)
    return val


@njit(cache=True)
def render(out: np.ndarray, t: float, R: np.ndarray, p: np.ndarray, f: float, cx: float, cy: float,
           patches: np.ndarray, pano: np.ndarray, bg: np.ndarray, sprites: np.ndarray,
           data: np.ndarray, table: np.ndarray, ss: int) -> None:
    """Write the true linear intensity at time ``t`` (s) into ``out`` (H, W).

    ``ss`` is the supersampling factor per axis for the world (occlusion
    edges of patches are not otherwise anti-aliased). Per pixel the value
    is :func:`pixel_value`'s; the background is drawn first (a translating
    2-D texture with its texel taps computed once per row and column, a
    lone panorama incrementally along rows), then each sprite over its
    bounding box, in order."""
    H, W = out.shape
    st = sprite_states(sprites, t, np.empty((sprites.shape[0], SPRITE_STATE)))
    gain, bx, by = background(bg, t)
    pc = frame_patches(R, p, patches, np.empty((patches.shape[0], 12)))
    if patches.shape[0] == 0 and pano[0] >= 0 and ss == 1:
        _panorama_rows(out, R, f, cx, cy, pano, data, table, gain)
    elif patches.shape[0] > 0 or pano[0] >= 0:
        inv = 1.0 / (ss * ss)
        for y in range(H):
            for x in range(W):
                acc = 0.0
                for sy in range(ss):
                    for sx in range(ss):
                        acc += _world_value(x + (sx + 0.5) / ss - 0.5, y + (sy + 0.5) / ss - 0.5,
                                            R, f, cx, cy, pc, patches, pano, bg[0], data, table)
                out[y, x] = acc * inv * gain
    elif bg[1] >= 0:
        tid = int(bg[1])
        off, th, tw = table[tid, 0], table[tid, 1], table[tid, 2]
        ibt = 1.0 / bg[2]
        c0 = np.empty(W, np.int64)
        c1 = np.empty(W, np.int64)
        au = np.empty(W)
        for x in range(W):
            c0[x], c1[x], au[x] = texel_taps((x - bx) * ibt, tw)
        for y in range(H):
            r0, r1, av = texel_taps((y - by) * ibt, th)
            for x in range(W):
                out[y, x] = bilinear(data, off, tw, c0[x], c1[x], au[x], r0, r1, av) * gain
    else:
        out[:, :] = bg[0] * gain
    for k in range(sprites.shape[0]):
        r = st[k, 5]
        x0, x1, y0, y1 = 0, W - 1, 0, H - 1
        if r < np.inf:
            x0 = max(x0, int(math.ceil(st[k, 0] - r)))
            x1 = min(x1, int(math.floor(st[k, 0] + r)))
            y0 = max(y0, int(math.ceil(st[k, 1] - r)))
            y1 = min(y1, int(math.floor(st[k, 1] + r)))
        # (the body of _blend_sprite, written out: numba compiles the call to slower code)
        shape, a_, b_, tid = int(sprites[k, 0]), sprites[k, 7], sprites[k, 8], int(sprites[k, 11])
        on, off, texel, wk = sprites[k, 9], sprites[k, 10], sprites[k, 12], st[k, 4]
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                ddx = x - st[k, 0]
                ddy = y - st[k, 1]
                lx = st[k, 2] * ddx + st[k, 3] * ddy
                ly = -st[k, 3] * ddx + st[k, 2] * ddy
                a = _coverage(shape, lx, ly, a_, b_, 0.0)
                if a <= 0.0:
                    continue
                v = on if tid < 0 else sample_texture(data, table, tid, lx / texel, ly / texel)
                out[y, x] = out[y, x] * (1.0 - a) + (off + (v - off) * wk) * a


@njit(cache=True, inline="always")
def _project(Xx: float, Xy: float, Xz: float, R: np.ndarray, p: np.ndarray, w: float,
             f: float, cx: float, cy: float) -> tuple[float, float]:
    """Project a world point (w = 1) or direction (w = 0) with pose (R, p)."""
    ax = Xx - w * p[0]
    ay = Xy - w * p[1]
    az = Xz - w * p[2]
    cxx = R[0, 0] * ax + R[1, 0] * ay + R[2, 0] * az
    cyy = R[0, 1] * ax + R[1, 1] * ay + R[2, 1] * az
    czz = R[0, 2] * ax + R[1, 2] * ay + R[2, 2] * az
    return f * cxx / czz + cx, f * cyy / czz + cy


@njit(cache=True)
def probe(xs: np.ndarray, ys: np.ndarray, t: float, R: np.ndarray, p: np.ndarray,
          Ra: np.ndarray, pa: np.ndarray, Rb: np.ndarray, pb: np.ndarray, delta: float,
          f: float, cx: float, cy: float, patches: np.ndarray, pano: np.ndarray, bg: np.ndarray,
          sprites: np.ndarray, vx: np.ndarray, vy: np.ndarray, oid: np.ndarray,
          depth: np.ndarray) -> None:
    """True image motion at pixels ``(xs, ys)`` at time ``t`` (s).

    Writes ``vx``, ``vy`` (px/s), the object id and the depth (m along the
    optical axis; inf for the panorama, NaN for image-plane objects and
    background). The topmost sprite that covers the pixel (dilated by one
    pixel, so a trailing edge still owns the pixel it just left) wins; else
    the world point seen there is projected with the poses at ``t - delta``
    (``Ra, pa``) and ``t + delta`` (``Rb, pb``): a symmetric difference of the
    exact projection."""
    st = sprite_states(sprites, t, np.empty((sprites.shape[0], SPRITE_STATE)))
    world = patches.shape[0] > 0 or pano[0] >= 0
    pc = frame_patches(R, p, patches, np.empty((patches.shape[0], 12)))
    for i in range(xs.shape[0]):
        x = float(xs[i])
        y = float(ys[i])
        found = False
        for k in range(sprites.shape[0] - 1, -1, -1):
            ddx = x - st[k, 0]
            ddy = y - st[k, 1]
            if abs(ddx) > st[k, 5] or abs(ddy) > st[k, 5]:
                continue
            s = sprites[k]
            lx = st[k, 2] * ddx + st[k, 3] * ddy
            ly = -st[k, 3] * ddx + st[k, 2] * ddy
            if _coverage(int(s[0]), lx, ly, s[7], s[8], 1.0) > 0.0:
                w = s[6]
                vx[i] = st[k, 6] - w * ddy
                vy[i] = st[k, 7] + w * ddx
                oid[i] = int(s[17])
                depth[i] = np.nan
                found = True
                break
        if found:
            continue
        if not world:
            vx[i] = bg[3]
            vy[i] = bg[4]
            oid[i] = int(bg[6])
            depth[i] = np.nan
            continue
        ux = (x - cx) / f
        uy = (y - cy) / f
        hit, s_, al, be = _cast(ux, uy, pc, patches)
        dx = R[0, 0] * ux + R[0, 1] * uy + R[0, 2]
        dy = R[1, 0] * ux + R[1, 1] * uy + R[1, 2]
        dz = R[2, 0] * ux + R[2, 1] * uy + R[2, 2]
        if hit >= 0:
            Xx = p[0] + s_ * dx
            Xy = p[1] + s_ * dy
            Xz = p[2] + s_ * dz
            ww = 1.0
            oid[i] = int(patches[hit, 17])
            depth[i] = s_
        elif pano[0] >= 0:
            Xx, Xy, Xz, ww = dx, dy, dz, 0.0
            oid[i] = int(pano[2])
            depth[i] = np.inf
        else:
            vx[i] = 0.0
            vy[i] = 0.0
            oid[i] = int(bg[6])
            depth[i] = np.inf
            continue
        ua, va = _project(Xx, Xy, Xz, Ra, pa, ww, f, cx, cy)
        ub, vb = _project(Xx, Xy, Xz, Rb, pb, ww, f, cx, cy)
        vx[i] = (ub - ua) / (2.0 * delta)
        vy[i] = (vb - va) / (2.0 * delta)


@njit(cache=True, inline="always")
def _sobel(L: np.ndarray, x: int, y: int) -> tuple[float, float]:
    H, W = L.shape
    sx = 0.0
    sy = 0.0
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            wgt = 2.0 if dx == 0 or dy == 0 else 1.0
            v = L[min(max(y + dy, 0), H - 1), min(max(x + dx, 0), W - 1)]
            sx += dx * wgt * v
            sy += dy * wgt * v
    return sx / 8.0, sy / 8.0


@njit(cache=True)
def gradient_at(L: np.ndarray, xs: np.ndarray, ys: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> None:
    """Spatial gradient of ``L`` (H, W) at the pixels: the Sobel operator
    (scaled to per-pixel units; edges replicated at the border), whose
    direction is accurate for oblique edges too."""
    for i in range(xs.shape[0]):
        gx[i], gy[i] = _sobel(L, int(xs[i]), int(ys[i]))


@njit(cache=True)
def lifetimes(L: np.ndarray, xs: np.ndarray, ys: np.ndarray, vx: np.ndarray, vy: np.ndarray,
              out: np.ndarray) -> None:
    """Per pixel, the time (µs) the local edge takes to move one pixel:
    ``1e6 / |v . g / |g||`` with ``g`` the :func:`gradient_at` of ``L``
    (the speed itself where ``L`` is flat; inf when nothing moves, NaN
    when the motion is unknown)."""
    for i in range(xs.shape[0]):
        gx, gy = _sobel(L, int(xs[i]), int(ys[i]))
        g = math.sqrt(gx * gx + gy * gy)
        if g > 1e-9:
            vn = abs(vx[i] * gx + vy[i] * gy) / g
        else:
            vn = math.sqrt(vx[i] * vx[i] + vy[i] * vy[i])
        out[i] = 1e6 / vn if vn > 0 else (np.inf if vn == 0 else np.nan)  # NaN: motion unknown
