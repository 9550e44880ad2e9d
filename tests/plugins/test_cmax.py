"""The shared contrast-maximisation core (tectum.plugins._cmax): the IWE and
its focus against an image built the obvious way, analytic gradients against
finite differences, the first-order rotational warp against the exact
rotation, and BFGS finding a known rotation."""

from __future__ import annotations

import numpy as np
import pytest

from tectum.camera import so3_exp
from tectum.plugins._cmax import focus, focus_grad, iwe, maximise_rotation, rotation_focus_grad, rotation_warp


def _image(u, v, shape):
    """The IWE written out: each point's 3 x 3 quadratic B-spline votes."""
    img = np.zeros(shape)
    for a, b in zip(u, v):
        ix, iy = int(np.floor(a + 0.5)), int(np.floor(b + 0.5))
        if not (1 <= ix < shape[1] - 1 and 1 <= iy < shape[0] - 1):
            continue
        wx, wy = ([0.5 * (0.5 - d) ** 2, 0.75 - d * d, 0.5 * (0.5 + d) ** 2] for d in (a - ix, b - iy))
        for i in range(3):
            for j in range(3):
                img[iy - 1 + i, ix - 1 + j] += wy[i] * wx[j]
    return img


def _points(n=400, seed=3, shape=(30, 40)):
    rng = np.random.default_rng(seed)
    # clustered (many votes on the same pixels) and a few off the image
    u = rng.integers(0, 8, n) * 4.0 + rng.normal(0, 0.3, n) + 2.0
    v = rng.uniform(-2.0, shape[0] + 2.0, n)
    return u, v


def test_iwe_and_focus_match_the_image_written_out():
    u, v = _points()
    ref = _image(u, v, (30, 40))
    img = np.zeros((30, 40))
    voted = iwe(u, v, img)
    np.testing.assert_allclose(img, ref, atol=1e-12)
    assert voted == sum(1 <= np.floor(a + 0.5) < 39 and 1 <= np.floor(b + 0.5) < 29 for a, b in zip(u, v))
    img[:] = 0
    assert focus(u, v, img) == pytest.approx(float((ref ** 2).sum()), rel=1e-10)
    assert not img.any()
    gu, gv = np.empty(len(u)), np.empty(len(u))
    assert focus_grad(u, v, img, gu, gv) == pytest.approx(float((ref ** 2).sum()), rel=1e-10)
    assert not img.any()


def test_focus_gradient_matches_finite_differences():
    u, v = _points(n=150)
    img = np.zeros((30, 40))
    gu, gv = np.empty(len(u)), np.empty(len(u))
    focus_grad(u, v, img, gu, gv)
    h = 1e-6
    for k in range(0, 150, 7):
        for arr, g in ((u, gu), (v, gv)):
            a = arr[k]
            arr[k] = a + h
            fp = focus(u, v, img)
            arr[k] = a - h
            fm = focus(u, v, img)
            arr[k] = a
            assert g[k] == pytest.approx((fp - fm) / (2 * h), rel=1e-5, abs=1e-6)


def _rays(n=300, seed=1):
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-0.5, 0.5, n), rng.uniform(-0.4, 0.4, n)
    dt = rng.uniform(-0.004, 0.004, n)
    return x, y, dt


CAM = np.array([100.0, 100.0, 60.0, 45.0])


def test_rotation_warp_is_the_first_order_rotation():
    x, y, dt = _rays()
    w = np.array([1.5, -3.0, 2.0])
    u, v = np.empty(len(x)), np.empty(len(x))
    rotation_warp(x, y, dt, w, CAM, u, v)
    b = np.stack([x, y, np.ones_like(x)], axis=1)
    first = b + dt[:, None] * np.cross(w, b)  # b' = b + dt ω x b
    np.testing.assert_allclose(u, CAM[0] * first[:, 0] / first[:, 2] + CAM[2], atol=1e-9)
    np.testing.assert_allclose(v, CAM[1] * first[:, 1] / first[:, 2] + CAM[3], atol=1e-9)
    # and close to the exact rotation exp([ω dt]x) b: second order in |ω dt| (here <= 0.017 rad)
    exact = np.einsum("nij,nj->ni", so3_exp(w[None] * dt[:, None]), b)
    ue = CAM[0] * exact[:, 0] / exact[:, 2] + CAM[2]
    assert np.abs(u - ue).max() < 100 * 0.5 * (np.linalg.norm(w) * 0.004) ** 2 * 2


def _region_variance(img, rect):
    """The focus written out: Σ_R I^2 - (Σ_R I)^2 / |R| over the rectangle R."""
    c0, c1, r0, r1 = (int(a) for a in rect)
    part = img[r0:r1 + 1, c0:c1 + 1]
    return float((part ** 2).sum() - part.sum() ** 2 / part.size)


#: a focus region that cuts through the warped points (many straddle its edges)
RECT = np.array([20.0, 105.0, 12.0, 80.0])


@pytest.mark.parametrize("rect", [RECT, np.array([0.0, 129.0, 0.0, 99.0])])
def test_rotation_focus_and_gradient(rect):
    x, y, dt = _rays()
    w = np.array([2.0, -1.0, 3.0])
    img = np.zeros((100, 130))
    u, v, g = np.empty(len(x)), np.empty(len(x)), np.empty(3)
    f, m = rotation_focus_grad(x, y, dt, w, CAM, img, u, v, g, rect)
    assert not img.any()
    uu, vv = np.empty(len(x)), np.empty(len(x))
    rotation_warp(x, y, dt, w, CAM, uu, vv)
    assert f == pytest.approx(_region_variance(_image(uu, vv, img.shape), rect), rel=1e-9)
    assert m == len(x)
    h = 1e-5
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        fp, _ = rotation_focus_grad(x, y, dt, w + e, CAM, img, u, v, np.empty(3), rect)
        fm, _ = rotation_focus_grad(x, y, dt, w - e, CAM, img, u, v, np.empty(3), rect)
        assert g[j] == pytest.approx((fp - fm) / (2 * h), rel=1e-4)


def test_bfgs_finds_a_known_rotation():
    rng = np.random.default_rng(5)
    w_true = np.array([1.0, -2.0, 4.0])
    pts = np.stack([rng.uniform(-0.5, 0.5, 40), rng.uniform(-0.4, 0.4, 40), np.ones(40)], axis=1)
    dt = np.repeat(np.linspace(-0.005, 0.005, 60), 40)
    # the point seen at dt is exp(-[ω dt]x) of where it is at the reference time
    b = np.einsum("nji,nj->ni", so3_exp(w_true[None] * dt[:, None]), np.tile(pts, (60, 1)))
    x, y = b[:, 0] / b[:, 2], b[:, 1] / b[:, 2]
    x, y = np.round(x * 100) / 100, np.round(y * 100) / 100  # pixel quantised
    img = np.zeros((100, 130))
    u, v = np.empty(len(x)), np.empty(len(x))
    H = np.zeros((3, 3))
    w, f, m, evals = maximise_rotation(x, y, dt, np.array([0.8, -1.6, 3.5]), H, CAM, img, u, v, 40, 1e-4,
                                       np.array([5.0, 124.0, 5.0, 94.0]))
    np.testing.assert_allclose(w, w_true, atol=0.03 * 4.0)
    assert H[0, 0] > 0 and evals < 60
