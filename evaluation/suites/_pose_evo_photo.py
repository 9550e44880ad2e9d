"""EVO with the photometric tracker: ``tracker.pose_6dof`` against maps
whose depth is ``map.emvs``'s and whose image is a DAVIS APS frame (no
truth intensity), on the EVO bench's plane: the measurement behind
``docs/evo.md``'s section "The photometric loop" (not kept: see there).

The bench's ``PLANE`` scene and simulation (240x180, seed 1) with APS
frames added (``aps_hz``, 5 ms exposure, each stamped at its exposure's
middle; the events are the same: the frames have their own noise stream).
A photometric map is made from one ``map.emvs`` map (:func:`photo_map`):
the log of an APS frame's intensity (``log(DN / 255 + eps)``, the
simulator's ``eps``) as its image, the EMVS depth moved into the frame's
view (each known pixel back-projected from the EMVS map's reference view
and projected into the frame's, the nearest surface kept; then each known
pixel's inverse depth the median of the known ones within ``median_px``),
at the pose of the frame's time interpolated from the poses at hand (the
truth for the tracker alone, the tracker's own good rows in the loop).
The frame is the last one whose exposure ended before the map was made
(``frame="late"``; as ``map.photometric`` makes them, with its pure
functions) or the one nearest the map's reference view
(``"ref"``); ``conf`` keeps only that share of the EMVS map's pixels with
the highest confidence.

* ``alone``: ``map.emvs`` on the true poses of the whole run; the tracker
  starts ``boot_us`` after each start at the true pose, with the latest map
  made ``delay_us`` before, and takes each later map ``delay_us`` after it
  was made (the pixels' states from the events of the 50 ms before);
  ``--depth truth`` (the true depth in the frame's view, everywhere) or
  ``truth_sparse`` (at the EMVS map's pixels only) for the ceiling.
* ``loop``: as :func:`~tectum.evaluation.suites._pose_evo.evo_loop` with
  ``tracker.pose_6dof``: slices of 5 ms; ``boot_us`` of the true poses go
  to the mapper, then the tracker's rows; each new map becomes a
  photometric map at once and reaches the tracker with the next slice.

Both scored as the bench scores (position RMSE over the path, %).
From a shell::

    python -m tectum.evaluation.suites._pose_evo_photo alone
    python -m tectum.evaluation.suites._pose_evo_photo loop --mapper '{"focus": 6}' --conf 0.5
    python -m tectum.evaluation.suites._pose_evo_photo loop --starts 0 1.0 1.7 0.5 1.3 2.0
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tectum import EventPacket, FramePacket, MapPacket, Packet, PosePacket, concat
from tectum.camera import interpolate_poses
from tectum.evaluation.suites._map_emvs import _simulate
from tectum.evaluation.suites._pose_evo import MAPPERS, PLANE, scores
from tectum.plugins.map.emvs import Emvs
from tectum.plugins.map.photometric import frame_before, log_image, median_depth, reproject
from tectum.plugins.tracker.pose_6dof import Pose6Dof
from tectum.sources.simulate import Simulator
from tectum.testing import feed_ports

__all__ = ["Run", "simulate_davis", "photo_map", "alone", "loop", "wired", "pipeline"]

BOOT_US = 300_000
TRACKED_US = 2_000_000


@dataclass
class Run:
    """A simulation with APS frames: events, true poses (1 kHz), frames,
    the simulator (for the true depth), intrinsics and ``eps``."""

    events: EventPacket
    truth: PosePacket
    frames: FramePacket
    sim: Simulator
    K: np.ndarray
    eps: float

    @property
    def calib(self) -> str:
        return f"{self.K[0, 0]};{self.K[1, 1]};{self.K[0, 2]};{self.K[1, 2]}"


def simulate_davis(duration_us: int, aps_hz: float = 25.0, exposure_us: float = 5000.0,
                   scene: dict[str, Any] = PLANE) -> Run:
    """The bench's simulation (240x180, seed 1, 20 ms windows) with APS frames."""
    ev, poses, sim = _simulate({**scene, "davis": {"aps_rate_hz": aps_hz, "exposure_us": exposure_us}}, duration_us)
    tr = sim.truth  # the frames as the simulator gave them, over the events' span
    frames = FramePacket(np.array(tr["aps_t"]), images=np.array(tr["aps_images"]),
                         exposure_start=np.array(tr["aps_exposure_start"]),
                         exposure_end=np.array(tr["aps_exposure_end"]), t_start=ev.t_start, t_end=ev.t_end)
    f, cx, cy = (float(v) for v in tr["camera"])
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    return Run(ev, poses, frames, sim, K, float(sim.model.eps))


