"""The benchmark harness shared by the suites of ``tectum bench``.

A suite is a function ``run(out: Path, quick: bool) -> dict`` registered
through the ``tectum_register_bench_suites`` hook (the six built-in ones in
:mod:`tectum.evaluation.suites`): it measures, prints its tables and returns
the numbers, which the CLI writes to ``OUT/bench-SUITE.json``. A suite that
states a target (say 200k events/s) records it with :func:`target`, shows it
with :func:`target_row` / :func:`targets_table` (``met`` or ``MISSED``) and
returns the records under ``"targets"``. Peers (dv-processing, tonic, faery,
evlib) are measured side by side where they import. Benchmarks are never
part of the test suite: tests do not depend on wall-clock speed.
"""

from __future__ import annotations

import importlib
import json
import math
import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["throughput", "interleaved", "versus", "peer", "fmt", "table", "target", "target_row", "targets_table",
           "write_results", "shared_data", "memory_bandwidth"]

#: columns of :func:`targets_table`
TARGET_COLUMNS = ["measure", "value", "unit", "target", "met"]


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


def interleaved(fns: dict[str, Callable[[], Any]], n_events: dict[str, int] | int, *, repeat: int = 5,
                warmup: int = 1, shuffle: bool = False) -> dict[str, dict[str, Any]]:
    """Run every function of ``fns`` in turn, ``repeat`` rounds (a, b, a, b,
    ...), after ``warmup`` rounds, so load from other processes falls on
    all of them alike. Per function: the median and the spread (min, max)
    of Mev/s by the wall clock and per CPU second of this process (all its
    threads), and the per-round times (s) that :func:`versus` pairs up.
    ``n_events``: events each function processes (one number for all).
    ``shuffle``: each round in its own order (seeded, so runs repeat), so
    no function always runs just after the same one: what one leaves in the
    caches (a file it read, memory it dirtied) falls on all of them alike."""
    counts = {k: n_events if isinstance(n_events, int) else n_events[k] for k in fns}
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    rng = np.random.default_rng(0)
    for _ in range(repeat):
        for k in (rng.permutation(list(fns)).tolist() if shuffle else list(fns)):
            fn = fns[k]
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(max(time.process_time() - c0, 1e-9))
    out = {}
    for k in fns:
        n, w, c = counts[k], np.array(wall[k]), np.array(cpu[k])
        out[k] = {"events": n, "mev_s": n / float(np.median(w)) / 1e6, "mev_s_min": n / w.max() / 1e6,
                  "mev_s_max": n / w.min() / 1e6, "cpu_mev_s": n / float(np.median(c)) / 1e6,
                  "cpu_mev_s_min": n / c.max() / 1e6, "cpu_mev_s_max": n / c.min() / 1e6,
                  "wall_s": wall[k], "cpu_s": cpu[k]}
    return out


def versus(name: str, ours: dict[str, Any], theirs: dict[str, Any], goal: float = 2.0, *, clock: str = "wall",
           peer_name: str = "peer") -> dict[str, Any]:
    """The target "ours at least ``goal`` x theirs" from two :func:`interleaved`
    results: the ratio of the medians of Mev/s (by ``clock``: ``wall`` or
    ``cpu``), and its spread over the rounds (each round's pair of runs
    gives one ratio: min and max). A :func:`target` record with
    ``ratio_min``/``ratio_max`` and both speeds added."""
    key, times = ("mev_s", "wall_s") if clock == "wall" else ("cpu_mev_s", "cpu_s")
    per_round = [(ours["events"] / a) / (theirs["events"] / b) for a, b in zip(ours[times], theirs[times])]
    ratio = ours[key] / theirs[key]
    rec = target(f"{name} vs {peer_name} ({clock})", ratio, goal, "x")
    rec.update({"ratio_min": min(per_round), "ratio_max": max(per_round), "ours_mev_s": ours[key],
                "theirs_mev_s": theirs[key], "clock": clock})
    return rec


