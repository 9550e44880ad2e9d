"""One simulation step as one kernel: log intensity, per-pixel refinement, DVS.

A step ``(t0, t1]`` renders the whole frame once, at ``t1``. A pixel whose
log intensity changed by at most ``max_dlog``, and ended at most ``max_bend``
off the straight continuation of its previous piece (so it did not turn
inside the step, as where a texture extremum passes by: a turn the two
end samples alone would miss), is taken as linear in time over the step
(the common case). Any other pixel is refined alone
(into two pieces at least when it turned): its interval
is cut on a dyadic grid of ``2**nlev`` sub-steps, and only that pixel is
rendered at the sub-step times it needs, walking forward in time and halving
the sub-step until each piece changes by at most ``max_dlog`` (or is one
grid cell, at least ``dt_min`` long); the DVS model then runs along the
pieces. So every pixel's samples obey the same bound as a global step would
give, but only the pixels that need them pay for them. Scene states at the
grid times (pose, patch planes, sprite states, background offset) are
computed once per step, on first use.

With the photoreceptor low-pass on, the filter runs along the same pieces
(its input held at each piece's end value, as for a whole step).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .dvs import fire, lowpass1, need_events, quiet
from .motion import pose_kernel
from .render import SPRITE_STATE, background, frame_patches, pixel_value, sprite_states

__all__ = ["advance", "NodeCache"]


class NodeCache:
    """Scene states at the sub-step grid of one step (arrays the kernel fills)."""

    def __init__(self, max_lev: int, n_patches: int, n_sprites: int) -> None:
        n = (1 << max_lev) + 1
        self.t = np.zeros(n)
        self.R = np.zeros((n, 3, 3))
        self.p = np.zeros((n, 3))
        self.pc = np.zeros((n, n_patches, 12))
        self.st = np.zeros((n, n_sprites, SPRITE_STATE))
        self.g = np.zeros((n, 3))
        self.done = np.zeros(n, np.bool_)
        self.seg_t = np.empty(n)
        self.seg_L = np.empty(n)

    def reset(self) -> None:
        self.done[:] = False


@njit(cache=True)
def _node(j: int, N: int, t0: float, t1: float, traj: np.ndarray, patches: np.ndarray, sprites: np.ndarray,
          bg: np.ndarray, nt: np.ndarray, nR: np.ndarray, np_: np.ndarray, npc: np.ndarray, nst: np.ndarray,
          ng: np.ndarray, done: np.ndarray) -> None:
    """Fill the scene state of grid node ``j`` (time ``t0 + j (t1 - t0) / N`` µs)."""
    t = t1 if j == N else t0 + (t1 - t0) * j / N
    ts = t * 1e-6
    nt[j] = t
    pose_kernel(traj, ts, nR[j], np_[j])
    frame_patches(nR[j], np_[j], patches, npc[j])
    sprite_states(sprites, ts, nst[j])
    g, bx, by = background(bg, ts)
    ng[j, 0] = g
    ng[j, 1] = bx
    ng[j, 2] = by
    done[j] = True


@njit(cache=True)
def advance(img: np.ndarray, W: int, L: np.ndarray, lp: np.ndarray, slope: np.ndarray, t0: float, t1: float, eps: float,
            lp_hz: float, lp_min_hz: float, max_dlog: float, max_bend: float, nlev: int,
            l_ref: np.ndarray, t_release: np.ndarray, c_on: np.ndarray, c_off: np.ndarray, refr: float,
            traj: np.ndarray, f: float, cx: float, cy: float, patches: np.ndarray, pano: np.ndarray,
            bg: np.ndarray, sprites: np.ndarray, data: np.ndarray, table: np.ndarray, ss: int,
            nt: np.ndarray, nR: np.ndarray, np_: np.ndarray, npc: np.ndarray, nst: np.ndarray, ng: np.ndarray,
            done: np.ndarray, seg_t: np.ndarray, seg_L: np.ndarray,
            start: int, out_t: np.ndarray, out_i: np.ndarray, out_p: np.ndarray) -> tuple[int, int, int]:
    """Advance pixels ``start ..`` over ``(t0, t1]`` µs (see the module doc).

    ``img`` (flat) is the true linear intensity at ``t1``; ``L`` (log
    intensity at ``t0``, becomes that at ``t1``), ``lp`` (low-pass state,
    used when ``lp_hz > 0``), ``slope`` (log intensity per µs over each
    pixel's last piece), ``l_ref`` and ``t_release`` are updated in place.
    Events go to ``out_*`` as in :func:`.dvs.dvs_step`. Returns
    ``(n_written, next_pixel, refined_pixels)``; ``next_pixel < img.size``
    means the output was full: call again from there with room (that pixel
    is untouched).
    """
    n = 0
    refined = 0
    cap = out_t.shape[0]
    npx = img.shape[0]
    N = 1 << nlev
    lowpass = lp_hz > 0.0
    dt = t1 - t0
    dt_s = dt * 1e-6
    for i in range(start, npx):
        v = img[i]
        if lowpass:
            lpb = lowpass1(lp[i], v, dt_s, lp_hz, lp_min_hz)
            b = math.log(max(lpb, 0.0) + eps)
        else:
            lpb = v
            b = math.log(max(v, 0.0) + eps)
        a = L[i]
        bend = abs(b - a - slope[i] * dt)  # off the straight line of the previous step: a turn inside?
        if nlev == 0 or (abs(b - a) <= max_dlog and bend <= max_bend):
            if not quiet(i, b, t0, t1, l_ref, t_release, c_on, c_off):
                if n + need_events(i, a, b, t0, t1, l_ref, t_release, c_on, c_off) > cap:
                    return n, i, refined
                n = fire(i, a, b, t0, t1, l_ref, t_release, c_on, c_off, refr, out_t, out_i, out_p, n)
            L[i] = b
            lp[i] = lpb
            slope[i] = (b - a) / dt
            continue
        # refine this pixel alone: walk the dyadic grid forward (at least two pieces when it turns)
        refined += 1
        x = float(i % W)
        y = float(i // W)
        j = 0
        s = N if abs(b - a) > max_dlog else N >> 1
        la = a
        lpa = lp[i]
        ta = t0
        ns = 0
        seg_t[0] = t0
        seg_L[0] = a
        while j < N:
            jb = j + s
            if jb == N:
                vb = v
                tb = t1
            else:
                if not done[jb]:
                    _node(jb, N, t0, t1, traj, patches, sprites, bg, nt, nR, np_, npc, nst, ng, done)
                vb = pixel_value(x, y, nR[jb], npc[jb], nst[jb], ng[jb, 0], ng[jb, 1], ng[jb, 2], f, cx, cy,
                                 patches, pano, bg, sprites, data, table, ss)
                tb = nt[jb]
            if lowpass:
                lpn = lowpass1(lpa, vb, (tb - ta) * 1e-6, lp_hz, lp_min_hz)
                lb = math.log(max(lpn, 0.0) + eps)
            else:
                lpn = vb
                lb = math.log(max(vb, 0.0) + eps)
            if s > 1 and abs(lb - la) > max_dlog:
                s >>= 1
                continue
            ns += 1
            seg_t[ns] = tb
            seg_L[ns] = lb
            j = jb
            la = lb
            lpa = lpn
            ta = tb
            if j % (2 * s) == 0 and 2 * s <= N:
                s <<= 1
        # room for the worst case along the pieces (see need_events)
        cmin = min(c_on[i], c_off[i])
        cmax = max(c_on[i], c_off[i])
        need = abs(a - l_ref[i]) / cmin + 1.0
        for k in range(1, ns + 1):
            need += (abs(seg_L[k] - seg_L[k - 1]) + cmax) / cmin + 1.0
        if n + need > cap:
            return n, i, refined - 1
        for k in range(1, ns + 1):
            n = fire(i, seg_L[k - 1], seg_L[k], seg_t[k - 1], seg_t[k], l_ref, t_release, c_on, c_off, refr,
                     out_t, out_i, out_p, n)
        L[i] = la
        lp[i] = lpa
        slope[i] = (seg_L[ns] - seg_L[ns - 1]) / (seg_t[ns] - seg_t[ns - 1])
    return n, npx, refined
