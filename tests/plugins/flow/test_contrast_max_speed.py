"""contrast_max's fast sharpness (summed while voting) against the obvious
image-then-sum-of-squares reference, and the image left cleared."""

from __future__ import annotations

import numpy as np
import pytest

from tectum.plugins.flow.contrast_max import _sharpness


def _reference(xs, ys, ts, vx, vy, shape, margin, scale):
    img = np.zeros(shape)
    for x, y, t in zip(xs, ys, ts):
        wx, wy = (x - vx * t + margin) / scale, (y - vy * t + margin) / scale
        ix, iy = int(np.floor(wx + 0.5)), int(np.floor(wy + 0.5))
        if not (1 <= ix < shape[1] - 1 and 1 <= iy < shape[0] - 1):
            continue
        wgt = []
        for d in (wx - ix, wy - iy):
            wgt.append([0.5 * (0.5 - d) ** 2, 0.75 - d * d, 0.5 * (0.5 + d) ** 2])
        for i in range(3):
            for j in range(3):
                img[iy - 1 + i, ix - 1 + j] += wgt[1][i] * wgt[0][j]
    return float((img ** 2).sum())


@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_sharpness_matches_the_image_sum_of_squares(scale):
    rng = np.random.default_rng(7)
    n = 150
    # clustered on a few pixels (edges): many votes land on the same pixels
    xs = rng.integers(0, 8, n).astype(float) * 4
    ys = rng.integers(0, 32, n).astype(float)
    ts = rng.uniform(-0.005, 0.005, n)
    img = np.zeros((50, 50))
    for vx, vy in ((0.0, 0.0), (730.0, -410.0), (-6000.0, 5000.0)):  # the last pushes some off the image
        got = _sharpness(xs, ys, ts, 0, n, vx, vy, img, 9, scale)
        want = _reference(xs, ys, ts, vx, vy, img.shape, 9, scale)
        assert got == pytest.approx(want, rel=1e-9)
        assert not img.any()
