"""``tectum bench pose``, part ``failure``: where ``tracker.pose_6dof``
breaks. One axis at a time from the base case (the textured plane of
:mod:`._pose_scenes`, 240x180, peak 0.5 m/s and 30 °/s, ideal sensor,
C = 0.2, 150 ms):

* speed: peak rotation 30 to 1000 °/s with translation 0.5 to 3 m/s
  (faster runs oscillate faster, as in ``known_map``);
* event noise: shot noise of the ``realistic`` sensor model at 0 to 20
  Hz per pixel (with its threshold spread and refractory period);
* map error: multiplicative Gaussian noise on the map's depth (σ 0 to 30 %),
  and a wrong contrast threshold given to the tracker (0.1 to 0.4 against
  the sensor's 0.2);
* texture: the plane's noise texel (0.01 to 0.08 m: 1 to 8 px) and its
  log-contrast (0.1 to 0.8).

Per cell: position RMSE as % of the path, median rotation error (deg) and
the rows flagged lost (%) (a cell that is all lost has no error to show).
Each axis reports the first value at which the position RMSE passes twice
the base case's or 10 % of the rows are lost. (150 ms is a short path: the
base case's % of path is larger than in ``known_map``.)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tectum import MapPacket
from tectum.evaluation.harness import table

from ._pose_known_map import score, simulated_case, track

DURATION = 150_000


def _cell(axis: str, value: float, scene: str = "plane", m_s: float = 0.5, deg_s: float = 30.0, freq: float = 2.0,
          depth_noise: float = 0.0, contrast: float = 0.2, **model: Any) -> dict[str, Any]:
    ev, truth, maps = simulated_case(scene, m_s, deg_s, freq, DURATION, **model)
    if depth_noise:
        rng = np.random.default_rng(7)
        d = maps.depth * (1 + depth_noise * rng.standard_normal(maps.depth.shape))
        maps = MapPacket(maps.t, image=maps.image, depth=np.where(d > 0, d, np.nan).astype(np.float32), K=maps.K,
                         pose=maps.pose, t_start=maps.t_start, t_end=maps.t_end)
    po, _, _ = track(ev, maps, contrast=contrast)
    s = score(po, truth["pose_t"], truth["pose_position"], truth["pose_orientation"])
    return {"axis": axis, "value": value, "ATE mm": s["ate_m"] * 1e3, "pos %path": s["pos_pct"],
            "rot med deg": s["rot_median_deg"],
            "lost %": 100 * s["lost"], "events": len(ev)}


def run(out: Path, quick: bool) -> dict[str, Any]:
    speeds = [(30.0, 0.5, 2.0), (300.0, 2.0, 4.0)] if quick else \
        [(30.0, 0.5, 2.0), (100.0, 1.0, 2.0), (300.0, 2.0, 4.0), (600.0, 2.5, 6.0), (1000.0, 3.0, 10.0)]
    noise = [0.0, 5.0] if quick else [0.0, 1.0, 5.0, 20.0]
    depth = [0.0, 0.1, 0.3] if quick else [0.0, 0.02, 0.05, 0.1, 0.3]
    contrast = [0.1, 0.3] if quick else [0.1, 0.15, 0.25, 0.3, 0.4]
    rows: list[dict[str, Any]] = []
    for deg, m_s, f in speeds:
        rows.append(_cell("speed deg/s", deg, m_s=m_s, deg_s=deg, freq=f))
    for hz in noise:
        rows.append(_cell("shot noise Hz/px", hz, preset="realistic", shot_noise_hz=hz))
    for sd in depth:
        rows.append(_cell("depth noise (x)", sd, depth_noise=sd))
    for c in contrast:
        rows.append(_cell("tracker C (sensor 0.2)", c, contrast=c))
    if not quick:
        for texel in (0.01, 0.04, 0.08):
            rows.append(_cell_texture("texel m", texel, texel_m=texel))
        for con in (0.1, 0.25, 0.8):
            rows.append(_cell_texture("texture log-contrast", con, contrast=con))
    cols = ["axis", "value", "ATE mm", "pos %path", "rot med deg", "lost %", "events"]
    print(table(rows, cols))
    base = rows[0]["ATE mm"]
    breaks = []
    for axis in dict.fromkeys(r["axis"] for r in rows):
        bad = [r["value"] for r in rows if r["axis"] == axis and not (r["ATE mm"] <= 2 * base and r["lost %"] < 10)]
        breaks.append({"axis": axis, "first value past 2x the base ATE or 10 % lost": bad[0] if bad else "none"})
    print("\n" + table(breaks, list(breaks[0])))
    return {"rows": rows, "breaks": breaks, "targets": []}


def _cell_texture(axis: str, value: float, **tex: float) -> dict[str, Any]:
    """A cell on a plane with another texture (the scene built here, not by name)."""
    from tectum.evaluation.suites import _pose_scenes

    orig = _pose_scenes.plane

    def plane(**kw: Any) -> dict[str, Any]:
        return orig(**{**kw, **tex})

    _pose_scenes.plane = plane  # type: ignore[assignment]
    try:
        return _cell(axis, value)
    finally:
        _pose_scenes.plane = orig
