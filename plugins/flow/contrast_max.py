"""``flow.contrast_max``: full flow by contrast maximisation (Gallego et al., CVPR 2018).

Time is cut into windows of ``window_us`` (aligned to multiples of it); each
window's events are split into square patches of ``patch_px`` pixels (0 =
one patch for the whole sensor). Per patch, the flow ``v`` maximises the
sharpness of the image of warped events ``x - v (t - t_mid)`` (bilinear
voting; sharpness = sum of squared pixel values, which for a fixed number of
events is the image variance up to a constant). The search is a
coarse-to-fine pattern search from zero with a step of ``max_speed / 2``
down to 0.05 px of displacement, on coarser pixels while the step is large;
a patch whose previous window gave a valid flow starts from it with a step
of ``max_speed / 16`` instead.

A patch's flow is given to all its events (**full flow**), valid only if:
it has ``min_events`` events; the warped image is focused (sharpness per
event >= ``min_focus``: random events give about 1) and at least
``min_gain`` times sharper than without motion compensation (else the
motion is too small to measure in one window); and its edges have several
orientations (smaller over larger eigenvalue of its gradient structure
tensor >= ``min_cond``): a lone straight edge leaves the flow along it
undetermined, the aperture problem, reported as invalid.

Windowed: output for a window is emitted when the watermark passes its end
(or at end of stream), identical however the packets are split.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, concat

from ._common import FlowOperator

__all__ = ["ContrastMax", "contrast_max_window"]


@njit(cache=True, nogil=True, inline="always")
def _vote(xs, ys, ts, lo, hi, vx, vy, img, margin, scale):  # type: ignore[no-untyped-def]
    """Bilinear image of events lo..hi warped by ``v`` (px/s) to the window's
    middle, on pixels ``scale`` times the sensor's, added into ``img``."""
    ih, iw = img.shape
    for j in range(lo, hi):
        wx = (xs[j] - vx * ts[j] + margin) / scale
        wy = (ys[j] - vy * ts[j] + margin) / scale
        ix, iy = int(np.floor(wx)), int(np.floor(wy))
        if 0 <= ix < iw - 1 and 0 <= iy < ih - 1:
            fx, fy = wx - ix, wy - iy
            img[iy, ix] += (1 - fx) * (1 - fy)
            img[iy, ix + 1] += fx * (1 - fy)
            img[iy + 1, ix] += (1 - fx) * fy
            img[iy + 1, ix + 1] += fx * fy


@njit(cache=True, nogil=True)
def _sharpness(xs, ys, ts, lo, hi, vx, vy, img, margin, scale=1.0):  # type: ignore[no-untyped-def]
    """Sum of squares of the bilinear image of warped events lo..hi (then
    cleared), on pixels ``scale`` times the sensor's (coarse-to-fine search)."""
    ih, iw = img.shape
    _vote(xs, ys, ts, lo, hi, vx, vy, img, margin, scale)
    s = 0.0
    for j in range(lo, hi):
        wx = (xs[j] - vx * ts[j] + margin) / scale
        wy = (ys[j] - vy * ts[j] + margin) / scale
        ix, iy = int(np.floor(wx)), int(np.floor(wy))
        if 0 <= ix < iw - 1 and 0 <= iy < ih - 1:
            for cy in range(iy, iy + 2):
                for cx in range(ix, ix + 2):
                    u = img[cy, cx]
                    s += u * u
                    img[cy, cx] = 0.0
    return s


@njit(cache=True, nogil=True)
def _isotropy(xs, ys, ts, lo, hi, vx, vy, img, margin):  # type: ignore[no-untyped-def]
    """Smaller over larger eigenvalue of the gradient structure tensor of the
    image of warped events: near 0 for a lone straight edge (aperture problem),
    larger where edges of several orientations meet."""
    ih, iw = img.shape
    _vote(xs, ys, ts, lo, hi, vx, vy, img, margin, 1.0)
    sxx = sxy = syy = 0.0
    for r in range(1, ih - 1):
        for c in range(1, iw - 1):
            gx = img[r, c + 1] - img[r, c - 1]
            gy = img[r + 1, c] - img[r - 1, c]
            sxx += gx * gx
            sxy += gx * gy
            syy += gy * gy
    img[:, :] = 0.0
    tr = sxx + syy
    if tr <= 0.0:
        return 0.0
    disc = np.sqrt(max(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0.0))
    return (0.5 * tr - disc) / (0.5 * tr + disc)


