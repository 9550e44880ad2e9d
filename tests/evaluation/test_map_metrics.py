import numpy as np
import pytest

from tectum.evaluation.metrics.maps import depth_scores, intensity_scores, pearson, ssim


def test_intensity_scores_are_affine_invariant_where_they_should_be():
    t = np.random.default_rng(0).normal(size=(40, 50))
    s = intensity_scores(2 * t + 1, t)
    assert s["pearson"] == pytest.approx(1.0)
    assert s["ssim"] == pytest.approx(1.0)
    assert s["mse_affine"] == pytest.approx(0.0, abs=1e-20)
    assert s["mse"] == pytest.approx(np.mean((t + 1) ** 2))
    assert s["coverage"] == 1.0


def test_ssim_drops_with_noise_and_ignores_invalid_pixels():
    rng = np.random.default_rng(1)
    t = rng.normal(size=(60, 60))
    noisy = t + rng.normal(scale=1.0, size=t.shape)
    assert ssim(noisy, t) < 0.8 < ssim(t + 0.05 * rng.normal(size=t.shape), t)
    half = t.copy()
    half[:, :30] = np.nan
    assert intensity_scores(half, t)["coverage"] == pytest.approx(0.5)
    assert pearson(half, t) == pytest.approx(1.0)


def test_depth_scores_on_a_known_error():
    truth = np.full((10, 10), 2.0)
    est = np.full((10, 10), np.nan)
    est[:5] = 2.2  # 10 % too far on half the pixels
    s = depth_scores(est, truth)
    assert s["abs_rel"] == pytest.approx(0.1)
    assert s["median_abs_rel"] == pytest.approx(0.1)
    assert s["delta_1_25"] == 1.0
    assert s["density"] == pytest.approx(0.5)
    assert s["log_rmse"] == pytest.approx(np.log(1.1))
