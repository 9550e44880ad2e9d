import numpy as np
import pytest

from tectum import EventPacket
from tectum.evaluation.metrics import binomial_pass, denoise_rates, roc_auc


def test_denoise_rates():
    n = 6
    ev = EventPacket.from_arrays(np.arange(n), np.zeros(n), np.zeros(n), np.ones(n), sensor=(4, 4),
                                 columns={"noise": np.array([0, 0, 0, 1, 1, 0], np.uint8)})
    tpr, fpr = denoise_rates(ev, np.array([1, 1, 0, 1, 0, 1], bool))
    assert (tpr, fpr) == (0.75, 0.5)
    with pytest.raises(ValueError, match="noise"):
        denoise_rates(ev.without_columns("noise"), np.ones(n, bool))


def test_roc_auc():
    assert roc_auc([]) == pytest.approx(0.5)
    assert roc_auc([(1.0, 0.0)]) == pytest.approx(1.0)
    assert roc_auc([(0.8, 0.2)]) == pytest.approx(0.5 * 0.2 * 0.8 + 0.8 * 0.8 + 0.5 * 0.8 * 0.2)


def test_binomial_pass():
    q = 1 - np.exp(-0.2)
    assert binomial_pass(20.0, 10_000, 1) == pytest.approx(1 - (1 - q) ** 8)
    assert binomial_pass(20.0, 10_000, 8) == pytest.approx(q**8)