def _pose7(t_us: int, poses: PosePacket) -> np.ndarray:
    p, q, _ = interpolate_poses(np.array([t_us], np.int64), poses.t, poses.position, poses.orientation)
    return np.concatenate([p[0], q[0]])


def photo_map(maps: MapPacket, i: int, run: Run, poses: PosePacket, frame: str = "late", conf: float = 0.0,
              median_px: int = 4, depth: str = "emvs") -> MapPacket | None:
    """The photometric map of EMVS map ``i`` (see the module); None when the
    frame's time is outside ``poses`` or too few pixels keep a depth."""
    t_map = int(maps.t[i])
    ft = run.frames.t
    if frame == "late":  # the last frame whose exposure ended before the map was made
        j = frame_before(run.frames.data["exposure_end"], t_map)
    else:
        j = int(np.argmin(np.abs(ft - int(maps.data["t_ref"][i]))))
    if j < 0 or not poses.t[0] <= ft[j] <= poses.t[-1]:
        return None
    tf = int(ft[j])
    p7 = _pose7(tf, poses)
    dep = np.asarray(maps.data["depth"][i], np.float64)
    if conf > 0:
        c = np.asarray(maps.data["confidence"][i], np.float64)
        known = np.isfinite(dep) & np.isfinite(c)
        if known.any():
            dep = np.where(known & (c >= np.quantile(c[known], 1.0 - conf)), dep, np.nan)
    dep = reproject(dep, run.K, np.asarray(maps.data["pose"][i], np.float64), p7)
    if depth != "emvs":  # the ceiling: the true depth in the frame's view (truth_sparse: at the map's pixels)
        h, w = dep.shape
        ys, xs = (a.ravel().astype(np.float64) for a in np.mgrid[0:h, 0:w])
        _, _, _, d = run.sim.probe(xs, ys, float(tf))
        true = np.asarray(d, np.float64).reshape(h, w)
        true = np.where(np.isfinite(true) & (true > 0), true, np.nan)
        dep = true if depth == "truth" else np.where(np.isfinite(dep), true, np.nan)
    else:
        dep = median_depth(dep, median_px)
    if np.isfinite(dep).sum() < 200:
        return None
    img = log_image(run.frames.data["images"][j], 255.0, run.eps)
    return MapPacket(np.array([t_map], np.int64), image=img[None], depth=dep[None], K=run.K[None], pose=p7[None],
                     t_start=t_map, t_end=t_map + 1)


def _plain(p: PosePacket) -> PosePacket:
    """Time, position, orientation and ``lost`` only (truth and tracker rows in one stream)."""
    lost = p.lost if "lost" in p.data else np.zeros(len(p), bool)
    return PosePacket(p.t, position=p.position, orientation=p.orientation, lost=lost, t_start=p.t_start,
                      t_end=p.t_end)


