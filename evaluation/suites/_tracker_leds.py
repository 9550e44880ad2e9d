"""``tectum bench tracker``, part ``leds``: ``tracker.led_markers`` on a
simulated rigid body of five LEDs (800 to 2450 Hz, 0.24 x 0.18 x 0.1 m,
0.8 m in front of a 240x180 camera, f = 220 px) translating parallel to
the image plane and bouncing (:class:`~tectum.sources.simulate.objects.LedBody`),
with a lamp flickering at 100 Hz (50 Hz mains) beside it.

Sensor: the realistic preset (noise, threshold spread, 10 µs jitter, 100 µs
refractory) with the photoreceptor cut-off raised from the preset's 300 Hz
at full scale (office light) to 5 kHz: LEDs are far brighter than the scene
and the bandwidth grows with light. With the preset's 300 Hz no LED above
about 500 Hz gives events at all (measured: none of the five).

* accuracy: id accuracy (rows whose id is the LED nearest to them, within
  3 px), position error (median px, against the LED's own truth), coverage
  (LED-times seen over LED-times after the first window), pose error against
  the truth (median translation mm, rotation deg; the pose is the camera in
  the body's frame) and the share of updates with a pose.
* highest frequency and speed that still work: the LEDs' frequencies scaled
  up (x1 to x8), the body's speed raised (0.2 to 6 m/s, 55 to 1650 px/s in
  the image); "works" = id accuracy >= 0.95, coverage >= 0.8 and median
  translation error <= 50 mm. The frequency limit is the pixel's: with the
  preset's 100 µs refractory period the LEDs from 3.7 kHz on give too few
  transitions (measured at x2: the 3.7 and 4.9 kHz LEDs are not seen), so
  the top scale is run again with a faster pixel (refractory 20 µs,
  bandwidth 20 kHz), where 9.8 kHz LEDs were all seen.
* failure map: speed, shot noise (0.2 to 10 Hz/px), flicker lamps (none,
  one at 100 Hz, three at 100 Hz, one at 120 Hz: 60 Hz mains, not in the
  default rejected bands but in no LED's band either).
* chart (with matplotlib): ``tracker_leds_failure_map.png``.
* latency (1 ms packets: stream-time wait plus processing, p50/p99) and
  speed (Mev/s per CPU second, one core) on a busy stream (20 Hz/px of shot
  noise added: the body alone gives about 0.5 Mev/s, where the per-update
  work, a pose every ms, would dominate), with poses and tracks only.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from tectum import EventPacket, PosePacket, TrackPacket, concat
from tectum.evaluation.harness import table, target, throughput
from tectum.evaluation.metrics.tracking import id_accuracy, output_latencies, pose_errors
from tectum.evaluation.suites._tracker_clusters import LATENCY_COLS, failure_chart, latency_row

POINTS = ((0, 0, 0), (0.24, 0, 0), (0.24, 0.18, 0), (0, 0.18, 0.06), (0.12, 0.09, 0.1))
FREQS = (800.0, 1050.0, 1400.0, 1850.0, 2450.0)
LAMP = (30.0, 150.0, 8.0, 100.0)
COLS = ["case", "events", "id_acc", "median_px", "coverage", "pose_share", "trans_mm", "rot_deg", "works"]


def _body(speed: float = 0.2, scale: float = 1.0,
          lamps: tuple[tuple[float, float, float, float], ...] = (LAMP,)) -> Any:
    from tectum.sources.simulate.objects import LedBody

    return LedBody(POINTS, tuple(f * scale for f in FREQS), position=(-0.12, -0.1, 0.8), velocity=(speed, 0.5 * speed),
                   bounce=(0.2, 0.12), sensor=(240, 180), focal_px=220.0, flicker=lamps)


def _events(body: Any, duration_us: int, **model: Any) -> EventPacket:
    from tectum.sources.simulate import simulate

    ev, _ = simulate(body.scene(), duration_us, seed=1, preset="realistic", **{"lowpass_hz": 5000.0, **model})
    return EventPacket.from_arrays(ev.t, ev.x, ev.y, ev.p, sensor=ev.sensor, t_start=ev.t_start, t_end=ev.t_end)


def _operator(body: Any, folder: str) -> Any:
    from tectum.plugins.tracker import LedMarkers

    path = os.path.join(folder, "layout.txt")
    with open(path, "w") as f:
        f.write(body.layout_text())
    return LedMarkers(layout=path, calib=body.calib)


def _score(case: str, body: Any, ev: EventPacket) -> dict[str, Any]:
    from tectum.camera import quat_to_rot, rot_to_quat

    with tempfile.TemporaryDirectory() as d:
        op = _operator(body, d)
        outs = op.process(ev)
    tracks = [q for q in outs if isinstance(q, TrackPacket)]
    poses = [q for q in outs if isinstance(q, PosePacket)]
    n = len(POINTS)
    row: dict[str, Any] = {"case": case, "events": len(ev)}
    updates = max(1, (ev.t_end - ev.t_start - 4000) // 1000)
    if not tracks:
        return {**row, "id_acc": float("nan"), "coverage": 0.0, "pose_share": 0.0, "works": "no"}
    tr = concat(tracks)
    acc, med = id_accuracy(tr["id"], tr["x"], tr["y"], body.image_points(tr.t), np.arange(1, n + 1), 3.0)
    row.update(id_acc=acc, median_px=med, coverage=min(1.0, len(tr) / (updates * n)))
    te_mm, re_deg = float("nan"), float("nan")
    if poses:
        P = concat(poses)
        pos, q = body.poses(P.t)
        R_wc = np.transpose(quat_to_rot(q), (0, 2, 1))
        te, re = pose_errors(P["position"], P["orientation"], -np.einsum("nij,nj->ni", R_wc, pos), rot_to_quat(R_wc))
        te_mm, re_deg = float(np.median(te)) * 1e3, float(np.median(re))
        row["pose_share"] = min(1.0, len(P) / updates)
    else:
        row["pose_share"] = 0.0
    row.update(trans_mm=te_mm, rot_deg=re_deg)
    ok = acc >= 0.95 and row["coverage"] >= 0.8 and te_mm <= 50
    row["works"] = "yes" if ok else "no"
    return row


def _highest(rows: list[dict[str, Any]], values: list[float]) -> float:
    """The largest value whose row works, counting up until the first that does not."""
    best = float("nan")
    for v, r in zip(values, rows):
        if r["works"] != "yes":
            break
        best = v
    return best


def run(out: Path, quick: bool) -> dict[str, Any]:
    from tectum.plugins.tracker import LedMarkers

    dur = 100_000 if quick else 400_000
    body = _body()
    main_ev = _events(body, dur)
    main = _score("0.2 m/s, one 100 Hz lamp", body, main_ev)
    rows = [main]
    speeds = [0.2, 1.0, 3.0] if quick else [0.2, 1.0, 2.0, 3.0, 4.5, 6.0]
    speed_rows = [main] + [_score(f"speed {v:g} m/s ({v * 220 / 0.8:.0f} px/s)", _body(v), _events(_body(v), dur))
                           for v in speeds[1:]]
    rows += speed_rows[1:]
    scales = [1.0, 2.0, 4.0] if quick else [1.0, 2.0, 4.0, 8.0]
    freq_rows = [main] + [_score(f"frequencies x{s:g} ({FREQS[0] * s:.0f}-{FREQS[-1] * s:.0f} Hz)", _body(scale=s),
                                 _events(_body(scale=s), min(dur, 100_000))) for s in scales[1:]]
    rows += freq_rows[1:]
    fast = {"refractory_us": 20.0, "lowpass_hz": 20_000.0}
    top_scale = scales[-1]
    rows.append(_score(f"frequencies x{top_scale:g}, faster pixel (refractory 20 µs, 20 kHz)", _body(scale=top_scale),
                       _events(_body(scale=top_scale), min(dur, 100_000), **fast)))
    for hz in ((2.0,) if quick else (2.0, 10.0)):
        rows.append(_score(f"noise {hz:g} Hz/px", body, _events(body, dur, shot_noise_hz=hz)))
    lamps = {"no lamp": (), "three 100 Hz lamps": (LAMP, (200.0, 30.0, 10.0, 100.0), (120.0, 160.0, 6.0, 100.0)),
             "one 120 Hz lamp (60 Hz mains)": ((30.0, 150.0, 8.0, 120.0),)}
    for name, ls in (lamps.items() if not quick else list(lamps.items())[1:2]):
        rows.append(_score(name, _body(lamps=ls), _events(_body(lamps=ls), dur)))
    print(table(rows, COLS))
    failure_chart(out, "tracker_leds_failure_map", "tracker.led_markers: failure map", rows,
                  ["id_acc", "median_px", "coverage", "trans_mm", "rot_deg"])
    top_f = _highest(freq_rows, [FREQS[-1] * s for s in scales])
    top_v = _highest(speed_rows, [v * 220 / 0.8 for v in speeds])
    print(f"highest LED frequency that works: {top_f:.0f} Hz; highest image speed that works: {top_v:.0f} px/s "
          "(works: id accuracy >= 0.95, coverage >= 0.8, median translation error <= 50 mm)")

    with tempfile.TemporaryDirectory() as d:
        op = _operator(body, d)
        op.warmup()
        lat_row = latency_row("update_us=1000, 1 ms packets", output_latencies(op, main_ev, 1000))
        print("\n" + table([lat_row], LATENCY_COLS))

    # speed on a busy stream: the same body with 20 Hz/px of shot noise (about 4.6 Mev/s of events)
    busy = _events(body, dur, shot_noise_hz=20.0)
    with tempfile.TemporaryDirectory() as d:
        sp = throughput(lambda: _operator(body, d).process(busy), len(busy), repeat=3)
    tracks_only = throughput(lambda: LedMarkers(freqs=FREQS).process(busy), len(busy), repeat=3)
    print(f"\nspeed: {sp['cpu_mev_s']:.1f} Mev/s per CPU second with poses (solvePnP every ms), "
          f"{tracks_only['cpu_mev_s']:.1f} without ({len(busy):,} events in {dur / 1e6:g} s, 240x180, one core)")
    targets = [
        target("leds: Mev/s (one core)", sp["cpu_mev_s"], 10.0, "Mev/s"),
        target("leds: id accuracy", main["id_acc"], 0.99, ""),
        target("leds: median position error", main["median_px"], 0.5, "px", higher_is_better=False),
        target("leds: median pose translation error at 0.8 m", main["trans_mm"], 30.0, "mm", higher_is_better=False),
    ]
    return {"rows": rows, "highest_hz": top_f, "highest_px_s": top_v, "latency": lat_row, "speed": sp,
            "speed_tracks_only": tracks_only, "targets": targets}