def memory_bandwidth(mbytes: int = 256, repeat: int = 5) -> float:
    """This machine's copy bandwidth now, bytes/s (read plus write of a
    ``mbytes`` MB array; the median of ``repeat`` copies, timed in CPU
    seconds of this process: on a loaded machine the wall clock would count
    the time other processes ran, and so state a limit lower than memory's)."""
    a = np.ones(mbytes * 1_000_000 // 8)
    b = np.empty_like(a)
    np.copyto(b, a)  # b's pages faulted in: the copies time memory, not the kernel
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        np.copyto(b, a)
        times.append(max(time.process_time() - t0, 1e-9))
    return 2 * a.nbytes / float(np.median(times))


def peer(module: str) -> Any | None:
    """Import a peer library, or None when it is not installed."""
    try:
        return importlib.import_module(module)
    except Exception:
        return None


def fmt(v: Any) -> str:
    """A table cell: floats to 3 significant digits (whole numbers from 1000 on)."""
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"
    return str(v)


def table(rows: list[dict[str, Any]], cols: list[str]) -> str:
    """Format rows as a fixed-width text table (a missing cell is blank)."""
    cells = [[fmt(r.get(c, "")) for c in cols] for r in rows]
    widths = [max(len(c), *(len(x[i]) for x in cells)) if cells else len(c) for i, c in enumerate(cols)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(cols, widths))]
    lines += ["  ".join(x.ljust(w) for x, w in zip(r, widths)) for r in cells]
    return "\n".join(lines)


def target(name: str, value: float, goal: float, unit: str, higher_is_better: bool = True) -> dict[str, Any]:
    """A target a suite states, and whether this run met it: ``value`` at
    least ``goal`` (or at most, with ``higher_is_better=False``), both in
    ``unit``. A NaN value misses. The record goes into the suite's JSON
    under ``"targets"``."""
    value = float(value)
    met = not math.isnan(value) and (value >= goal if higher_is_better else value <= goal)
    return {"name": name, "value": value, "goal": goal, "unit": unit, "higher_is_better": higher_is_better, "met": met}


def target_row(rec: dict[str, Any]) -> dict[str, Any]:
    """A :func:`target` record as a row of :data:`TARGET_COLUMNS`: the goal
    as ``>= 200000`` / ``<= 5``, and ``met`` or ``MISSED``; a ratio from
    :func:`versus` shows its spread over the rounds in ``value``
    (``2.31 (2.05-2.6)``)."""
    goal = (">= " if rec["higher_is_better"] else "<= ") + fmt(float(rec["goal"]))
    value: Any = rec["value"]
    if "ratio_min" in rec:
        value = f"{fmt(float(rec['value']))} ({fmt(float(rec['ratio_min']))}-{fmt(float(rec['ratio_max']))})"
    return {"measure": rec["name"], "value": value, "unit": rec["unit"], "target": goal,
            "met": "met" if rec["met"] else "MISSED"}


def targets_table(records: Sequence[dict[str, Any]]) -> str:
    """:func:`target` records as a text table, one line each with met/MISSED."""
    return table([target_row(r) for r in records], TARGET_COLUMNS)


def run_parts(suite: str, parts: Sequence[str], out: Path, quick: bool) -> dict[str, Any]:
    """A suite made of parts, one module each
    (``tectum.evaluation.suites._SUITE_PART`` with ``run(out, quick)``): runs
    them in order, then prints every part's targets in one table. Returns
    ``{"parts": {part: result}, "targets": [...]}``."""
    results: dict[str, Any] = {}
    targets: list[dict[str, Any]] = []
    for part in parts:
        print(f"\n== {suite}: {part}")
        r: dict[str, Any] = importlib.import_module(f"tectum.evaluation.suites._{suite}_{part}").run(out, quick)
        results[part] = r
        targets += r.get("targets", [])
    print("\n" + targets_table(targets))
    return {"parts": results, "targets": targets}


def write_results(out: Path, suite: str, results: dict[str, Any]) -> Path:
    """Write ``results`` with the machine's description to ``out/bench-SUITE.json``."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"bench-{suite}.json"
    meta = {"python": platform.python_version(), "machine": platform.machine(), "processor": platform.processor(),
            "numpy": np.__version__, "time": time.strftime("%Y-%m-%dT%H:%M:%S")}
    path.write_text(json.dumps({"suite": suite, "meta": meta, "results": results}, indent=1, default=float))
    return path


def shared_data() -> Path | None:
    """The folder of shared recordings: ``TECTUM_SHARED_DATA``, else
    ``../shared/data`` beside the source tree; None when absent."""
    env = os.environ.get("TECTUM_SHARED_DATA")
    p = Path(env) if env else Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
    return p if p.is_dir() else None