def alone(run: Run, start_us: int, mapper: dict[str, Any], tracker: dict[str, Any] | None = None,
          delay_us: int = 20_000, slice_us: int = 5000, **photo: Any) -> tuple[PosePacket, Pose6Dof, float]:
    """The tracker alone from ``start_us + BOOT_US`` for ``TRACKED_US``
    against photometric maps from the EMVS maps of the true poses (see the
    module): (its poses, the tracker, CPU seconds)."""
    made = [q for q in feed_ports(Emvs(calib=run.calib, **mapper), {"events": [run.events], "poses": [run.truth]})
            if isinstance(q, MapPacket)]
    emaps = concat(made)
    assert isinstance(emaps, MapPacket)
    maps = [m for m in (photo_map(emaps, i, run, run.truth, **photo) for i in range(len(emaps))) if m is not None]
    ready = [int(m.t[0]) + delay_us for m in maps]
    op = Pose6Dof(calib=run.calib, **(tracker or {}))
    op.warmup()
    t_from, t_to = start_us + BOOT_US, min(start_us + BOOT_US + TRACKED_US, run.events.t_end)
    out: list[PosePacket] = []
    given, first = 0, True
    cpu = time.process_time()
    for a in range(t_from - 50_000, t_to, slice_us):
        ports: dict[str, Packet] = {"events": run.events.slice_time(a, min(a + slice_us, t_to))}
        if a >= t_from:
            new = [k for k in range(given, len(maps)) if ready[k] <= a]
            if first:
                ports["poses"] = run.truth.slice_time(a, a + 2000)
                first = False
            if new:
                ports["maps"] = maps[new[-1]]
                given = new[-1] + 1
        out += [q for q in op.process_ports(ports) if isinstance(q, PosePacket)]
    out += [q for q in op.finish() if isinstance(q, PosePacket)]
    cpu = time.process_time() - cpu
    est = concat([_plain(q) for q in out])
    assert isinstance(est, PosePacket)
    return est, op, cpu


