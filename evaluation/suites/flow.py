"""``tectum bench flow``: speed and accuracy of the flow and lifetime methods.

* speed: Mev/s and µs per event of every method/setting on one core, on a
  346x260 textured scene (edges of three orientations translating);
  contrast maximisation also as a real-time factor on a 1 Mev/s stream.
* accuracy: on the reference scene (straight edges at 1000 px/s, 300 µs
  timestamp jitter, 1 Hz/px noise; normal-flow methods against the normal
  component of the truth), on texture (full flow), and on simulator scenes
  (``SIM_SCENES``; normal-flow methods against the true normal speed
  ``1e6/lifetime`` along the true log-intensity gradient, full-flow methods
  against the true ``vx``/``vy``). AEE (px/s, %), median relative error, AAE,
  density, noise given a flow; lifetime relative error.
* failure maps: sweeps of noise rate, speed, texture density, edge
  orientation and contrast threshold; per method the values where the
  median error doubles (against the sweep's best, taken as at least 2.5 %:
  1 % -> 3 % is noise, not a failure) or density falls under half of its
  best. Charts (PNG) need matplotlib (extra ``charts``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, cast

import numpy as np

from tectum import EventPacket, Packet, concat
from tectum.evaluation.harness import shared_data, table, throughput
from tectum.evaluation.metrics import flow_errors, lifetime_errors, simulator_normal_truth
from tectum.evaluation.scenes import translating_edges
from tectum.plugins.flow import ContrastMax, EdgeSpeed, LucasKanade, PlaneFit
from tectum.plugins.lifetime import PlaneFitLifetime
from tectum.testing import feed

#: method/setting -> (factory, flow type)
METHODS: dict[str, tuple[Callable[[], Any], str]] = {
    "edge_speed": (EdgeSpeed, "normal"),
    "plane_fit naive 5x5": (lambda: PlaneFit(radius=2, n_iter=0, reject_us=1e12, max_rms=1e12), "normal"),
    "plane_fit benosman 5x5": (PlaneFit, "normal"),
    "plane_fit robust 5x5": (lambda: PlaneFit(radius=2, robust=True), "normal"),
    "plane_fit robust 7x7": (lambda: PlaneFit(radius=3, robust=True), "normal"),
    "plane_fit benosman 5x5 burst 10ms": (lambda: PlaneFit(burst_us=10_000), "normal"),
    "plane_fit robust 7x7 burst 10ms": (lambda: PlaneFit(radius=3, robust=True, burst_us=10_000), "normal"),
    "lucas_kanade normal": (lambda: LucasKanade(radius=3, dt_us=2000, min_explained=0.0), "normal"),
    "lucas_kanade full": (lambda: LucasKanade(radius=3, dt_us=2000, mode="full", min_explained=0.0), "full"),
    "contrast_max 32px/10ms": (ContrastMax, "full"),
    "contrast_max 32px/10ms fixed span": (lambda: ContrastMax(max_window_us=10_000), "full"),
}

#: lifetime settings scored (vs 1/|normal speed|)
LIFETIMES: dict[str, Callable[[], Any]] = {
    "lifetime plane_fit": PlaneFitLifetime,
    "lifetime plane_fit burst 10ms": lambda: PlaneFitLifetime(burst_us=10_000),
}


def _edges(speed: float = 1000.0, angle: float = 30.0, noise_hz: float = 1.0, jitter_us: float = 300.0,
           spacing: float = 16.0, threshold: float = 0.5, duration_us: int = 60_000, sensor: tuple[int, int] = (96, 96),
           angles: tuple[float, ...] | None = None, seed: int = 1) -> EventPacket:
    v = speed * np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    one = threshold >= 0.5  # the reference: one event per pixel crossing, sharp edges
    return translating_edges(sensor, duration_us, v[0], v[1], angles_deg=angles or (angle,), spacing_px=spacing,
                             contrast=(0.5, 0.5) if one else (0.3, 0.8), threshold=threshold,
                             blur_px=0.0 if one else 1.0, jitter_us=jitter_us, noise_hz=noise_hz, seed=seed)


def _feed(make: Callable[[], Any], pkt: EventPacket) -> list[Packet]:
    return feed(make(), [pkt])


def _run(make: Callable[[], Any], pkt: EventPacket) -> EventPacket:
    return concat(feed(make(), [pkt.without_columns("vx", "vy", "lifetime")]))  # type: ignore[return-value]


def _score(out: EventPacket, truth: EventPacket, kind: str) -> dict[str, float]:
    """Normal-flow methods against the normal truth (``nvx``/``nvy``), full-flow
    methods against the full truth (``vx``/``vy``)."""
    tx, ty = (truth["vx"], truth["vy"]) if kind == "full" else (truth["nvx"], truth["nvy"])
    # events of still parts (true speed < 1 px/s) have no relative error: left out, like noise
    still = ~(np.hypot(truth["vx"], truth["vy"]) >= 1.0)
    noise = ((truth["noise"] != 0) | still).astype(np.uint8)
    return flow_errors(out["vx"], out["vy"], out["valid"], tx, ty, noise)


def speed(quick: bool) -> list[dict[str, Any]]:
    pkt = translating_edges((346, 260), 20_000 if quick else 60_000, 600.0, 250.0, angles_deg=(0, 60, 120),
                            spacing_px=12, jitter_us=100, noise_hz=1.0, seed=3).without_columns("vx", "vy")
    rows = []
    makers = {name: make for name, (make, _) in METHODS.items()}
    makers["lifetime plane_fit"] = PlaneFitLifetime
    makers["lifetime plane_fit burst 10ms"] = lambda: PlaneFitLifetime(burst_us=10_000)
    for name, make in makers.items():
        r = throughput(partial(_feed, make, pkt), len(pkt), repeat=2 if quick else 3)
        # CPU time too: the machine may be shared, wall time then overstates the cost
        cpu = []
        for _ in range(2 if quick else 3):
            c0 = time.process_time()
            feed(make(), [pkt])
            cpu.append(time.process_time() - c0)
        rows.append({"method": name, "mev_s": r["mev_s"], "us_per_event": 1.0 / r["mev_s"],
                     "cpu_mev_s": len(pkt) / min(cpu) / 1e6})
    # contrast maximisation on a 1 Mev/s, 346x260 stream: compute time / stream time
    dur = 100_000 if quick else 300_000
    tex = translating_edges((346, 260), dur, 210.0, 105.0, angles_deg=(0, 60, 120), spacing_px=40,
                            contrast=(0.5, 0.5), threshold=0.5, blur_px=0, jitter_us=100, noise_hz=1.0, seed=4)
    rate = len(tex) / (dur * 1e-6) / 1e6
    feed(ContrastMax(), [tex.without_columns("vx", "vy")])  # compile
    els = []
    for _ in range(2):
        c0 = time.process_time()  # CPU time: the machine may be shared
        out = cast(EventPacket, concat(feed(ContrastMax(), [tex.without_columns("vx", "vy")])))
        els.append(time.process_time() - c0)
    el = min(els)
    e = _score(out, tex, "full")
    rows.append({"method": f"contrast_max real-time factor at {rate:.2f} Mev/s (346x260, CPU time)",
                 "mev_s": len(tex) / el / 1e6, "cpu_mev_s": len(tex) / el / 1e6, "us_per_event": el / len(tex) * 1e6,
                 "realtime_factor": (dur * 1e-6) / el, "density": e["density"], "median_rel_pct": e["median_rel_pct"]})
    return rows


def accuracy(quick: bool) -> list[dict[str, Any]]:
    rows = []
    ref = _edges()
    tex = _edges(speed=800.0, angle=30.0, angles=(0.0, 60.0, 120.0), spacing=12, jitter_us=300.0)
    for name, (make, kind) in METHODS.items():
        scene, truth = ((ref, "reference edges 1000 px/s, 300 us jitter, 1 Hz/px (vs normal truth)") if kind == "normal"
                        else (tex, "texture 800 px/s, 300 us jitter, 1 Hz/px (vs full truth)"))
        rows.append({"method": name, "scene": truth, **_score(_run(make, scene), scene, kind)})
    for lname, lmake in LIFETIMES.items():
        out = lmake().process(ref.without_columns("lifetime"))[0]
        e = lifetime_errors(out["lifetime"], ref["lifetime"], ref["noise"])
        rows.append({"method": lname, "scene": "reference edges (vs 1/|normal speed|)",
                     "median_rel_pct": e["median_rel_pct"], "rel_aee_pct": e["mean_rel_pct"], "density": e["density"],
                     "noise_valid": e["noise_valid"]})
    rows += _simulated(quick)
    rows += _imu_rotation(quick)
    return rows


#: simulator scenes scored (160x120, realistic sensor model)
SIM_SCENES = ("translation_edges", "moving_texture", "rotation")


def simulated_scene(scene: str, duration_us: int, sensor: str = "160x120", seed: int = 1) -> EventPacket:
    """A simulator run with the normal-flow truth added as ``nvx``/``nvy``
    (see :func:`tectum.evaluation.metrics.simulator_normal_truth`)."""
    from tectum.sources.simulate import simulate

    ev, truth = simulate(scene, duration_us=duration_us, seed=seed, preset="realistic", sensor=sensor,
                         truth_fps=2000.0)
    nvx, nvy = simulator_normal_truth(ev, truth["frame_t"], truth["frame_intensity"])
    return ev.with_columns(nvx=nvx.astype(np.float32), nvy=nvy.astype(np.float32))


def _simulated(quick: bool) -> list[dict[str, Any]]:
    try:
        import tectum.sources.simulate  # noqa: F401
    except ImportError:  # the simulator is optional here
        return []
    rows = []
    for scene in SIM_SCENES:
        ev = simulated_scene(scene, 100_000 if quick else 300_000)
        for name, (make, kind) in METHODS.items():
            rows.append({"method": name, "scene": f"simulate:{scene} realistic (vs {kind} truth)",
                         **_score(_run(make, ev), ev, kind)})
        life = np.where(np.isfinite(ev["lifetime"]), ev["lifetime"], np.nan)
        for lname, lmake in LIFETIMES.items():
            out = lmake().process(ev.without_columns("lifetime"))[0]
            e = lifetime_errors(out["lifetime"], life, (ev["noise"] != 0).astype(np.uint8))
            rows.append({"method": lname, "scene": f"simulate:{scene} realistic",
                         "median_rel_pct": e["median_rel_pct"], "rel_aee_pct": e["mean_rel_pct"],
                         "density": e["density"], "noise_valid": e["noise_valid"]})
    return rows


def _imu_rotation(quick: bool) -> list[dict[str, Any]]:
    """Real DAVIS240 recording, camera rolling at about 0.5 rad/s: flow from
    the gyro (focal 200 px assumed, principal point at the centre, camera z =
    -IMU z, gyro full scale fixed from gravity) as ground truth."""
    data = shared_data()
    path = data / "aedat" / "davis240_imu_rotdisk.aedat" if data else None
    if path is None or not path.exists():
        return []
    from tectum.evaluation.imu_truth import (
        full_flow_vs_rotation,
        gyro_flow,
        imu_full_scale_factor,
        normal_flow_vs_rotation,
        read_events_and_imu,
    )

    ev, imu = read_events_and_imu(str(path))
    if quick:
        ev = ev.slice_time(int(ev.t[0]), int(ev.t[0]) + 1_000_000)
    tx, ty = gyro_flow(ev, imu, 200.0, 119.5, 89.5, axes=np.diag([1.0, 1.0, -1.0]),
                       scale=imu_full_scale_factor(imu))
    rows = []
    for name, (make, kind) in METHODS.items():
        out = cast(EventPacket, concat(feed(make(), [ev])))
        if kind == "normal":
            r = normal_flow_vs_rotation(out["vx"], out["vy"], out["valid"], tx, ty)
            rows.append({"method": name, "scene": "davis240 rotdisk + gyro (normal vs projected truth)",
                         "median_rel_pct": r["median_rel_pct"], "median_ratio": r["median_ratio"],
                         "sign_agree": r["sign_agree"], "density": r["density"]})
        else:
            r = full_flow_vs_rotation(out["vx"], out["vy"], out["valid"], tx, ty)
            rows.append({"method": name, "scene": "davis240 rotdisk + gyro (vs full truth)", **r})
    return rows


SWEEPS: dict[str, tuple[str, list[float]]] = {
    "noise_hz": ("noise rate (Hz/px)", [0.1, 1, 5, 20, 50, 100]),
    "speed": ("speed (px/s)", [1, 10, 50, 200, 1000, 2000, 5000]),
    "spacing": ("texture: edge spacing (px)", [3, 5, 8, 16, 32]),
    "angle": ("edge orientation (deg)", [0, 15, 30, 45, 60, 75, 90]),
    "threshold": ("contrast threshold (log)", [0.05, 0.1, 0.2, 0.4, 0.6, 0.8]),
}


def _sweep_scene(param: str, value: float, kind: str) -> EventPacket:
    kw: dict[str, Any] = {"speed": 500.0, "jitter_us": 100.0, "noise_hz": 1.0}
    if kind == "full":
        kw.update(angles=(0.0, 60.0, 120.0), spacing=12.0)
    if param == "noise_hz":
        kw["noise_hz"] = value
    elif param == "speed":
        kw["speed"] = value
    elif param == "spacing":
        kw["spacing"] = value
    elif param == "angle":
        kw["angle"] = value
        if kind == "full":
            kw["angles"] = (value, value + 60.0, value + 120.0)
    elif param == "threshold":
        kw["threshold"] = value
    sp = kw["speed"]
    dur = int(np.clip(40 / sp * 1e6, 30_000, 2_000_000))
    kw["duration_us"] = dur
    if sp < 100:  # slow: long windows, smaller sensor to keep it short
        kw["sensor"] = (48, 48)
    return _edges(**kw)


def failure_maps(quick: bool) -> dict[str, Any]:
    methods = {k: v for k, v in METHODS.items() if "robust 5x5" not in k}
    maps: dict[str, Any] = {}
    for param, (label, values) in SWEEPS.items():
        if quick:
            values = values[::2] + ([values[-1]] if len(values) % 2 == 0 else [])
        per: dict[str, list[dict[str, float]]] = {}
        for name, (make, kind) in methods.items():
            per[name] = []
            for v in values:
                scene = _sweep_scene(param, v, kind)
                per[name].append(_score(_run(make, scene), scene, kind))
        maps[param] = {"label": label, "values": values, "results": per, "boundary": _boundaries(values, per)}
    return maps


def _boundaries(values: list[float], per: dict[str, list[dict[str, float]]]) -> dict[str, str]:
    out = {}
    for name, res in per.items():
        err = np.array([r["median_rel_pct"] for r in res], np.float64)
        dens = np.array([r["density"] for r in res])
        if not np.isfinite(err).any():
            out[name] = "never valid"
            continue
        best_e, best_d = np.nanmin(err), dens.max()
        worse = ~np.isfinite(err) | (err > 2 * max(best_e, 2.5))
        bad = [(v, "error x2" if w else "density /2") for v, w, d in zip(values, worse, dens) if w or d < best_d / 2]
        out[name] = ", ".join(f"{v:g} ({why})" for v, why in bad) or "none in range"
    return out


def _charts(out: Path, acc: list[dict[str, Any]], spd: list[dict[str, Any]], maps: dict[str, Any]) -> list[str]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing (pip install tectum[charts]): no charts")
        return []
    files = []
    fig, ax = plt.subplots(figsize=(7, 5))
    speeds = {r["method"]: r["mev_s"] for r in spd}
    for r in acc:  # the synthetic scenes (the IMU rows have no relative AEE)
        if r["method"] in METHODS and r["scene"].startswith(("reference", "texture")):
            ax.scatter(speeds[r["method"]], r["rel_aee_pct"], s=40)
            ax.annotate(f"{r['method']} ({METHODS[r['method']][1]})", (speeds[r["method"]], r["rel_aee_pct"]),
                        fontsize=7, xytext=(4, 4), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("speed (Mev/s, one core)")
    ax.set_ylabel("relative AEE (%)")
    ax.set_title("flow: speed vs accuracy (normal flow vs normal truth; full vs full)")
    fig.tight_layout()
    p = out / "flow-speed-vs-aee.png"
    fig.savefig(p, dpi=120)
    plt.close(fig)
    files.append(str(p))
    for param, m in maps.items():
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
        for name, res in m["results"].items():
            a1.plot(m["values"], [r["median_rel_pct"] for r in res], marker="o", label=name)
            a2.plot(m["values"], [r["density"] for r in res], marker="o", label=name)
        for a in (a1, a2):
            a.set_xlabel(m["label"])
            if param in ("noise_hz", "speed", "threshold"):
                a.set_xscale("log")
        a1.set_ylabel("median relative error (%)")
        a1.set_yscale("log")
        a2.set_ylabel("density (signal events with a flow)")
        a2.legend(fontsize=7)
        fig.suptitle(f"failure map: {m['label']}")
        fig.tight_layout()
        p = out / f"flow-failure-{param}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        files.append(str(p))
    return files


def run(out: Path, quick: bool) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    spd = speed(quick)
    print(table(spd, ["method", "mev_s", "cpu_mev_s", "us_per_event", "realtime_factor", "density", "median_rel_pct"]))
    acc = accuracy(quick)
    print(table(acc, ["method", "scene", "aee", "rel_aee_pct", "median_rel_pct", "aae_deg", "density",
                      "noise_valid", "median_ratio", "sign_agree"]))
    maps = failure_maps(quick)
    bounds = [{"sweep": m["label"], "method": k, "fails at": v}
              for m in maps.values() for k, v in m["boundary"].items()]
    print(table(bounds, ["sweep", "method", "fails at"]))
    charts = _charts(out, acc, spd, maps)
    for c in charts:
        print("chart:", c)
    return {"speed": spd, "accuracy": acc, "failure_maps": maps, "charts": charts}
