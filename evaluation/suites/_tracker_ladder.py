"""The ``ladder`` part of ``tectum bench tracker``: ``tracker.ego_motion``'s
model ladder on simulated scenes with known motion and on the ECD excerpts.

Simulated scenes (240x180, f = 208 px, contrast thresholds 0.4, sparse
rectangles over a dark wall, as the ECD ``shapes`` poster): ``rotation``
(w = 0.8, -1.5, 0.6 rad/s), ``translation`` (1.6, -1.0, 0 m/s before a
fronto-parallel plane at 2 m), ``depths`` (1.5, 0.5, 0 m/s past rectangles at
1.2, 2.4 and 4.8 m: parallax, which no global warp holds; right is a rung
with depth structure, 6dof or its planar superset homography, not
translation or rotation) and ``6dof`` (1.2, -0.8, 1.6 m/s and 1.5, 2.0,
-0.8 rad/s before the plane: right is 6dof). Real: the four ECD excerpts of
30 000 events (``*_rotation`` must pick rotation, ``*_translation`` anything
but rotation) and slider_depth (a linear slider, several depths; shown, not
a target). One window of 30 000 events (the default) per excerpt; windows
of 30 000 events sliding by 30 000 on the simulated runs.

Reported: the confusion matrix (windows per scene and chosen rung), the
chosen rung's parameter error against the truth (rotation: rad/s of w;
translation: px/s of the image velocity; 6dof: rad/s of w) and the ladder's
speed in events/s (all five rungs per window).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from tectum.evaluation.harness import shared_data, table, target

_MODELS = ("translation", "rotation", "similarity", "homography", "6dof")
_RIGHT = {"rotation": {"rotation"}, "translation": {"translation"}, "depths": {"6dof", "homography"},
          "6dof": {"6dof"}}


def _shapes(depths: list[float], n: int, seed: int = 0) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    planes: list[dict[str, Any]] = [{"center": [0, 0, 30.0], "intensity": 0.15}]
    for k in range(n):
        z = depths[k % len(depths)]
        planes.append({"center": [rng.uniform(-0.75, 0.75) * z, rng.uniform(-0.6, 0.6) * z, z],
                       "orientation": [0, 0, rng.uniform(0, np.pi)],
                       "size": list(rng.uniform(0.08, 0.16, 2) * z), "intensity": float(rng.uniform(0.5, 0.9))})
    return planes


def scenes() -> dict[str, dict[str, Any]]:
    """The simulated scenes (see the module docstring)."""
    return {
        "rotation": {"planes": _shapes([3.0], 20), "motion": {"angular_velocity": [0.8, -1.5, 0.6]}},
        "translation": {"planes": _shapes([2.0], 16), "motion": {"velocity": [1.6, -1.0, 0.0]}},
        "depths": {"planes": _shapes([1.2, 2.4, 4.8], 24), "motion": {"velocity": [1.5, 0.5, 0.0]}},
        "6dof": {"planes": _shapes([2.0], 16), "motion": {"velocity": [1.2, -0.8, 1.6],
                                                          "angular_velocity": [1.5, 2.0, -0.8]}},
    }


def _ladder(ev: Any, calib: str) -> tuple[list[Any], float]:
    """The operator over a whole recording: its samples and the seconds it took."""
    from tectum.plugins.tracker.ego_motion import EgoMotion
    from tectum.testing import feed

    op = EgoMotion(calib=calib)
    op.warmup()
    t0 = time.perf_counter()
    out = feed(op, [ev])
    return [q for q in out if len(q)], time.perf_counter() - t0


def _rows_of(samples: list[Any]) -> list[tuple[int, str, np.ndarray, np.ndarray]]:
    return [(int(t), _MODELS[int(m)], p, s) for q in samples for t, m, p, s in zip(q.t, q.model, q.params, q.scores)]


def _simulated(quick: bool) -> tuple[list[dict[str, Any]], dict[str, dict[str, int]], int, float]:
    from tectum.sources.simulate import simulate

    rows, confusion = [], {}
    n_ev, secs = 0, 0.0
    for name, scene in scenes().items():
        ev, truth = simulate(scene, duration_us=60_000 if quick else 150_000, sensor="240x180", c_on=0.4,
                             c_off=0.4)
        f, cx, cy = truth.meta["camera"]
        samples, dt = _ladder(ev, f"{f};{f};{cx};{cy}")
        n_ev, secs = n_ev + len(ev), secs + dt
        counts = dict.fromkeys(_MODELS, 0)
        errs = []
        for t, model, params, _scores in _rows_of(samples):
            counts[model] += 1
            k = int(np.searchsorted(truth["pose_t"], t))
            k = min(k, len(truth["pose_t"]) - 1)
            w = np.asarray(truth["pose_angular_velocity"][k])
            if name == "rotation" and model == "rotation":
                errs.append(float(np.linalg.norm(params[:3] - w)))
            elif name == "translation" and model == "translation":
                errs.append(float(np.hypot(*(params[:2] - [np.median(ev["vx"]), np.median(ev["vy"])]))))
            elif name == "6dof" and model == "6dof":
                errs.append(float(np.linalg.norm(params[:3] - w)))
        confusion[name] = counts
        right = sum(counts[m] for m in _RIGHT[name])
        unit = {"rotation": "rad/s", "translation": "px/s", "6dof": "rad/s"}.get(name, "")
        rows.append({"case": f"sim {name}", "windows": sum(counts.values()), "right": right,
                     "expected": "/".join(sorted(_RIGHT[name])),
                     **counts, "param_err": f"{np.mean(errs):.3g} {unit}" if errs else ""})
    return rows, confusion, n_ev, secs


def _ecd() -> tuple[list[dict[str, Any]], int, int, float, int]:
    import tectum

    root = shared_data()
    rows: list[dict[str, Any]] = []
    right = n_ev = 0
    secs = 0.0
    present = 0
    if root is None:
        return rows, 0, 0, 0.0, 0
    for name in ("shapes_rotation", "boxes_rotation", "shapes_translation", "dynamic_translation", "slider_depth"):
        folder = root / "ecd" / name
        if not (folder / "events.txt").is_file() or not (folder / "calib.txt").is_file():
            continue
        p = tectum.Pipeline()
        src = p.source(str(folder / "events.txt"))
        evs = tectum.testing.ListSink()
        p.sink(evs, src)
        tectum.run(p)
        ev = tectum.concat([q for q in evs.packets if q.kind == "events"])
        samples, dt = _ladder(ev, str(folder / "calib.txt"))
        n_ev, secs = n_ev + len(ev), secs + dt
        got = [m for _t, m, _p, _s in _rows_of(samples)]
        scores = [s for _t, _m, _p, s in _rows_of(samples)]
        ok = all(m == "rotation" for m in got) if name.endswith("_rotation") else all(m != "rotation" for m in got)
        counted = name != "slider_depth"
        if counted:
            present += 1
            right += int(ok and bool(got))
        rows.append({"case": f"ecd {name}", "windows": len(got), "right": int(ok) if counted else "",
                     "expected": "rotation" if name.endswith("_rotation") else "not rotation",
                     **{m: got.count(m) for m in _MODELS},
                     "scores": " ".join(f"{x:.3f}" for x in scores[0]) if scores else ""})
    return rows, right, present, secs, n_ev


def _chart(out: Path, rows: list[dict[str, Any]]) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    cases = [r["case"] for r in rows]
    counts = np.array([[r[m] for m in _MODELS] for r in rows], float)
    share = counts / np.maximum(counts.sum(1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(7, 0.45 * len(cases) + 1.5))
    ax.imshow(share, cmap="Blues", vmin=0, vmax=1)
    ax.set_xticks(range(len(_MODELS)), _MODELS)
    ax.set_yticks(range(len(cases)), cases)
    for i in range(len(cases)):
        for j in range(len(_MODELS)):
            if counts[i, j]:
                ax.text(j, i, str(int(counts[i, j])), ha="center", va="center")
    ax.set_title("tracker.ego_motion: chosen rung per window")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "tracker_ladder_confusion.png", dpi=100)
    plt.close(fig)


def run(out: Path, quick: bool) -> dict[str, Any]:
    sim_rows, confusion, n_sim, s_sim = _simulated(quick)
    ecd_rows, ecd_right, ecd_present, s_ecd, n_ecd = _ecd()
    rows = sim_rows + ecd_rows
    cols = ["case", "expected", "windows", "right", *_MODELS, "param_err", "scores"]
    print(table(rows, cols))
    speed = (n_sim + n_ecd) / max(s_sim + s_ecd, 1e-9)
    print(f"\nspeed: {speed:,.0f} events/s (all five rungs per window of 30 000 events, one core)")
    if ecd_rows:
        print("scores: mean held-out log-likelihood per rung (translation rotation similarity homography 6dof), "
              "nats/event")
    else:
        print("ECD excerpts: ../shared/data absent, skipped")
    _chart(out, rows)
    sim_share = sum(r["right"] for r in sim_rows) / max(sum(r["windows"] for r in sim_rows), 1)
    targets = [target("ladder: share of simulated windows right", sim_share, 1.0, "")]
    if ecd_present:
        targets.append(target(f"ladder: ECD excerpts right (of {ecd_present} present)", ecd_right, 4, "excerpts"))
    return {"rows": rows, "confusion": confusion, "events_per_s": speed, "targets": targets}