def coverage(op: Pose6Dof) -> float:
    """The share of the tracker's map points in view at its last pose (1
    before it has a pose)."""
    if op._pose is None or op.map is None or op._sensor is None:
        return 1.0
    R, t, _ = op._pose
    X = (op._P - t) @ R
    K, (w, h) = op.map.K, op._sensor
    z = X[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = K[0, 0] * X[:, 0] / z + K[0, 2], K[1, 1] * X[:, 1] / z + K[1, 2]
    return float(np.mean((z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)))


def loop(run: Run, start_us: int, mapper: dict[str, Any], tracker: dict[str, Any] | None = None,
         slice_us: int = 5000, keep: float = 0.0, **photo: Any) -> tuple[PosePacket, Pose6Dof, int, float]:
    """``tracker.pose_6dof`` and ``map.emvs`` in a loop (see the module):
    (the poses, bootstrap included, the tracker, the maps made, CPU seconds).
    ``keep`` > 0: a new map reaches the tracker only once less than that
    share of its current map's points is in view (a photometric map does not
    go stale: it holds the whole image, not the edges that fired)."""
    tr = Pose6Dof(calib=run.calib, **(tracker or {}))
    mp = Emvs(calib=run.calib, **mapper)
    tr.warmup()
    mp.warmup()
    boot_end = start_us + BOOT_US
    t_end = min(boot_end + TRACKED_US, run.events.t_end)
    out: list[PosePacket] = []
    pending: list[MapPacket] = []
    made, started, started_map = 0, False, False
    cpu = time.process_time()
    for a in range(start_us, t_end, slice_us):
        b = min(a + slice_us, t_end)
        ev = run.events.slice_time(a, b)
        ports: dict[str, Packet] = {"events": ev}
        if a < boot_end:  # the tracker has no map yet: the events set its pixels' states; the truth goes out
            tr.process_ports(ports)
            tp = run.truth.slice_time(a, b)
            rows = [_plain(tp)] if len(tp) else []
        else:
            if not started:
                ports["poses"] = run.truth.slice_time(a, a + 2000)
                started = True
            if pending and (not started_map or coverage(tr) < keep or keep <= 0):
                ports["maps"] = pending[-1]
                pending = []
                started_map = True
            rows = [_plain(q) for q in tr.process_ports(ports) if isinstance(q, PosePacket)]
        out += rows
        mp_ports: dict[str, Packet] = {"events": ev}
        if rows:
            mp_ports["poses"] = concat(rows)
        new = [q for q in mp.process_ports(mp_ports) if isinstance(q, MapPacket)]
        if new:
            est = concat(out)
            assert isinstance(est, PosePacket)
            good = est.slice_time(start_us, b)
            good = PosePacket(good.t[~good.lost], position=good.position[~good.lost],
                              orientation=good.orientation[~good.lost], t_start=good.t_start, t_end=good.t_end)
            for m in new:
                made += 1
                pm = photo_map(m, 0, run, good, **photo) if len(good) >= 2 else None
                if pm is not None:
                    pending.append(pm)
    cpu = time.process_time() - cpu
    est = concat(out)
    assert isinstance(est, PosePacket)
    return est, tr, made, cpu


def wired(run: Run, start_us: int, mapper: dict[str, Any], delay_us: int = 20_000,
          slice_us: int = 5000) -> tuple[PosePacket, list[MapPacket], float]:
    """The operators of ``tracker.evo:tracker=pose_6dof`` driven by hand in
    slices, wired as the macro wires them: ``tracker.pose_6dof`` with
    ``bootstrap_us`` on the true poses, ``map.emvs`` on its rows,
    ``map.photometric`` on the mapper's maps, the frames and the tracker's
    rows, its maps back to the tracker stamped ``delay_us`` late (as the
    delayed edge delivers them): (the tracker's rows, the EMVS maps, CPU
    seconds). The check of :func:`pipeline`: the same poses."""
    from tectum.plugins.map.photometric import Photometric

    tr = Pose6Dof(calib=run.calib, bootstrap_us=BOOT_US)
    mp = Emvs(calib=run.calib, **mapper)
    ph = Photometric()
    tr.warmup()
    mp.warmup()
    t_end = min(start_us + BOOT_US + TRACKED_US, run.events.t_end)
    out: list[PosePacket] = []
    emaps: list[MapPacket] = []
    back: list[MapPacket] = []
    cpu = time.process_time()
    for a in range(start_us, t_end, slice_us):
        b = min(a + slice_us, t_end)
        ev = run.events.slice_time(a, b)
        ports: dict[str, Packet] = {"events": ev, "poses": run.truth.slice_time(a, b)}
        ready = [m for m in back if m.t_start < b]
        back = [m for m in back if m.t_start >= b]
        if ready:
            ports["maps"] = concat(ready)
        rows = [q for q in tr.process_ports(ports) if isinstance(q, PosePacket)]
        out += rows
        mp_ports: dict[str, Packet] = {"events": ev}
        if rows:
            mp_ports["poses"] = concat(rows)
        new = [q for q in mp.process_ports(mp_ports) if isinstance(q, MapPacket)]
        emaps += new
        ph_ports: dict[str, Packet] = {"frames": run.frames.slice_time(a, b),
                                       "poses": concat(rows) if rows else PosePacket.empty(a, b)}
        if new:
            ph_ports["maps"] = concat(new)
        for m in ph.process_ports(ph_ports):
            assert isinstance(m, MapPacket)
            t = m.t + delay_us
            back.append(MapPacket(t, **m.data, t_start=int(t[0]), t_end=int(t[-1]) + 1))
    last = [q for q in tr.finish() if isinstance(q, PosePacket)]  # the last batch, as at the end of a pipeline
    out += last
    end = list(mp.process_ports({"poses": concat(last)})) if last else []
    emaps += [q for q in end + list(mp.finish()) if isinstance(q, MapPacket)]
    cpu = time.process_time() - cpu
    est = concat([_plain(q) for q in out])
    assert isinstance(est, PosePacket)
    return est, emaps, cpu


def pipeline(run: Run, start_us: int, mapper: dict[str, Any], delay_us: int = 20_000
             ) -> tuple[PosePacket, list[MapPacket], float]:
    """``tracker.evo:tracker=pose_6dof`` under ``tectum.run`` on the run from
    ``start_us`` (events, the true poses as bootstrap, the APS frames): (the
    tracker's rows, the EMVS maps, CPU seconds of the whole process)."""
    import tectum
    from tectum.testing import ListSink, ListSource

    t_end = min(start_us + BOOT_US + TRACKED_US, run.events.t_end)
    p = tectum.Pipeline()
    cam = p.source(ListSource([run.events.slice_time(start_us, t_end)]), id="cam")
    gt = p.source(ListSource([run.truth.slice_time(start_us, t_end)]), id="gt")
    fr = p.source(ListSource([run.frames.slice_time(start_us, t_end)]), id="fr")
    p.op("tracker.evo", events=cam, poses=gt, frames=fr, id="evo", tracker="pose_6dof", calib=run.calib,
         delay_us=delay_us, bootstrap_us=BOOT_US, **mapper)
    sink = ListSink()
    p.sink(sink, "evo")
    cpu = time.process_time()
    tectum.run(p)
    cpu = time.process_time() - cpu
    est = concat([_plain(q) for q in sink.packets if isinstance(q, PosePacket)])
    assert isinstance(est, PosePacket)
    maps = [q for q in sink.packets if isinstance(q, MapPacket)]
    return est, maps, cpu


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m tectum.evaluation.suites._pose_evo_photo",
                                 description="tracker.pose_6dof on EMVS maps with APS images (see the module)")
    ap.add_argument("mode", choices=("alone", "loop"))
    ap.add_argument("--mapper", default="{}", help="map.emvs parameters (JSON) over the bench's plane's")
    ap.add_argument("--tracker", default="{}", help="tracker.pose_6dof parameters (JSON)")
    ap.add_argument("--starts", type=float, nargs="*", default=[0.0], help="start times, s (the bench's: 0)")
    ap.add_argument("--aps-hz", type=float, default=25.0)
    ap.add_argument("--frame", choices=("late", "ref"), default="late")
    ap.add_argument("--conf", type=float, default=0.0, help="share of the EMVS pixels kept by confidence (0: all)")
    ap.add_argument("--median-px", type=int, default=4)
    ap.add_argument("--keep", type=float, default=0.0, help="loop: a new map only below this share of points in view")
    ap.add_argument("--depth", choices=("emvs", "truth", "truth_sparse"), default="emvs")
    args = ap.parse_args(argv)
    mapper = {**MAPPERS["plane"], **json.loads(args.mapper)}
    tracker = json.loads(args.tracker)
    starts = [int(s * 1e6) for s in args.starts]
    run = simulate_davis(max(starts) + BOOT_US + TRACKED_US, args.aps_hz)
    photo = {"frame": args.frame, "conf": args.conf, "median_px": args.median_px, "depth": args.depth}
    rows = []
    for s in starts:
        if args.mode == "loop":
            est, op, made, cpu = loop(run, s, mapper, tracker, keep=args.keep, **photo)
        else:
            est, op, cpu = alone(run, s, mapper, tracker, **photo)
            made = 0
        r = scores(est, run.truth.slice_time(s, s + BOOT_US + TRACKED_US), s + BOOT_US)
        rows.append(r)
        print(f"start {s * 1e-6:.2f} s: position RMSE {r['pos_pct']:.2f} % of {r['path_m']:.2f} m, final "
              f"{r['drift_pct']:.1f} %, rotation median {r['rot_median_deg']:.2f} deg, lost {100 * r['lost']:.1f} %, "
              f"maps made {made}, {op.counts}, CPU {cpu:.1f} s", flush=True)
    pos = np.array([r["pos_pct"] for r in rows])
    print(f"mean: position RMSE {np.nanmean(pos):.2f} % of the path (median {np.nanmedian(pos):.2f} %), final "
          f"{np.nanmean([r['drift_pct'] for r in rows]):.1f} %, rotation median "
          f"{np.nanmean([r['rot_median_deg'] for r in rows]):.2f} deg")


if __name__ == "__main__":
    main()
