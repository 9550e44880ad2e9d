"""The filter kernels mean the same run as plain Python as compiled.

numba's arithmetic is not numpy's: ``np.bool_ + np.bool_`` is a logical or
in numpy and an integer sum in numba, so a kernel can count right compiled
and wrong as Python. ``NUMBA_DISABLE_JIT=1`` (the decoder coverage and the
mutation run, README "Development") runs the Python form, so both must agree.
Each operator is fed the same stream twice, with its kernels compiled and
with their ``py_func``, and the outputs compared event by event (with the
JIT disabled both runs are Python and the test only checks the filters run).
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from tectum.plugins.filter import BackgroundActivity, HotPixel, RateLimit, Refractory, SpatioTemporalCorrelation
from tectum.testing import feed

CASES = {
    "stcf k=2": (lambda: SpatioTemporalCorrelation(dt_us=3000, k=2), ["stcf.stcf_kernel"]),
    "stcf k=3 polarity": (lambda: SpatioTemporalCorrelation(dt_us=5000, k=3, polarity=True), ["stcf.stcf_kernel"]),
    "background activity": (lambda: BackgroundActivity(dt_us=2000), ["background_activity.background_activity_select"]),
    "refractory": (lambda: Refractory(period_us=4000), ["refractory.refractory_kernel"]),
    "hot pixel": (lambda: HotPixel(learn_us=20_000, factor=1.5, min_events=2, learning="drop"),
                  ["hot_pixel.count_kernel", "hot_pixel.mask_kernel"]),
    "rate limit": (lambda: RateLimit(rate_hz=20_000, burst=30), ["rate_limit.token_bucket_kernel"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_python_form_equals_compiled(case, make_pattern, monkeypatch):  # type: ignore[no-untyped-def]
    make, kernels = CASES[case]
    ev = make_pattern(noise_hz=400.0)
    pieces = [ev.slice_time(a, a + 7_000) for a in range(ev.t_start, ev.t_end, 7_000)]
    compiled = feed(make(), pieces)
    for name in kernels + ["_state.compact_kernel"]:
        mod, fn = name.split(".")
        module = importlib.import_module(f"tectum.plugins.filter.{mod}")
        kernel = getattr(module, fn)
        monkeypatch.setattr(module, fn, getattr(kernel, "py_func", kernel))  # a function already without the JIT
    python = feed(make(), pieces)
    a, b = np.concatenate([q.t for q in compiled]), np.concatenate([q.t for q in python])
    assert 0 < len(a) < len(ev)  # the filter keeps some and drops some
    assert np.array_equal(a, b)
    for col in ("x", "y", "p"):
        assert np.array_equal(np.concatenate([getattr(q, col) for q in compiled]),
                              np.concatenate([getattr(q, col) for q in python])), col