@njit(cache=True, nogil=True)
def _maximise(xs, ys, ts, lo, hi, img, margin, max_speed, start_x, start_y, start_step, min_step, half_s):  # type: ignore[no-untyped-def]
    """Pattern search from (start_x, start_y) px/s, halving the step down to
    ``min_step``; while a step moves events by more than a pixel at the
    window's ends (``half_s`` seconds from its middle) the image is made of
    coarser pixels, which keeps the narrow ridges of the objective climbable."""
    bx, by = start_x, start_y
    step = start_step
    best = 0.0
    while step >= min_step:
        scale = max(1.0, step * half_s)
        best = _sharpness(xs, ys, ts, lo, hi, bx, by, img, margin, scale)
        moved = True
        while moved:
            moved = False
            cx, cy = bx, by
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    if dx == 0 and dy == 0:
                        continue
                    vx, vy = cx + dx * step, cy + dy * step
                    if abs(vx) > max_speed or abs(vy) > max_speed:
                        continue
                    f = _sharpness(xs, ys, ts, lo, hi, vx, vy, img, margin, scale)
                    if f > best:
                        best, bx, by, moved = f, vx, vy, True
        step *= 0.5
    return bx, by, _sharpness(xs, ys, ts, lo, hi, bx, by, img, margin, 1.0)


