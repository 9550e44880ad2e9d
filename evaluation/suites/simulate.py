"""Simulator generation speed: Mev/s of output events at 346x260 (one core).

Measures whole runs (rendering, DVS kernel, truth columns, sorting into
packets) of a moving texture, a rotating panorama and a 6-DoF plane with
the ideal preset, and the moving texture with the realistic one, after a
warm-up run that pays numba's compile/cache load. ``mev_s`` is per CPU
second (time.process_time: the machine may be shared), ``mev_s_wall`` per
wall second; ``refined`` counts pixel-steps refined alone.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from tectum.evaluation.harness import table, target, targets_table

SCENES = ("moving_texture", "rotation", "plane_6dof")
TARGET_MEV_S = 2.0  # per CPU second, each scene and preset


def _run(scene: str, preset: str, duration_us: int) -> dict[str, Any]:
    from tectum.sources.simulate import make_simulator

    sim = make_simulator(scene, duration_us, sensor="346x260", preset=preset)
    c0, w0 = time.process_time(), time.perf_counter()
    n = sum(len(ev) for ev, _ in sim.windows(10_000))
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    return {"scene": scene, "preset": preset, "events": n, "sim_ms": duration_us / 1000, "steps": sim.steps,
            "refined": sim.refined,
            "cpu_s": cpu, "wall_s": wall, "mev_s": n / max(cpu, 1e-9) / 1e6, "mev_s_wall": n / max(wall, 1e-9) / 1e6}


def run(out: Path, quick: bool) -> dict[str, Any]:
    dur = 50_000 if quick else 300_000
    _run("moving_texture", "ideal", 5_000)  # warm-up: numba cache load
    rows = [_run(s, "ideal", dur) for s in (SCENES[:1] if quick else SCENES)]
    rows.append(_run("moving_texture", "realistic", dur))
    print(table(rows, ["scene", "preset", "events", "sim_ms", "steps", "refined", "cpu_s", "mev_s", "mev_s_wall"]))
    targets = [target(f"{r['scene']} {r['preset']}, per CPU second", r["mev_s"], TARGET_MEV_S, "Mev/s") for r in rows]
    print(targets_table(targets))
    return {"rows": rows, "targets": targets}
