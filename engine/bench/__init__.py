"""The benchmark harness behind ``tectum bench``.

One module per suite (``engine``, ``io``, ``filters``, ``flow``,
``simulate``, ``net``); each defines ``run(out: Path, quick: bool) -> dict``
which measures, prints a table and returns the numbers (written to
``OUT/bench-SUITE.json`` by the CLI). Peers (dv-processing, tonic, faery,
evlib) are measured side by side where they import. Benchmarks are never
part of the test suite: tests do not depend on wall-clock speed.
"""

from __future__ import annotations

import importlib
import json
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["SUITES", "throughput", "peer", "write_results", "table"]

SUITES = ("engine", "io", "filters", "flow", "simulate", "net")


def available_suites() -> list[str]:
    out = []
    for s in SUITES:
        try:
            importlib.import_module(f"tectum.bench.{s}")
        except ModuleNotFoundError as e:
            if e.name != f"tectum.bench.{s}":
                raise
            continue
        out.append(s)
    return out


def throughput(fn: Callable[[], Any], n_events: int, *, repeat: int = 5, warmup: int = 1) -> dict[str, float]:
    """Run ``fn`` (which processes ``n_events`` events) ``repeat`` times after
    ``warmup`` calls; returns the best and median Mev/s and seconds (wall
    clock), and the best Mev/s per CPU second (all threads of the process)."""
    for _ in range(warmup):
        fn()
    times, cpu = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    best, med = min(times), float(np.median(times))
    return {"mev_s": n_events / best / 1e6, "mev_s_median": n_events / med / 1e6, "seconds": best,
            "cpu_mev_s": n_events / max(min(cpu), 1e-9) / 1e6, "events": n_events}


def peer(module: str) -> Any | None:
    """Import a peer library, or None when it is not installed."""
    try:
        return importlib.import_module(module)
    except Exception:
        return None


def table(rows: list[dict[str, Any]], cols: list[str]) -> str:
    """Format rows as a fixed-width text table."""
    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"
        return str(v)

    cells = [[fmt(r.get(c, "")) for c in cols] for r in rows]
    widths = [max(len(c), *(len(x[i]) for x in cells)) if cells else len(c) for i, c in enumerate(cols)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(cols, widths))]
    lines += ["  ".join(x.ljust(w) for x, w in zip(r, widths)) for r in cells]
    return "\n".join(lines)


def write_results(out: Path, suite: str, results: dict[str, Any]) -> Path:
    """Write ``results`` with the machine's description to ``out/bench-SUITE.json``."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"bench-{suite}.json"
    meta = {"python": platform.python_version(), "machine": platform.machine(), "processor": platform.processor(),
            "numpy": np.__version__, "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
    path.write_text(json.dumps({"suite": suite, "meta": meta, "results": results}, indent=1, default=float))
    return path