@njit(cache=True, nogil=True)
def contrast_max_window(t, x, y, t_mid, half_s, patch, max_speed, min_step, min_events, min_focus, min_gain,
                        min_cond, prev_v, prev_ok, vx, vy, valid):  # type: ignore[no-untyped-def]
    """Flow (px/s) for one window's events; ``prev_v`` (PY, PX, 2) and
    ``prev_ok`` (PY, PX) hold each patch's last result and are updated."""
    n = t.shape[0]
    npy, npx = prev_ok.shape
    pid = np.empty(n, np.int64)
    for i in range(n):
        pid[i] = (np.int64(y[i]) // patch) * npx + np.int64(x[i]) // patch
    order = np.argsort(pid, kind="mergesort")
    half = 0.5 * max_speed * 1e-6 * (np.max(t) - np.min(t) + 1) if n else 0.0
    margin = int(np.ceil(max(half, 0.0))) + 2
    img = np.zeros((patch + 2 * margin + 2, patch + 2 * margin + 2))
    xs = np.empty(n)
    ys = np.empty(n)
    ts = np.empty(n)
    for q in range(n):
        i = order[q]
        xs[q] = np.int64(x[i]) % patch
        ys[q] = np.int64(y[i]) % patch
        ts[q] = (t[i] - t_mid) * 1e-6
    lo = 0
    while lo < n:
        p = pid[order[lo]]
        hi = lo
        while hi < n and pid[order[hi]] == p:
            hi += 1
        py_, px_ = p // npx, p % npx
        ok = hi - lo >= min_events
        fx = fy = 0.0
        if ok:
            if prev_ok[py_, px_]:
                fx, fy, best = _maximise(xs, ys, ts, lo, hi, img, margin, max_speed, prev_v[py_, px_, 0],
                                         prev_v[py_, px_, 1], max_speed / 16.0, min_step, half_s)
            else:
                fx, fy, best = _maximise(xs, ys, ts, lo, hi, img, margin, max_speed, 0.0, 0.0, max_speed / 2.0,
                                         min_step, half_s)
            ok = best / (hi - lo) >= min_focus
        if ok:
            # the flow must sharpen the image clearly more than no motion does
            ok = best >= min_gain * _sharpness(xs, ys, ts, lo, hi, 0.0, 0.0, img, margin, 1.0)
        if ok:
            ok = _isotropy(xs, ys, ts, lo, hi, fx, fy, img, margin) >= min_cond
        prev_ok[py_, px_] = ok
        prev_v[py_, px_, 0] = fx
        prev_v[py_, px_, 1] = fy
        for q in range(lo, hi):
            i = order[q]
            valid[i] = ok
            vx[i] = fx if ok else np.nan
            vy[i] = fy if ok else np.nan
        lo = hi


class ContrastMax(FlowOperator):
    """Full flow (px/s) per patch and time window by contrast maximisation.

    Output: **full flow** in ``out_vx``/``out_vy``, NaN where ``out_valid`` is
    false (too few events, unfocused, or aperture-limited). Parameters:
    ``window_us`` (µs), ``patch_px`` (px, 0 = whole sensor), ``max_speed``
    (px/s, the search range), ``min_events``, ``min_focus`` (sharpness per
    event), ``min_gain`` (over no motion), ``min_cond`` (0..1). Emits each window when the watermark passes
    its end: latency up to one window.
    """

    name = "flow.contrast_max"
    flow_type = "full"

    def __init__(self, window_us: int = 10_000, patch_px: int = 32, max_speed: float = 2000.0,
                 min_events: int = 40, min_focus: float = 1.3, min_gain: float = 1.2, min_cond: float = 0.15,
                 out_vx: str = "vx", out_vy: str = "vy", out_valid: str = "valid") -> None:
        if window_us <= 0 or patch_px < 0 or max_speed <= 0 or min_events < 1 or min_cond < 0:
            raise ValueError("need window_us > 0, patch_px >= 0, max_speed > 0, min_events >= 1, min_cond >= 0")
        self.window_us, self.patch_px, self.max_speed = int(window_us), int(patch_px), float(max_speed)
        self.min_events, self.min_focus, self.min_cond = int(min_events), float(min_focus), float(min_cond)
        self.min_gain = float(min_gain)
        self._set_outputs(out_vx, out_vy, out_valid)
        # search down to 0.05 px of displacement at the window's ends
        self.min_step = 0.05 / (0.5 * self.window_us * 1e-6)
        self._pending: list[EventPacket] = []
        self._win: int | None = None  # start of the open window, µs
        self._prev_v: np.ndarray | None = None

    def _patch(self, sensor: tuple[int, int]) -> int:
        return self.patch_px or max(sensor)

    def _run_window(self, pkt: EventPacket, t0: int) -> EventPacket:
        w, h = pkt.sensor
        patch = self._patch(pkt.sensor)
        if self._prev_v is None:
            self._prev_v = np.zeros((-(-h // patch), -(-w // patch), 2))
            self._prev_ok = np.zeros((-(-h // patch), -(-w // patch)), np.bool_)
        vx, vy, valid = self._alloc(len(pkt))
        if len(pkt):
            contrast_max_window(pkt.t, pkt.x, pkt.y, t0 + self.window_us // 2, 0.5e-6 * self.window_us, patch,
                                self.max_speed,
                                self.min_step, self.min_events, self.min_focus, self.min_gain, self.min_cond,
                                self._prev_v, self._prev_ok, vx, vy, valid)
        return self._emit(pkt, vx, vy, valid)

    def _flush(self, upto: int | None) -> list[EventPacket]:
        """Run every window ending at or before the watermark ``upto`` (µs;
        None = end of stream: all)."""
        out: list[EventPacket] = []
        if not self._pending:
            return out
        buf = concat(self._pending) if len(self._pending) > 1 else self._pending[0]
        assert self._win is not None
        while len(buf):
            self._win = max(self._win, (int(buf.t[0]) // self.window_us) * self.window_us)
            end = self._win + self.window_us
            if upto is not None and upto < end:
                break
            head, buf = buf.split_at(end)
            out.append(self._run_window(head, self._win))  # type: ignore[arg-type]
            self._win = end
        self._pending = [buf] if len(buf) else []  # type: ignore[list-item]
        return out

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self._win is None:
            self._win = (packet.t_start // self.window_us) * self.window_us
        if len(packet):
            self._pending.append(packet)
        return self._flush(packet.t_end)

    def finish(self) -> list[EventPacket]:
        return self._flush(None)
