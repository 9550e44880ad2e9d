"""``tectum bench calibrate``, part ``accuracy``: ``tectum.calibrate`` against
the simulator's known camera.

A 240x180 camera (fx 200, fy 201 px, principal point 1.3 px off centre,
radtan k1 -0.3, k2 0.1, p1 0.001, p2 -0.001: at the image corners the lens
moves a point by 12 px) sees a 7x5 grid of dots (3 cm apart, radius 7.5 mm)
blinking at 250 Hz in 15 still poses (tilted up to 45°, 150 ms each, 60 ms
moves between them; DVS thresholds 0.25 ± 0.03). Conditions: clean; 1 and
5 Hz/px of shot noise; 50 and 100 Hz mains flicker (depth 0.3) on a lamp
behind the board (the right quarter of the image), with 1 Hz/px noise.
Two seeds per condition (one with ``--quick``); the targets hold for the
worst run: focal error <= 0.3 %, principal point <= 0.5 px, k1 within 0.01,
reprojection RMS <= 0.2 px. A picture of one view's transitions with the
detected dots, and every reprojection error, goes to ``out/calibrate.png``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from tectum.calibration import Calibration, calibrate
from tectum.camera import Camera
from tectum.evaluation.harness import table, target
from tectum.sources.simulate.blink_board import Board, BoardTruth, board_poses, simulate_board

W, H = 240, 180
CAMERA = Camera(np.array([[200.0, 0, 121.3], [0, 201.0, 88.7], [0, 0, 1]]), np.array([-0.3, 0.1, 0.001, -0.001]),
                (W, H))
BOARD = Board(7, 5, 0.03, 0.0075)
CONDITIONS: dict[str, dict[str, Any]] = {
    "clean": {},
    "noise 1 Hz/px": {"noise_hz": 1.0},
    "noise 5 Hz/px": {"noise_hz": 5.0},
    "flicker 50 Hz": {"flicker_hz": 50.0, "noise_hz": 1.0},
    "flicker 100 Hz": {"flicker_hz": 100.0, "noise_hz": 1.0},
}


def errors(cal: Calibration, truth: Camera) -> dict[str, float]:
    """Errors of a calibration against the true camera."""
    c = cal.camera
    return {"focal_%": 100 * max(abs(c.fx / truth.fx - 1), abs(c.fy / truth.fy - 1)),
            "pp_px": float(np.hypot(c.cx - truth.cx, c.cy - truth.cy)),
            "k1_err": abs(float(c.D[0] - truth.D[0])), "rms_px": cal.rms}


def simulate(views: int, seed: int, *, camera: Camera = CAMERA, tilt_deg: float = 45.0,
             **kw: Any) -> tuple[Any, BoardTruth]:
    R, t = board_poses(camera, BOARD, views, seed=seed, tilt_deg=tilt_deg)
    return simulate_board(camera, BOARD, R, t, seed=seed, **kw)


def run_case(name: str, seed: int, views: int = 15, **kw: Any) -> tuple[dict[str, Any], Calibration | None]:
    t0 = time.perf_counter()
    ev, truth = simulate(views, seed, **kw)
    t1 = time.perf_counter()
    row: dict[str, Any] = {"case": name, "seed": seed, "events": len(ev), "sim_s": t1 - t0}
    try:
        cal = calibrate(ev, (BOARD.cols, BOARD.rows), BOARD.spacing, min_views=3)
    except ValueError as e:
        row.update(used=0, error=str(e)[:60])
        return row, None
    row.update(used=len(cal.used), **errors(cal, truth.camera), cal_s=time.perf_counter() - t1)
    return row, cal


def picture(cal: Calibration, path: Path) -> None:
    """One view's ON→OFF transitions with the ordered dots, beside every
    reprojection error of the views used."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("(no matplotlib: no picture; pip install '.[charts]')")
        return
    fig, (a, b) = plt.subplots(1, 2, figsize=(8.0, 3.0), gridspec_kw={"width_ratios": [1.4, 1]})
    v = max(cal.used, key=lambda u: float(np.ptp(u.points[:, 0])) if u.points is not None else 0.0)
    assert v.transitions is not None and v.points is not None
    a.imshow(v.transitions, cmap="magma", interpolation="nearest")
    g = v.points.reshape(cal.grid.rows, cal.grid.cols, 2)
    for row in g:
        a.plot(row[:, 0], row[:, 1], "-", color="tab:cyan", lw=0.7)
    a.plot(v.points[:, 0], v.points[:, 1], "+", color="w", ms=4, mew=0.8)
    a.plot(*v.points[0], "o", mfc="none", mec="tab:cyan", ms=7)
    a.set_title("ON→OFF transitions of one view; dots in grid order (first circled)", fontsize=9)
    a.set_xticks([])
    a.set_yticks([])
    res = np.concatenate([v.residuals for v in cal.used if v.residuals is not None])
    b.scatter(res[:, 0], res[:, 1], s=3, alpha=0.5)
    lim = max(0.3, float(np.abs(res).max()) * 1.1)
    b.add_patch(plt.Circle((0, 0), cal.rms, fill=False, color="tab:red", lw=1))
    b.set_xlim(-lim, lim)
    b.set_ylim(-lim, lim)
    b.set_aspect("equal")
    b.set_xlabel("x error (px)")
    b.set_ylabel("y error (px)")
    b.set_title(f"reprojection errors, {len(cal.used)} views (RMS {cal.rms:.3f} px)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    print(f"picture: {path}")


def run(out: Path, quick: bool) -> dict[str, Any]:
    seeds = (1,) if quick else (1, 2)
    rows: list[dict[str, Any]] = []
    shown: Calibration | None = None
    for name, kw in CONDITIONS.items():
        for seed in seeds:
            row, cal = run_case(name, seed, **kw)
            rows.append(row)
            print(table([row], ["case", "seed", "events", "used", "focal_%", "pp_px", "k1_err", "rms_px", "sim_s",
                                "cal_s", "error"]).splitlines()[-1], flush=True)
            if cal is not None and name == "noise 1 Hz/px" and shown is None:
                shown = cal
    print("\n" + table(rows, ["case", "seed", "events", "used", "focal_%", "pp_px", "k1_err", "rms_px", "sim_s",
                              "cal_s", "error"]))
    if shown is not None:
        out.mkdir(parents=True, exist_ok=True)
        picture(shown, out / "calibrate.png")

    def worst(key: str) -> float:
        return max((float(r.get(key, np.nan)) for r in rows), default=float("nan"))

    failed = any("error" in r for r in rows)
    nan = float("nan")
    targets = [target("focal error, worst run", nan if failed else worst("focal_%"), 0.3, "%", False),
               target("principal point error, worst run", nan if failed else worst("pp_px"), 0.5, "px", False),
               target("k1 error, worst run", nan if failed else worst("k1_err"), 0.01, "", False),
               target("reprojection RMS, worst run", nan if failed else worst("rms_px"), 0.2, "px", False)]
    return {"rows": rows, "targets": targets}
