"""The built-in suites of ``tectum bench`` as a plugin (entry point
``evaluation``), registered like any third-party suite. Each suite module is
imported only when the suite runs: building the registry stays cheap."""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tectum.hookspecs import hookimpl

if TYPE_CHECKING:
    from tectum._registry import RegistryView

__all__ = ["SUITES"]

#: suite -> the line ``tectum bench --list`` shows
SUITES = {
    "engine": "scheduler overhead per packet and operator, event-by-event and micro-batch rates, paced latency, "
              "port joins",
    "io": "decode and encode Mev/s per file format, beside dv-processing, expelliarmus, faery, numpy.loadtxt",
    "filters": "filter and representation speed beside peers; denoising ROC and AUC on labelled noise",
    "flow": "flow and lifetime speed and accuracy (analytic edges, simulator, gyro truth), failure maps",
    "map": "map reconstruction, panoramic mosaic and EMVS depth: speed, and accuracy against simulator truth "
           "(Pearson/SSIM, AbsRel), failure maps",
    "tracker": "angular velocity and ego-motion: speed, latency, RMS error against simulator truth and IMU, "
               "the model ladder's confusion matrix",
    "pose": "6-DoF tracking against a known photometric map: ATE, RPE, position RMSE as % of path, rotation "
            "median against simulator truth and slider_depth, events/s and pose updates/s; failure maps",
    "calibrate": "tectum calibrate against a simulated blinking board: focal, principal point, k1 and RMS errors "
                 "with noise and flicker; failure map (noise, views, tilt, blink frequency vs jitter)",
    "simulate": "simulator generation speed (Mev/s at 346x260)",
    "net": "TCP rate and UDP loss and latency on loopback",
    "scale": "time shards and many recordings on Dask and a process pool: speed-up against one run, warm-up "
             "overlap, seek cost per format",
}


def _lazy(suite: str) -> Callable[[Path, bool], dict[str, Any]]:
    """The suite's ``run``, importing ``tectum.evaluation.suites.SUITE`` on the first call."""
    module = f"tectum.evaluation.suites.{suite}"

    def run(out: Path, quick: bool) -> dict[str, Any]:
        result: dict[str, Any] = importlib.import_module(module).run(out, quick)
        return result

    run.__module__, run.__qualname__ = module, "run"  # messages name the function that really runs
    return run


@hookimpl
def tectum_register_bench_suites(registry: RegistryView) -> None:
    for name, description in SUITES.items():
        registry.add_bench_suite(name, _lazy(name), description)
