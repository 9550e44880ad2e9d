"""``tectum.evaluation``: everything that scores or times tectum, apart from
the runtime code (the engine imports none of it).

* :mod:`.metrics`: flow and lifetime errors against ground truth, denoising
  rates and ROC AUC.
* :mod:`.scenes`: analytic scenes with exact flow (translating edges).
* :mod:`.imu_truth`: flow ground truth from a gyro under pure rotation.
* :mod:`.harness` and :mod:`.suites`: the benchmark suites of ``tectum
  bench``, registered by :mod:`.plugin` through the
  ``tectum_register_bench_suites`` hook like any third-party suite.
"""

from __future__ import annotations

from .metrics import (
    binomial_pass,
    denoise_rates,
    flow_errors,
    lifetime_errors,
    noise_passed_by_label,
    roc_auc,
    rotational_flow,
    simulator_normal_truth,
)
from .scenes import translating_edges

__all__ = [
    "flow_errors", "lifetime_errors", "rotational_flow", "simulator_normal_truth",
    "denoise_rates", "noise_passed_by_label", "roc_auc", "binomial_pass", "translating_edges",
]
