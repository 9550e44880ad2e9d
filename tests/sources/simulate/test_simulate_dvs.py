"""The DVS kernel against a slow reference, and the log-intensity ramp."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tectum.sources.simulate import simulate
from tectum.sources.simulate.dvs import dvs_step, lowpass_step


def reference_step(L0, L1, t0, t1, l_ref, t_rel, c_on, c_off, refr):
    """Plain per-pixel loop: linear L in time, crossings at L_ref ± C."""
    out = []
    for i in range(len(L0)):
        a, b = L0[i], L1[i]

        def level(t, a=a, b=b):
            return a + (b - a) * (t - t0) / (t1 - t0)

        if t_rel[i] > t1:
            continue
        s = t0
        if t_rel[i] > t0:
            l_ref[i] = level(t_rel[i])
            s = t_rel[i]
        while True:
            if b - l_ref[i] >= c_on[i]:
                target, pol = l_ref[i] + c_on[i], 1
            elif l_ref[i] - b >= c_off[i]:
                target, pol = l_ref[i] - c_off[i], -1
            else:
                break
            tc = t0 + (target - a) * (t1 - t0) / (b - a) if b != a else s
            tc = min(max(tc, s), t1)
            out.append((tc, i, pol))
            l_ref[i] = target
            t_rel[i] = tc + refr
            if refr > 0:
                if t_rel[i] > t1:
                    break
                l_ref[i] = level(t_rel[i])
                s = t_rel[i]
    return out


@pytest.mark.parametrize("refr", [0.0, 30.0])
def test_kernel_matches_reference(refr):
    rng = np.random.default_rng(3)
    n = 200
    L = rng.normal(0, 0.3, n)
    c_on = rng.uniform(0.1, 0.3, n)
    c_off = rng.uniform(0.1, 0.3, n)
    st_k = [L.copy(), np.full(n, -np.inf)]
    st_r = [L.copy(), np.full(n, -np.inf)]
    ot, oi, op = np.empty(64), np.empty(64, np.int64), np.empty(64, np.int8)  # small: forces resumes
    t = 0.0
    for _ in range(30):
        L1 = L + rng.normal(0, 0.4, n)
        dt = rng.uniform(5, 100)
        got, start = [], 0
        while start < n:
            k, start = dvs_step(L, L1, t, t + dt, st_k[0], st_k[1], c_on, c_off, refr, start, ot, oi, op)
            got += list(zip(ot[:k], oi[:k], op[:k]))
        want = reference_step(L, L1, t, t + dt, st_r[0], st_r[1], c_on, c_off, refr)
        assert len(got) == len(want)
        for (ta, ia, pa), (tb, ib, pb) in zip(got, want):
            assert ia == ib and pa == pb and ta == pytest.approx(tb, abs=1e-9)
        np.testing.assert_allclose(st_k[0], st_r[0], atol=1e-12)
        L, t = L1, t + dt


def test_lowpass_converges_and_slows_in_the_dark():
    s = np.array([0.0, 0.0])
    lowpass_step(s, np.array([1.0, 0.01]), 1e-3, 300.0, 1.0)
    # one time constant at full scale is 1/(2 pi 300) s = 0.53 ms: most of the way after 1 ms
    assert s[0] == pytest.approx(1 - math.exp(-2 * math.pi * 300 * 1e-3))
    assert s[1] / 0.01 < 0.1  # 3 Hz cut-off in the dark: barely moved


@pytest.mark.parametrize("slope", [3.0, -2.5])
def test_ramp_gives_floor_dl_over_c_events_at_analytic_times(slope):
    i0, c, eps, T = 0.3, 0.2, 1e-3, 600_000
    scene = {"sensor": [6, 4], "background": {"intensity": i0, "log_slope": slope}}
    ev, _ = simulate(scene, T, preset="ideal", c_on=c, c_off=c)

    def level(t_s):
        return math.log(i0 * math.exp(slope * t_s) + eps)

    dl = level(T * 1e-6) - level(0.0)
    n = math.floor(abs(dl) / c)
    pol = 1 if slope > 0 else -1
    # analytic crossing times: level(t_k) = level(0) + k C pol
    t_k = [math.log((math.exp(level(0.0) + pol * k * c) - eps) / i0) / slope * 1e6 for k in range(1, n + 1)]
    assert len(ev) == n * 24
    assert np.all(ev.p == pol) and np.all(ev["noise"] == 0)
    for pix in range(24):
        mine = ev.t[(ev.y.astype(int) * 6 + ev.x) == pix]
        assert len(mine) == n
        np.testing.assert_allclose(mine, np.floor(t_k), atol=2)
