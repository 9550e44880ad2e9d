"""``tectum bench tracker``, part ``clusters``: ``tracker.clusters`` on
simulated moving objects (disks at a set speed in random directions,
bouncing off the sensor's sides: :func:`~tectum.sources.simulate.objects.moving_objects`),
scored against the renderer's own object positions.

* accuracy: per output time each object is matched to the nearest cluster
  within 10 px; position error (median, p90 px), coverage (object-times with
  a cluster), false rows (clusters matched to no object), id switches per
  second (a matched id changing), on 240x180 with the realistic sensor
  model, denoised by ``filter.background_activity`` (dt 3 ms) as the
  operator's docstring advises.
* failure map: object speed (100 to 3000 px/s), shot noise (the preset's
  0.2 Hz/px up to 5 Hz/px, with and without the denoiser: at 5 Hz/px raw,
  noise seeds take every cluster slot and no object becomes visible),
  object count.
  Above about 500 px/s the realistic sensor's photoreceptor low-pass (300
  Hz at full scale, slower in the dark) delays the events of an edge going
  dark by milliseconds, so the events themselves trail the object by a few
  px: the rows "no photoreceptor lag" turn that low-pass off to show the
  tracker alone (measured: 0.64-0.67 px median at 1000-3000 px/s, against
  3-5 px with the low-pass).
* latency: event-to-output latency fed as a live source would feed it
  (packets of 100 µs with a row per event, ``update_us=0``, the goalie's
  path; packets of 1 ms with rows every ms): stream-time wait plus the
  packet's processing time, p50/p99.
* chart (with matplotlib): ``tracker_clusters_failure_map.png``, the
  failure map's rows as bars.
* speed: Mev/s per CPU second on 1 s of 346x260 (three disks at
  1000 px/s, realistic noise), denoised as advised and raw, one core.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tectum import EventPacket
from tectum.evaluation.harness import table, target, throughput
from tectum.evaluation.metrics.tracking import output_latencies, track_scores

SENSOR = (240, 180)
GATE_PX = 10.0
COLS = ["case", "events", "median_px", "p90_px", "coverage", "false_rows", "switches_per_s"]


def _events(speed: float, duration_us: int, n: int = 3, sensor: tuple[int, int] = SENSOR, seed: int = 2,
            **model: Any) -> tuple[dict[str, Any], EventPacket]:
    from tectum.sources.simulate import simulate
    from tectum.sources.simulate.objects import moving_objects

    sc = moving_objects(n, sensor=sensor, speed_px_s=speed, seed=seed, radius_px=8.0 * sensor[0] / 240)
    ev, _ = simulate(sc, duration_us, seed=1, preset="realistic", **model)
    return sc, EventPacket.from_arrays(ev.t, ev.x, ev.y, ev.p, sensor=ev.sensor, t_start=ev.t_start, t_end=ev.t_end)


def _denoised(ev: EventPacket) -> EventPacket:
    from tectum.plugins.filter.background_activity import BackgroundActivity

    return BackgroundActivity(dt_us=3000).process(ev)[0]


def _score(case: str, sc: dict[str, Any], ev: EventPacket, **params: Any) -> dict[str, Any]:
    from tectum.plugins.tracker.clusters import track_clusters
    from tectum.sources.simulate.objects import object_truth

    out = track_clusters(ev, **params)
    if not len(out):  # nothing visible: every object missed
        return {"case": case, "events": len(ev), "coverage": 0.0, "false_rows": 0.0, "switches_per_s": 0.0}
    _, xy, _ = object_truth(sc, out.t)
    s = track_scores(out.t, out["id"], out["x"], out["y"], xy, GATE_PX)
    dur = (ev.t_end - ev.t_start) * 1e-6
    return {"case": case, "events": len(ev), "median_px": s["median_px"], "p90_px": s["p90_px"],
            "coverage": s["coverage"], "false_rows": s["false_rows"] / max(s["rows"], 1),
            "switches_per_s": s["id_switches"] / dur}


def _failure_map(quick: bool, dur: int) -> list[dict[str, Any]]:
    rows = []
    for speed in ((100, 1000, 3000) if quick else (100, 300, 1000, 2000, 3000)):
        sc, ev = _events(speed, dur)
        rows.append(_score(f"speed {speed} px/s", sc, _denoised(ev)))
    for speed in ((3000,) if quick else (1000, 3000)):
        sc, ev = _events(speed, dur, lowpass_hz=0.0)
        rows.append(_score(f"speed {speed} px/s, no photoreceptor lag", sc, _denoised(ev)))
    for hz in ((1.0, 5.0) if quick else (1.0, 2.0, 5.0)):
        sc, ev = _events(300, dur, shot_noise_hz=hz)
        rows.append(_score(f"noise {hz:g} Hz/px, raw", sc, ev))
        rows.append(_score(f"noise {hz:g} Hz/px, denoised", sc, _denoised(ev)))
    for n in ((6,) if quick else (1, 6, 10)):
        sc, ev = _events(300, dur, n=n)
        rows.append(_score(f"{n} objects", sc, _denoised(ev)))
    return rows


def failure_chart(out: Path, name: str, title: str, rows: list[dict[str, Any]], metrics: list[str]) -> None:
    """A failure map as a picture: one panel of horizontal bars per metric,
    one bar per case (missing values left blank); ``out/NAME.png``. Needs
    matplotlib (the ``charts`` extra); without it, nothing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    cases = [str(r["case"]) for r in rows]
    fig, axes = plt.subplots(1, len(metrics), figsize=(3.2 * len(metrics) + 3, 0.35 * len(cases) + 1.5), sharey=True)
    for ax, m in zip(np.atleast_1d(axes), metrics):
        vals = np.array([float(r.get(m, np.nan)) for r in rows])
        ax.barh(range(len(cases)), np.nan_to_num(vals, nan=0.0), color="tab:blue")
        ax.set_title(m)
    first = np.atleast_1d(axes)[0]
    first.set_yticks(range(len(cases)), cases)
    first.invert_yaxis()  # (shared: once for all) the first case on top
    fig.suptitle(title)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / f"{name}.png", dpi=100)
    plt.close(fig)


