"""``flow.contrast_max``: full flow by contrast maximisation (Gallego et al., CVPR 2018).

Time is cut into windows of ``window_us`` (aligned to multiples of it); each
window's events are split into square patches of ``patch_px`` pixels (0 =
one patch for the whole sensor). Per patch, the flow ``v`` maximises the
sharpness of the image of warped events ``x - v (t - t_mid)`` (sum of
squared pixel values, which for a fixed number of events is the image
variance up to a constant). Each event votes with a separable quadratic
B-spline of 3 x 3 pixels (a Gaussian-like blob, sigma 0.5 px: the image of
warped events smoothed, as Gallego et al. do, so the objective is smooth in
``v`` and does not favour whole-pixel displacements, which plain bilinear
voting does for sub-pixel motion): the votes and the sum of squares of the
CMax core (:mod:`tectum.plugins._cmax`) that ``tracker.angular_velocity``
uses too. The search is a coarse-to-fine pattern
search from zero with a step of ``max_speed / 2`` down to about 0.1 px of
displacement, on coarser pixels while the step is large, ending at the
vertex of the parabolas through the best point and its 4 neighbours (within
half a step); a patch whose previous window gave a valid flow starts from it
with a step of ``max_speed / 64`` instead (a quarter of a pixel at the ends
of a 10 ms span at the default 2000 px/s: constant motion moves the optimum
little between windows, and the search walks on while it improves).

A patch's flow is given to all its events (**full flow**), valid only if:
it has ``min_events`` events; the warped image is focused (sharpness per
event >= ``min_focus``: with the smoothed votes random events give about
0.4-0.6 at up to 300 events per 32 px patch; lone or sparse edges in one
10 ms window about 0.9-1.3, where the flow is often wrong, so they wait
for a longer span) and at least
``min_gain`` times sharper than without motion compensation; and its edges
have several orientations (smaller over larger eigenvalue of its gradient
structure tensor >= ``min_cond``): a lone straight edge leaves the flow
along it undetermined, the aperture problem, reported as invalid.

Adaptive time span: a slow patch moves too little in one window to be
measured (no gain over no motion) or only coarsely. When a patch's estimate
is invalid (but not aperture-limited) or moves it less than
``min_disp_px`` over the span, the span
grows, by doubling, up to ``max_window_us``: the estimate then uses the
patch's events of the last 2, 4, ... windows (speeds searched up to
``max_speed * window_us / span``: the same range of displacements; from
the shorter span's estimate, with a step of ``max_speed / 8``, or
``/ 64`` if that was valid), and the
events of the current window get the flow of the first span that moves the
patch by ``min_disp_px``, else of the longest span that gave a valid one.
A patch does not retry spans predicted to fail: after a valid estimate on
a span, the next window starts on the shortest span whose predicted
sharpness per event and displacement clear ``min_focus`` and
``min_disp_px`` by 20 % (on a focused edge both grow in proportion to the
span; :func:`_first_span`). On sparse edges at 1 Mev/s this skips the
one-window estimate that most patches fail for lack of focus: 1.5x less
compute at the same accuracy (A/B, interleaved repeats).

Windowed: output for a window is emitted when the watermark passes its end
(or at end of stream), identical however the packets are split (the
longer spans are made of whole earlier windows).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, concat, same_sensor

from .._cmax import add_sq
from ._common import FlowOperator

__all__ = ["ContrastMax", "contrast_max_window", "contrast_max_grow"]


@njit(cache=True, nogil=True, inline="always")
def _vote(xs, ys, ts, lo, hi, vx, vy, img, margin, scale):  # type: ignore[no-untyped-def]
    """Image of events lo..hi warped by ``v`` (px/s) to the span's middle,
    each a 3 x 3 quadratic B-spline, on pixels ``scale`` times the sensor's,
    added into ``img``; returns the box of touched pixels (r0, r1, c0, c1),
    inclusive."""
    ih, iw = img.shape
    r0, r1, c0, c1 = ih, -1, iw, -1
    for j in range(lo, hi):
        wx = (xs[j] - vx * ts[j] + margin) / scale
        wy = (ys[j] - vy * ts[j] + margin) / scale
        fx = np.floor(wx + 0.5)
        fy = np.floor(wy + 0.5)
        ix, iy = int(fx), int(fy)
        if 1 <= ix < iw - 1 and 1 <= iy < ih - 1:
            r0, r1, c0, c1 = min(r0, iy - 1), max(r1, iy + 1), min(c0, ix - 1), max(c1, ix + 1)
            add_sq(img, ix, iy, wx - fx, wy - fy)
    return r0, r1, c0, c1


@njit(cache=True, nogil=True, fastmath=True)
def _sharpness(xs, ys, ts, lo, hi, vx, vy, img, margin, scale=1.0):  # type: ignore[no-untyped-def]
    """Sum of squares of the smoothed image of warped events lo..hi (``img``
    is left cleared), on pixels ``scale`` times the sensor's (coarse-to-fine
    search). Summed while voting (the CMax core's :func:`add_sq`), without
    a sweep of the image."""
    ih, iw = img.shape
    inv = 1.0 / scale
    r0, r1, c0, c1 = ih, -1, iw, -1
    s = 0.0
    for j in range(lo, hi):
        wx = (xs[j] - vx * ts[j] + margin) * inv
        wy = (ys[j] - vy * ts[j] + margin) * inv
        fx = np.floor(wx + 0.5)
        fy = np.floor(wy + 0.5)
        ix, iy = int(fx), int(fy)
        if 1 <= ix < iw - 1 and 1 <= iy < ih - 1:
            r0, r1, c0, c1 = min(r0, iy), max(r1, iy), min(c0, ix), max(c1, ix)
            s += add_sq(img, ix, iy, wx - fx, wy - fy)
    for r in range(r0 - 1, r1 + 2):
        img[r, c0 - 1:c1 + 2] = 0.0
    return s


@njit(cache=True, nogil=True)
def _isotropy(xs, ys, ts, lo, hi, vx, vy, img, margin):  # type: ignore[no-untyped-def]
    """Smaller over larger eigenvalue of the gradient structure tensor of the
    image of warped events: near 0 for a lone straight edge (aperture problem),
    larger where edges of several orientations meet."""
    ih, iw = img.shape
    r0, r1, c0, c1 = _vote(xs, ys, ts, lo, hi, vx, vy, img, margin, 1.0)
    sxx = sxy = syy = 0.0
    # the gradient is zero but next to the touched box (pixels 1..size-2 only)
    for r in range(max(1, r0 - 1), min(ih - 1, r1 + 2)):
        for c in range(max(1, c0 - 1), min(iw - 1, c1 + 2)):
            gx = img[r, c + 1] - img[r, c - 1]
            gy = img[r + 1, c] - img[r - 1, c]
            sxx += gx * gx
            sxy += gx * gy
            syy += gy * gy
    img[max(0, r0):r1 + 1, max(0, c0):c1 + 1] = 0.0
    tr = sxx + syy
    if tr <= 0.0:
        return 0.0
    disc = np.sqrt(max(0.25 * (sxx - syy) ** 2 + sxy * sxy, 0.0))
    return (0.5 * tr - disc) / (0.5 * tr + disc)


@njit(cache=True, nogil=True)
def _maximise(xs, ys, ts, lo, hi, img, margin, max_speed, start_x, start_y, start_step, min_step, half_s):  # type: ignore[no-untyped-def]
    """Pattern search from (start_x, start_y) px/s, halving the step down to
    ``min_step``; while a step moves events by more than a pixel at the
    span's ends (``half_s`` seconds from its middle) the image is made of
    coarser pixels, which keeps the narrow ridges of the objective climbable."""
    bx, by = start_x, start_y
    step = start_step
    best = 0.0
    scale = 0.0  # of the image ``best`` was measured on
    near = np.zeros(4)  # the objective at the centre's 4 neighbours
    while step >= min_step:
        if max(1.0, step * half_s) != scale:
            scale = max(1.0, step * half_s)
            best = _sharpness(xs, ys, ts, lo, hi, bx, by, img, margin, scale)
        back = -1  # the direction back to the last centre: known to be worse
        moved = True
        while moved:
            moved = False
            cx, cy = bx, by
            last = best
            for k, (dx, dy) in enumerate(((-1, 0), (1, 0), (0, -1), (0, 1))):
                vx, vy = cx + dx * step, cy + dy * step
                if k == back:
                    continue
                if abs(vx) > max_speed or abs(vy) > max_speed:
                    near[k] = -1.0
                    continue
                f = _sharpness(xs, ys, ts, lo, hi, vx, vy, img, margin, scale)
                near[k] = f
                if f > best:
                    best, bx, by, moved = f, vx, vy, True
                    back = k ^ 1
            if moved:
                near[back] = last
        if step < 4.0 * min_step and scale == 1.0:
            # the last step: the vertex of the parabola through the centre and its neighbours
            for k in (0, 2):
                den = near[k] - 2.0 * best + near[k + 1]
                if near[k] >= 0.0 and near[k + 1] >= 0.0 and den < 0.0:
                    d = min(0.5, max(-0.5, 0.5 * (near[k] - near[k + 1]) / den)) * step
                    if k == 0:
                        bx += d
                    else:
                        by += d
            return bx, by, best
        step *= 0.5
    if scale != 1.0:
        best = _sharpness(xs, ys, ts, lo, hi, bx, by, img, margin, 1.0)
    return bx, by, best


@njit(cache=True, nogil=True)
def _estimate(xs, ys, ts, lo, hi, img, margin, max_speed, start_x, start_y, start_step, min_step, half_s,  # type: ignore[no-untyped-def]
              min_events, min_focus, min_gain, min_cond):
    """One patch's flow (px/s) from its events lo..hi, its sharpness per
    event and why it is not valid (see the module docstring): (vx, vy,
    focus, ok, longer) where ``longer``
    says a longer span may help (too few events, unfocused or no gain over
    no motion: too few events or too little motion); an aperture-limited
    patch stays so."""
    if hi - lo < min_events:
        return 0.0, 0.0, 0.0, False, True
    fx, fy, best = _maximise(xs, ys, ts, lo, hi, img, margin, max_speed, start_x, start_y, start_step, min_step,
                             half_s)
    f = best / (hi - lo)
    if f < min_focus:
        return fx, fy, f, False, True
    # the flow must sharpen the image clearly more than no motion does
    if best < min_gain * _sharpness(xs, ys, ts, lo, hi, 0.0, 0.0, img, margin, 1.0):
        return fx, fy, f, False, True
    return fx, fy, f, _isotropy(xs, ys, ts, lo, hi, fx, fy, img, margin) >= min_cond, False


@njit(cache=True, nogil=True)
def _first_span(f, fx, fy, ok, k, half_s, min_focus, min_disp):  # type: ignore[no-untyped-def]
    """The doubling ``k`` of the span (``2^k`` windows) a patch starts on in
    the next window, from a valid estimate on span ``2^k`` with sharpness per
    event ``f`` and flow (fx, fy) px/s: the shortest span predicted to pass
    the focus and displacement tests. On a focused edge the sharpness per
    event grows with the events per edge pixel, so in proportion to the span
    (less the ~0.5 that unfocused events give); the displacement also grows
    in proportion. The prediction is kept 20 % short of the thresholds, and
    an invalid estimate starts the next window on one window again."""
    if not ok:
        return 0
    d = np.hypot(fx, fy) * 2.0 * half_s
    j = k
    while j > 0:
        r = 0.5 ** (k - j + 1)  # span 2^(j-1) over 2^k
        if 0.5 + (f - 0.5) * r < 1.2 * min_focus or d * r < 1.2 * min_disp:
            break
        j -= 1
    return j


@njit(cache=True, nogil=True)
def _by_patch(t, x, y, idx, patch, npx, t_mid):  # type: ignore[no-untyped-def]
    """Events ``idx`` ordered by patch (stable): their patch ids, positions
    inside the patch (px) and times from ``t_mid`` (s), and the order."""
    n = idx.shape[0]
    pid = np.empty(n, np.int64)
    for q in range(n):
        i = idx[q]
        pid[q] = (np.int64(y[i]) // patch) * npx + np.int64(x[i]) // patch
    order = np.argsort(pid, kind="mergesort")
    xs, ys, ts, ps = np.empty(n), np.empty(n), np.empty(n), np.empty(n, np.int64)
    for q in range(n):
        i = idx[order[q]]
        xs[q] = np.int64(x[i]) % patch
        ys[q] = np.int64(y[i]) % patch
        ts[q] = (t[i] - t_mid) * 1e-6
        ps[q] = pid[order[q]]
    return ps, xs, ys, ts, idx[order]


@njit(cache=True, nogil=True, inline="always")
def _patch_end(ps, lo):  # type: ignore[no-untyped-def]
    """End of the run of events of patch ``ps[lo]`` starting at ``lo``."""
    hi = lo
    while hi < ps.shape[0] and ps[hi] == ps[lo]:
        hi += 1
    return hi


@njit(cache=True, nogil=True)
def contrast_max_window(t, x, y, t_mid, half_s, patch, max_speed, min_step, min_events, min_focus, min_gain,  # type: ignore[no-untyped-def]
                        min_cond, min_disp, prev_v, prev_ok, prev_k, need, vx, vy, valid):
    """Flow (px/s) for one window's events; ``prev_v`` (PY, PX, 2) and
    ``prev_ok`` (PY, PX) hold each patch's last result and are updated;
    ``need`` (PY, PX) is set for the patches whose estimate moves them less
    than ``min_disp`` px over the window, or is invalid for any reason but
    the aperture problem (a longer span may do better, see
    :func:`contrast_max_grow`)."""
    n = t.shape[0]
    npy, npx = prev_ok.shape
    margin = int(np.ceil(max_speed * half_s)) + 3
    img = np.zeros((patch + 2 * margin + 2, patch + 2 * margin + 2))
    ps, xs, ys, ts, src = _by_patch(t, x, y, np.arange(n), patch, npx, t_mid)
    lo = 0
    while lo < n:
        hi = _patch_end(ps, lo)
        py_, px_ = ps[lo] // npx, ps[lo] % npx
        if prev_k[py_, px_] > 0:  # predicted to fail on one window: starts on a longer span
            need[py_, px_] = True
            fx, fy, ok = 0.0, 0.0, False
        else:
            if prev_ok[py_, px_]:
                sx, sy, st = prev_v[py_, px_, 0], prev_v[py_, px_, 1], max_speed / 64.0
            else:
                sx, sy, st = 0.0, 0.0, max_speed / 2.0
            fx, fy, f, ok, longer = _estimate(xs, ys, ts, lo, hi, img, margin, max_speed, sx, sy, st, min_step,
                                              half_s, min_events, min_focus, min_gain, min_cond)
            need[py_, px_] = longer or (ok and np.hypot(fx, fy) * 2.0 * half_s < min_disp)
            prev_ok[py_, px_] = ok
            prev_k[py_, px_] = _first_span(f, fx, fy, ok, 0, half_s, min_focus, min_disp)
            prev_v[py_, px_, 0] = fx
            prev_v[py_, px_, 1] = fy
        for q in range(lo, hi):
            i = src[q]
            valid[i] = ok
            vx[i] = fx if ok else np.nan
            vy[i] = fy if ok else np.nan
        lo = hi


@njit(cache=True, nogil=True)
def contrast_max_grow(t, x, y, cur0, t_mid, half_s, patch, max_speed, min_step, min_events, min_focus, min_gain,  # type: ignore[no-untyped-def]
                      min_cond, min_disp, prev_v, prev_ok, prev_k, k, need, vx, vy, valid):
    """The patches flagged in ``need`` again, on a longer span: events
    ``t, x, y`` (time-sorted) of the span, the current window's from index
    ``cur0`` on; ``vx, vy, valid`` are the current window's outputs. A
    valid estimate replaces the earlier one (and ``prev_v``); a patch leaves
    ``need`` unless it is still too slow or too sparse to measure. The span
    is ``2^k`` windows; patches whose first span (``prev_k``) is longer wait."""
    n = t.shape[0]
    npy, npx = prev_ok.shape
    margin = int(np.ceil(max_speed * half_s)) + 3
    img = np.zeros((patch + 2 * margin + 2, patch + 2 * margin + 2))
    sel = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        py_, px_ = np.int64(y[i]) // patch, np.int64(x[i]) // patch
        if need[py_, px_] and prev_k[py_, px_] <= k:
            sel[m] = i
            m += 1
    ps, xs, ys, ts, src = _by_patch(t, x, y, sel[:m], patch, npx, t_mid)
    lo = 0
    while lo < m:
        hi = _patch_end(ps, lo)
        py_, px_ = ps[lo] // npx, ps[lo] % npx
        # from the shorter span's estimate (a valid one with a finer step)
        st = max_speed / (64.0 if prev_ok[py_, px_] else 8.0)
        sx, sy = prev_v[py_, px_, 0], prev_v[py_, px_, 1]
        fx, fy, f, ok, longer = _estimate(xs, ys, ts, lo, hi, img, margin, max_speed, sx, sy, st, min_step,
                                          half_s, min_events, min_focus, min_gain, min_cond)
        need[py_, px_] = longer
        prev_k[py_, px_] = _first_span(f, fx, fy, ok, k, half_s, min_focus, min_disp)
        prev_v[py_, px_, 0] = fx
        prev_v[py_, px_, 1] = fy
        if ok:
            need[py_, px_] = np.hypot(fx, fy) * 2.0 * half_s < min_disp
            prev_ok[py_, px_] = True
            for q in range(lo, hi):
                i = src[q]
                if i >= cur0:
                    valid[i - cur0] = True
                    vx[i - cur0] = fx
                    vy[i - cur0] = fy
        lo = hi


class ContrastMax(FlowOperator):
    """Full flow (px/s) per patch and time window by contrast maximisation.

    Output: **full flow** in ``out_vx``/``out_vy``, NaN where ``out_valid`` is
    false (too few events, unfocused, or aperture-limited). Parameters:
    ``window_us`` (µs), ``patch_px`` (px, 0 = whole sensor), ``max_speed``
    (px/s, the search range), ``min_events``, ``min_focus`` (sharpness per
    event), ``min_gain`` (over no motion), ``min_cond`` (0..1),
    ``min_disp_px`` (px) and ``max_window_us`` (µs, a multiple of
    ``window_us``; = ``window_us`` for fixed windows): the adaptive span of
    slow patches. Emits each window when the watermark passes its end:
    latency up to one window. State: the events of the last
    ``max_window_us`` µs.
    """

    name = "flow.contrast_max"
    flow_type = "full"

    def __init__(self, window_us: int = 10_000, patch_px: int = 32, max_speed: float = 2000.0,
                 min_events: int = 40, min_focus: float = 1.3, min_gain: float = 1.2, min_cond: float = 0.15,
                 min_disp_px: float = 2.0, max_window_us: int = 80_000,
                 out_vx: str = "vx", out_vy: str = "vy", out_valid: str = "valid") -> None:
        if window_us <= 0 or patch_px < 0 or max_speed <= 0 or min_events < 1 or min_cond < 0:
            raise ValueError("need window_us > 0, patch_px >= 0, max_speed > 0, min_events >= 1, min_cond >= 0")
        if max_window_us < window_us or max_window_us % window_us or min_disp_px < 0:
            raise ValueError("need max_window_us a multiple of window_us (>= it) and min_disp_px >= 0")
        self.window_us, self.patch_px, self.max_speed = int(window_us), int(patch_px), float(max_speed)
        self.min_events, self.min_focus, self.min_cond = int(min_events), float(min_focus), float(min_cond)
        self.min_gain, self.min_disp, self.max_window = float(min_gain), float(min_disp_px), int(max_window_us)
        self._set_outputs(out_vx, out_vy, out_valid)
        self._pending: list[EventPacket] = []
        self._history: list[EventPacket] = []  # earlier whole windows, oldest first
        self._win: int | None = None  # start of the open window, µs
        self._prev_v: np.ndarray | None = None
        self._sensor = (0, 0)  # (width, height) px of the stream (the patch grid's)

    def _patch(self, sensor: tuple[int, int]) -> int:
        return self.patch_px or max(sensor)

    def _params(self, span_us: int) -> tuple[float, float, float]:
        """(half span in s, speed range px/s, smallest step px/s) of a span:
        the same range of displacements, down to 0.05 px at its ends."""
        half_s = 0.5e-6 * span_us
        return half_s, self.max_speed * self.window_us / span_us, 0.05 / half_s

    def _run_window(self, pkt: EventPacket, t0: int) -> EventPacket:
        w, h = pkt.sensor
        patch = self._patch(pkt.sensor)
        if self._prev_v is None:
            self._prev_v = np.zeros((-(-h // patch), -(-w // patch), 2))
            self._prev_ok = np.zeros((-(-h // patch), -(-w // patch)), np.bool_)
            self._prev_k = np.zeros((-(-h // patch), -(-w // patch)), np.int64)
        vx, vy, valid = self._alloc(len(pkt))
        end = t0 + self.window_us
        keep = self.max_window - self.window_us
        self._history = [q for q in self._history if q.t_end > end - keep - self.window_us]
        if len(pkt):
            need = np.zeros(self._prev_ok.shape, np.bool_)
            half_s, vmax, step = self._params(self.window_us)
            contrast_max_window(pkt.t, pkt.x, pkt.y, end - self.window_us // 2, half_s, patch, vmax, step,
                                self.min_events, self.min_focus, self.min_gain, self.min_cond, self.min_disp,
                                self._prev_v, self._prev_ok, self._prev_k, need, vx, vy, valid)
            span, k = 2 * self.window_us, 1
            while need.any() and span <= self.max_window:
                past = [q.slice_time(end - span, None) for q in self._history if q.t_end > end - span]
                both = concat([*past, pkt]) if past else pkt
                half_s, vmax, step = self._params(span)
                contrast_max_grow(both.t, both.x, both.y, len(both) - len(pkt), end - span // 2, half_s, patch,
                                  vmax, step, self.min_events, self.min_focus, self.min_gain, self.min_cond,
                                  self.min_disp, self._prev_v, self._prev_ok, self._prev_k, k, need, vx, vy, valid)
                span, k = 2 * span, k + 1
        if keep:
            self._history.append(pkt)
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
            out.append(self._run_window(head, self._win))
            self._win = end
        self._pending = [buf] if len(buf) else []
        return out

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self._win is None:
            self._win = (packet.t_start // self.window_us) * self.window_us
            self._sensor = packet.sensor
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        if len(packet):
            self._pending.append(packet)
        return self._flush(packet.t_end)

    def finish(self) -> list[EventPacket]:
        return self._flush(None)
