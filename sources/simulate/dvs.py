"""The DVS pixel model as numba kernels (pure functions on arrays).

Each pixel keeps a reference log intensity ``L_ref`` and fires an ON event
when ``L - L_ref >= C_on`` or an OFF event when ``L_ref - L >= C_off``, after
which ``L_ref`` moves by ``+C_on`` / ``-C_off``. Between two samples at
``t0`` and ``t1`` (µs) the log intensity is taken as linear in time, so one
step can give several events per pixel, each at its linearly interpolated
crossing time.

Refractory period: after an event at ``tc`` a pixel is held in reset until
``tc + refractory_us`` and then memorises the level at that moment
(``L_ref = L(tc + refractory_us)``), as a real pixel's reset switch does.
With a zero period this is the plain ``L_ref += C`` rule.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["dvs_step", "fire", "need_events", "quiet", "lowpass1", "lowpass_step", "log_intensity"]


@njit(cache=True)
def need_events(i: int, a: float, b: float, ta: float, tb: float, l_ref: np.ndarray, t_release: np.ndarray,
                c_on: np.ndarray, c_off: np.ndarray) -> int:
    """An upper bound on the events :func:`fire` gives pixel ``i`` for the
    segment ``(ta, tb]`` from level ``a`` to ``b`` (state unchanged)."""
    tr = t_release[i]
    if tr > tb:
        return 0
    ref = l_ref[i]
    if tr > ta:
        ref = a + (b - a) / (tb - ta) * (tr - ta)
    d = b - ref
    if d >= c_on[i]:
        return int(d / c_on[i]) + 1
    if -d >= c_off[i]:
        return int(-d / c_off[i]) + 1
    return 0


@njit(cache=True)
def fire(i: int, a: float, b: float, ta: float, tb: float, l_ref: np.ndarray, t_release: np.ndarray,
         c_on: np.ndarray, c_off: np.ndarray, refractory_us: float, out_t: np.ndarray, out_i: np.ndarray,
         out_p: np.ndarray, n: int) -> int:
    """Events of pixel ``i`` while its log intensity goes linearly from
    ``a`` at ``ta`` to ``b`` at ``tb`` (µs); appends them at ``n`` (room
    must be there: see :func:`need_events`), updates ``l_ref`` and
    ``t_release``; returns the new count."""
    tr = t_release[i]
    if tr > tb:
        return n
    slope = (b - a) / (tb - ta)
    s = ta
    if tr > ta:  # the hold ends inside this segment: memorise the level then
        l_ref[i] = a + slope * (tr - ta)
        s = tr
    ref = l_ref[i]
    while True:
        d = b - ref
        if d >= c_on[i]:
            target = ref + c_on[i]
            pol = 1
        elif -d >= c_off[i]:
            target = ref - c_off[i]
            pol = -1
        else:
            break
        if slope != 0.0:
            tc = ta + (target - a) / slope
        else:
            tc = s
        if tc < s:
            tc = s
        if tc > tb:
            tc = tb
        out_t[n] = tc
        out_i[n] = i
        out_p[n] = pol
        n += 1
        ref = target
        if refractory_us > 0.0:
            tr = tc + refractory_us
            t_release[i] = tr
            if tr > tb:
                break
            ref = a + slope * (tr - ta)
            s = tr
        else:
            t_release[i] = tc
    l_ref[i] = ref
    return n


@njit(cache=True, inline="always")
def quiet(i: int, b: float, ta: float, tb: float, l_ref: np.ndarray, t_release: np.ndarray, c_on: np.ndarray,
          c_off: np.ndarray) -> bool:
    """True when pixel ``i`` surely fires nothing in ``(ta, tb]`` ending at
    level ``b`` (the common case, decided without touching its state)."""
    tr = t_release[i]
    if tr <= ta:
        d = b - l_ref[i]
        return d < c_on[i] and -d < c_off[i]
    return tr > tb


@njit(cache=True)
def dvs_step(L0: np.ndarray, L1: np.ndarray, t0: float, t1: float, l_ref: np.ndarray,
             t_release: np.ndarray, c_on: np.ndarray, c_off: np.ndarray, refractory_us: float,
             start: int, out_t: np.ndarray, out_i: np.ndarray, out_p: np.ndarray) -> tuple[int, int]:
    """Events of one step ``(t0, t1]`` µs for pixels ``start ..`` (flat index).

    ``L0``/``L1`` are the log intensities at ``t0``/``t1``; ``l_ref`` and
    ``t_release`` (µs, end of each pixel's refractory hold) are updated in
    place. Writes crossing times (float µs), pixel indices and polarities
    (+1/-1) into the output arrays; returns ``(n_written, next_pixel)``:
    ``next_pixel < L0.size`` means the output was full and the call must be
    repeated from that pixel with room.
    """
    n = 0
    cap = out_t.shape[0]
    npx = L0.shape[0]
    for i in range(start, npx):
        b = L1[i]
        if quiet(i, b, t0, t1, l_ref, t_release, c_on, c_off):
            continue
        a = L0[i]
        if n + need_events(i, a, b, t0, t1, l_ref, t_release, c_on, c_off) > cap:
            return n, i
        n = fire(i, a, b, t0, t1, l_ref, t_release, c_on, c_off, refractory_us, out_t, out_i, out_p, n)
    return n, npx


@njit(cache=True, inline="always")
def lowpass1(state: float, target: float, dt_s: float, f3db_hz: float, f_min_hz: float) -> float:
    """One exact step of the photoreceptor low-pass (see :func:`lowpass_step`)."""
    fc = f3db_hz * max(target, 0.0)
    if fc < f_min_hz:
        fc = f_min_hz
    return state + (1.0 - math.exp(-2.0 * math.pi * fc * dt_s)) * (target - state)


@njit(cache=True)
def lowpass_step(state: np.ndarray, target: np.ndarray, dt_s: float, f3db_hz: float,
                 f_min_hz: float) -> None:
    """First-order photoreceptor low-pass on linear intensity, in place.

    The cut-off is ``f3db_hz * I`` (the bandwidth falls in the dark, ``I`` in
    units of full scale), at least ``f_min_hz``; the input is held constant
    over the step, so the update is exact and stable for any ``dt_s``."""
    for i in range(state.shape[0]):
        state[i] = lowpass1(state[i], target[i], dt_s, f3db_hz, f_min_hz)


@njit(cache=True)
def log_intensity(intensity: np.ndarray, eps: float, out: np.ndarray, previous: np.ndarray) -> float:
    """``out = log(max(intensity, 0) + eps)`` element by element; returns
    ``max |out - previous|`` (the largest change since the last sample)."""
    worst = 0.0
    for i in range(intensity.shape[0]):
        v = math.log(max(intensity[i], 0.0) + eps)
        out[i] = v
        d = abs(v - previous[i])
        if d > worst:
            worst = d
    return worst