LATENCY_COLS = ["mode", "rows", "p50_us", "p99_us", "p99_cpu_us", "processing_p99_us", "processing_p99_cpu_us"]


def latency_row(mode: str, lat: dict[str, np.ndarray]) -> dict[str, Any]:
    """A row of :data:`LATENCY_COLS` from :func:`output_latencies`."""
    return {"mode": mode, "rows": len(lat["wall"]), "p50_us": float(np.percentile(lat["wall"], 50)),
            "p99_us": float(np.percentile(lat["wall"], 99)), "p99_cpu_us": float(np.percentile(lat["cpu"], 99)),
            "processing_p99_us": float(np.percentile(lat["cost_wall"], 99)),
            "processing_p99_cpu_us": float(np.percentile(lat["cost_cpu"], 99))}


def _latency(ev: EventPacket) -> list[dict[str, Any]]:
    from tectum.plugins.tracker.clusters import Clusters

    rows = []
    for update, packet in ((0, 100), (1000, 1000)):
        op = Clusters(update_us=update)
        op.warmup()
        rows.append(latency_row(f"update_us={update}, {packet} µs packets", output_latencies(op, ev, packet)))
    return rows


def run(out: Path, quick: bool) -> dict[str, Any]:
    from tectum.plugins.tracker.clusters import Clusters

    dur = 300_000 if quick else 1_000_000
    sc, ev = _events(300, dur)
    main = _score("300 px/s, realistic, denoised", sc, _denoised(ev))
    rows = [main, *_failure_map(quick, dur)]
    print(table(rows, COLS))
    print("(3 disks of 8 px radius on 240x180 unless stated; 'denoised': filter.background_activity dt_us=3000)")
    failure_chart(out, "tracker_clusters_failure_map", "tracker.clusters: failure map", rows,
                  ["median_px", "coverage", "false_rows", "switches_per_s"])

    _, big = _events(1000, 1_000_000 if not quick else 300_000, sensor=(346, 260))
    lat_rows = _latency(big)
    print("\n" + table(lat_rows, LATENCY_COLS))
    print("(latency = stream-time wait for the packet to close + its processing time, by the wall clock; _cpu: "
          "by the thread's CPU time, what a core of its own would give)")

    clean = _denoised(big)
    sp_raw = throughput(lambda: Clusters().process(big), len(big), repeat=3)
    sp = throughput(lambda: Clusters().process(clean), len(clean), repeat=3)
    print(f"\nspeed: {sp['cpu_mev_s']:.1f} Mev/s per CPU second on the denoised stream ({len(clean):,} events), "
          f"{sp_raw['cpu_mev_s']:.1f} on the raw one ({len(big):,} events: noise seeds fill the cluster slots); "
          "346x260, 3 disks at 1000 px/s, realistic sensor, one core")
    goalie = lat_rows[0]
    targets = [
        target("clusters: Mev/s (one core, denoised input)", sp["cpu_mev_s"], 20.0, "Mev/s"),
        target("clusters: median position error, 300 px/s", main["median_px"], 1.5, "px", higher_is_better=False),
        target("clusters: id switches, 300 px/s", main["switches_per_s"], 10.0, "1/s", higher_is_better=False),
        target("clusters: latency p99 (wall clock), update_us=0, 100 µs packets", goalie["p99_us"], 3000.0, "µs",
               higher_is_better=False),
    ]
    return {"rows": rows, "latency": lat_rows, "speed": sp, "speed_raw": sp_raw, "targets": targets}
