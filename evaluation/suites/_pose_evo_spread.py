"""EVO on the bench's plane (or boxes) from several start times: the
measurement behind ``docs/evo.md`` (single runs of the loop are noisy: 13-29 %
of the path from one start to the next with the same settings).

One simulation of the bench's scene (``plane``: ``PLANE``; ``boxes_3d``; seed
1, 240x180) as long as the last start needs; per start, either

* ``loop``: :func:`~tectum.evaluation.suites._pose_evo.evo_loop` (tracker and
  mapper) bootstrapped with ``boot_us`` of the true poses, then ``tracked_us``
  alone; or
* ``alone``: ``tracker.edge_align`` bootstrapped the same way, against the
  maps ``map.emvs`` made from the true poses of the whole simulation (made
  once), so only the tracker's own error counts;

scored as the bench scores (position RMSE over the path, %, the final error
over the path, the rotation's median error, the share of lost rows), with
the bench's tracker and mapper settings for the scene.

From a shell (JSON for the parameters that differ from the bench's)::

    python -m tectum.evaluation.suites._pose_evo_spread loop
    python -m tectum.evaluation.suites._pose_evo_spread alone --mapper '{"keyframe_baseline": 0.1}'
    python -m tectum.evaluation.suites._pose_evo_spread loop --scene boxes_3d --mapper '{"overlap": 2}'
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from tectum import MapPacket, Packet, PosePacket, concat
from tectum.evaluation.suites._pose_evo import MAPPERS, PLANE, TRACKERS, evo_loop, scores, simulate, simulate_gyro
from tectum.plugins.map.emvs import Emvs
from tectum.plugins.tracker.edge_align import EdgeAlign
from tectum.testing import feed_ports

__all__ = ["spread", "mean_line", "LOOP_STARTS_S", "ALONE_STARTS_S"]

#: the scenes by name: the bench's plane and the built-in boxes
SCENES: dict[str, str | dict[str, Any]] = {"plane": PLANE, "boxes_3d": "boxes_3d"}
#: start times of the loop per scene (s): 0.3 s of bootstrap, then 2 s tracked
LOOP_STARTS_S = {"plane": (0.0, 1.0, 1.7, 0.5, 1.3, 2.0), "boxes_3d": (0.0, 0.15, 0.3)}
#: start times of the tracker alone per scene (s): 0.1 s of bootstrap before, then 0.7 s tracked
ALONE_STARTS_S = {"plane": (0.4, 0.9, 1.4, 1.9, 2.4, 2.9), "boxes_3d": (0.4, 0.9, 1.4, 1.9)}


def spread(mode: str, starts_s: Sequence[float] | None = None, tracked_us: int | None = None,
           boot_us: int | None = None, tracker: dict[str, Any] | None = None, mapper: dict[str, Any] | None = None,
           scene: str = "plane", duration_us: int | None = None, imu: dict[str, Any] | None = None
           ) -> list[dict[str, Any]]:
    """One row per start (``start_s``, ``pos_pct``, ``drift_pct``,
    ``rot_median_deg``, ``lost``, ``path_m``, ...) of ``mode`` ``"loop"`` or
    ``"alone"`` (see the module) on ``scene`` (a name of :data:`SCENES`) with
    the bench's tracker and mapper parameters for it updated by ``tracker``
    and ``mapper``. Defaults: the loop 0.3 s of bootstrap
    from each start then 2 s; alone 0.1 s of bootstrap ending at each start
    then 0.7 s. ``duration_us`` (µs) cuts the simulation short (every run
    ends with it at the latest). ``imu``: the simulated DAVIS's IMU (its
    ``davis`` keys, e.g. ``{"imu_rate_hz": 1000, "gyro_noise": 0.003}``)
    for the tracker (which uses it with ``gyro_rad`` > 0)."""
    if mode not in ("loop", "alone"):
        raise ValueError(f"spread: mode is 'loop' or 'alone', got {mode!r}")
    if scene not in SCENES:
        raise ValueError(f"spread: scene is one of {sorted(SCENES)}, got {scene!r}")
    loop = mode == "loop"
    starts = [int(s * 1e6) for s in (starts_s if starts_s is not None else
                                      (LOOP_STARTS_S if loop else ALONE_STARTS_S)[scene])]
    tracked = tracked_us if tracked_us is not None else (2_000_000 if loop else 700_000)
    boot = boot_us if boot_us is not None else (300_000 if loop else 100_000)
    trk = {**TRACKERS[scene], **(tracker or {})}
    mpr = {**MAPPERS[scene], **(mapper or {})}
    end = max(starts) + tracked + (boot if loop else 0)
    dur = min(end, duration_us) if duration_us else end
    gyro = None
    if imu:
        ev, truth, calib, gyro = simulate_gyro(SCENES[scene], dur, imu)
    else:
        ev, truth, calib = simulate(SCENES[scene], dur)
    maps: list[Packet] = []
    if not loop:
        mp = Emvs(calib=calib, **mpr)
        made = [q for q in feed_ports(mp, {"events": [ev], "poses": [truth]}) if isinstance(q, MapPacket)]
        maps = [concat(made)] if made else []
    rows = []
    for s in starts:
        est: Packet
        if loop:
            a, b, t_from = s, s + boot + tracked, s + boot
            est, _, _, _, _ = evo_loop(ev.slice_time(a, b), truth.slice_time(a, b), calib, boot, tracker=trk,
                                       mapper=mpr, imu=gyro.slice_time(a, b) if gyro is not None else None)
        else:
            a, b, t_from = s - boot, s + tracked, s
            op = EdgeAlign(calib=calib, bootstrap_us=boot, **trk)
            ports: dict[str, list[Packet]] = {"events": [ev.slice_time(a, b)], "poses": [truth.slice_time(a, b)],
                                              "maps": maps}
            if gyro is not None:
                ports["imu"] = [gyro.slice_time(a, b)]
            out = feed_ports(op, ports)
            poses = [q for q in out if isinstance(q, PosePacket)]
            est = concat(poses) if poses else PosePacket.empty(a, b)
        assert isinstance(est, PosePacket)
        rows.append({"start_s": s * 1e-6, **scores(est, truth.slice_time(a, b), t_from)})
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m tectum.evaluation.suites._pose_evo_spread",
                                 description="EVO on a bench scene from several start times (see the module)")
    ap.add_argument("mode", choices=("loop", "alone"))
    ap.add_argument("--scene", choices=sorted(SCENES), default="plane")
    ap.add_argument("--tracker", default="{}", help="tracker.edge_align parameters (JSON) over the bench's")
    ap.add_argument("--mapper", default="{}", help="map.emvs parameters (JSON) over the bench's for the scene")
    ap.add_argument("--starts", type=float, nargs="*", help="start times, s")
    ap.add_argument("--imu", default="{}", help="the simulated IMU for the tracker (JSON: the scene's davis keys, "
                    "e.g. {\"imu_rate_hz\": 1000, \"gyro_noise\": 0.003}; the tracker uses it with gyro_rad > 0)")
    args = ap.parse_args(argv)
    rows = spread(args.mode, args.starts, tracker=json.loads(args.tracker), mapper=json.loads(args.mapper),
                  scene=args.scene, imu=json.loads(args.imu))
    for r in rows:
        print(f"start {r['start_s']:.2f} s: position RMSE {r['pos_pct']:.1f} % of {r['path_m']:.2f} m, final "
              f"{r['drift_pct']:.1f} %, rotation median {r['rot_median_deg']:.2f} deg, lost {100 * r['lost']:.0f} %")
    print(mean_line(rows))


def mean_line(rows: Sequence[dict[str, Any]]) -> str:
    """The means over the starts ``rows`` (rows of :func:`spread`), said over
    the starts that tracked at all: a start lost from its first step has no
    score (NaN), and the bench's mean over the starts is then NaN (missed)."""
    pos = np.array([r["pos_pct"] for r in rows])
    rot = np.array([r["rot_median_deg"] for r in rows])
    scored = int(np.sum(np.isfinite(pos)))
    if not scored:
        return f"mean: none of {len(rows)} starts tracked (every one lost from the start)"
    over = "" if scored == len(rows) else (f" over {scored} of {len(rows)} starts ({len(rows) - scored} lost from "
                                           "the start: the bench's mean is NaN, missed)")
    return (f"mean: position RMSE {np.nanmean(pos):.1f} % of the path (median {np.nanmedian(pos):.1f} %), final "
            f"{np.nanmean([r['drift_pct'] for r in rows]):.1f} %, rotation median {np.nanmean(rot):.2f} deg{over}")


if __name__ == "__main__":
    main()
