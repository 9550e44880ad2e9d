"""``tectum bench map``, part ``reconstruction``: ``map.high_pass`` and
``map.complementary`` (Scheerlinck et al., ACCV 2018) against the truth.

* speed: Mev/s of ``map.high_pass`` and ``map.complementary`` (operators,
  maps every 10 ms, frames at 30 fps) and of the kernel alone, one core, on
  a 346x260 textured scene; wall clock and CPU time (the machine may be
  shared: CPU time is the one-core figure).
* accuracy on the simulator: maps at the truth's instants (``at_us`` = the
  truth frames, 100 Hz, from 100 ms on: the filter's memory is 1/α = 67 ms)
  against the true log intensity ``log(I + 1e-3)``; median over the maps of
  Pearson, SSIM and MSE after the affine fit (the high-pass filter knows
  log intensity up to an offset and a scale). Scored on the whole image
  (``all``): on the textured scenes (rotation, 6-DoF plane) every pixel
  sees events, so the whole image is what the filter claims; and on the
  pixels with an event in the last ``1/α`` (``recent``, confidence ≥ 1/e),
  which is what it can know where the scene has static parts: it loses the
  DC, a pixel that sees no event reads 0. The target (Pearson ≥ 0.6) is on
  the whole image of the clean (``ideal``) textured scenes.
* ``map.complementary`` on DAVIS scenes (APS frames at 30 Hz, 5 ms exposure,
  1 DN read noise): against the frames alone (the latest frame held) and
  the high-pass filter; MSE also without the fit (the frames give the level).
* failure map on the rotation scene: noise rate, wrong contrast (the
  operator's ``c_on`` off by a factor, ``c_off`` right), rotation speed and
  texture contrast, one at a time from the clean scene.
* real data, ``ecd/slider_depth`` (DAVIS240C): EVREAL's protocol (no
  histogram equalisation, maps at the APS frames' timestamps) against the
  log of the APS frames; the complementary filter is fed the even frames
  and scored on the odd ones (held out; scored on the frames it fused, it
  would score itself). Skipped when the shared data is absent.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from tectum import EventPacket, FramePacket, Kind, MapPacket, concat
from tectum.evaluation.harness import shared_data, table, target, throughput
from tectum.evaluation.metrics.maps import intensity_scores
from tectum.plugins.map import Complementary, HighPass
from tectum.plugins.map._integrate import integrate_events, new_state
from tectum.testing import feed_ports

EPS = 1e-3        #: the simulator's L = log(I + eps)
SKIP_US = 100_000  #: maps before this are not scored (the filter starts empty)


def _maps(op: HighPass, ev: EventPacket, frames: FramePacket | None = None) -> MapPacket:
    ports: dict[str, list[Any]] = {"events": [ev]}
    if frames is not None:
        ports["frames"] = [frames]
    out = concat(feed_ports(op, ports))
    assert isinstance(out, MapPacket)
    return out


def _median(scores: list[dict[str, float]]) -> dict[str, float]:
    keys = scores[0].keys() if scores else ()
    return {k: float(np.nanmedian([s[k] for s in scores])) for k in keys}


def _score(maps: MapPacket, truth_log: np.ndarray, recent: bool = False) -> dict[str, float]:
    out = []
    for k in range(len(maps)):
        mask = maps.confidence[k] >= np.exp(-1.0) if recent else None
        s = intensity_scores(maps.image[k], truth_log[k], mask)
        if recent:
            s["coverage"] = float(mask.mean())  # type: ignore[union-attr]
        out.append(s)
    return _median(out)


def _simulate(scene: str | Mapping[str, Any], sensor: str, duration_us: int, preset: str = "ideal",
              **model: Any) -> tuple[EventPacket, np.ndarray, np.ndarray, Any]:
    """Events, the truth instants from ``SKIP_US`` on and their log intensity, and the Truth."""
    from tectum.sources.simulate import simulate

    ev, truth = simulate(scene, duration_us=duration_us, sensor=sensor, truth_fps=100.0, seed=1, preset=preset,
                         **model)
    ft = np.asarray(truth["frame_t"])
    keep = ft >= SKIP_US
    return ev.without_columns(*ev.columns), ft[keep], np.log(np.asarray(truth["frame_intensity"])[keep] + EPS), truth


def _hp(ev: EventPacket, at: np.ndarray, **kw: Any) -> MapPacket:
    return _maps(HighPass(at_us=tuple(int(v) for v in at), **kw), ev)


# -- speed ----------------------------------------------------------------------------------
def speed(quick: bool) -> list[dict[str, Any]]:
    from tectum.sources.simulate import simulate

    ev, _ = simulate("moving_texture", duration_us=100_000 if quick else 300_000, sensor="346x260", seed=1)
    ev = ev.without_columns(*ev.columns)
    rows = []

    def kernel() -> None:
        D, tl = new_state(ev.sensor)
        integrate_events(ev.t, ev.x, ev.y, ev.p, D, tl, 15e-6, 0.2, 0.2)

    tf = np.arange(ev.t_start, ev.t_end, 33_333, dtype=np.int64)  # 30 fps; the content does not matter here
    images = np.random.default_rng(0).integers(0, 256, (len(tf), 260, 346)).astype(np.uint8)
    fr = FramePacket(tf, images=images, t_start=ev.t_start, t_end=ev.t_end)
    for name, fn in (("map.high_pass (maps every 10 ms)", lambda: _maps(HighPass(), ev)),
                     ("map.complementary (30 fps frames, maps every 10 ms)", lambda: _maps(Complementary(), ev, fr)),
                     ("integrate_events kernel alone", kernel)):
        r = throughput(fn, len(ev), repeat=3 if quick else 5)
        rows.append({"method": name, "scene": "moving_texture 346x260", "events": len(ev), "mev_s": r["mev_s"],
                     "cpu_mev_s": r["cpu_mev_s"], "ns_per_event": 1e3 / r["cpu_mev_s"]})
    return rows


# -- accuracy on the simulator ------------------------------------------------------------------
SCENES = ("rotation", "plane_6dof", "shapes", "translation_edges")
TEXTURED = ("rotation", "plane_6dof")


def accuracy(quick: bool, sensor: str, duration_us: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    rows, pics = [], []
    for preset in ("ideal", "realistic"):
        for scene in SCENES:
            ev, at, truth_log, _ = _simulate(scene, sensor, duration_us, preset)
            maps = _hp(ev, at)
            for region in ("all", "recent"):
                s = _score(maps, truth_log, recent=region == "recent")
                rows.append({"method": "high_pass", "scene": scene, "preset": preset, "pixels": region,
                             "pearson": s["pearson"], "ssim": s["ssim"], "mse_affine": s["mse_affine"],
                             "coverage": s["coverage"]})
            if preset == "ideal" and scene == "rotation":
                pics.append({"title": f"{scene} ({preset})", "truth": truth_log[-1], "high_pass": maps.image[-1]})
    return rows, pics


def _davis(scene: str, sensor: str) -> dict[str, Any]:
    from tectum.sources.simulate import load_scene

    d = load_scene(scene, sensor)
    d["davis"] = {"aps_rate_hz": 30.0, "exposure_us": 5000.0, "aps_noise": 1.0}
    return d


def complementary(quick: bool, sensor: str, duration_us: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    rows, pics = [], []
    for scene in ("plane_6dof", "translation_edges"):
        ev, at, truth_log, truth = _simulate(_davis(scene, sensor), sensor, duration_us, "realistic")
        fr = FramePacket(np.asarray(truth["aps_t"]), images=np.asarray(truth["aps_images"]), t_start=ev.t_start,
                         t_end=ev.t_end)
        comp = _maps(Complementary(at_us=tuple(int(v) for v in at)), ev, fr)
        held_idx = np.searchsorted(fr.t, at, side="right") - 1
        held = np.log(fr.images[np.maximum(held_idx, 0)] / 255.0 + 1.0 / 255).astype(np.float32)
        held[held_idx < 0] = np.nan
        hp = _hp(ev, at)
        for name, images in (("complementary", comp.image), ("frames held", held), ("high_pass", hp.image)):
            s = _median([intensity_scores(images[k], truth_log[k]) for k in range(len(at))])
            rows.append({"method": name, "scene": f"{scene} DAVIS 30 fps", "preset": "realistic",
                         "pearson": s["pearson"], "ssim": s["ssim"], "mse_affine": s["mse_affine"], "mse": s["mse"]})
        pics.append({"title": f"{scene} DAVIS 30 fps (realistic)", "truth": truth_log[-1], "high_pass": hp.image[-1],
                     "complementary": comp.image[-1], "frame held": held[-1]})
    return rows, pics


# -- failure map ------------------------------------------------------------------------------
def _rotation_scene(speed: float, contrast: float, sensor: str) -> dict[str, Any]:
    from tectum.sources.simulate import load_scene

    d = load_scene("rotation", sensor)
    m = d["motion"]
    for k in ("angular_velocity", "rotation_amplitude"):
        m[k] = [speed * v for v in m[k]]
    d["panorama"]["texture"]["contrast"] = contrast
    return d


def failure_map(quick: bool, sensor: str, duration_us: int) -> list[dict[str, Any]]:
    sweeps: dict[str, tuple[float, ...]] = {
        "noise Hz/px": (0.0, 1.0, 5.0) if quick else (0.0, 1.0, 3.0, 10.0, 30.0),
        "c_on / true C": (0.5, 1.0, 1.5) if quick else (0.5, 0.75, 1.0, 1.25, 1.5, 2.0),
        "rotation speed x": (0.25, 1.0, 2.0) if quick else (0.1, 0.25, 0.5, 1.0, 2.0),
        "texture contrast": (0.15, 0.6) if quick else (0.1, 0.2, 0.4, 0.6, 0.8),
    }
    rows = []
    base: dict[str, Any] | None = None
    for axis, values in sweeps.items():
        for v in values:
            speed = v if axis == "rotation speed x" else 1.0
            contrast = v if axis == "texture contrast" else 0.6
            noise = v if axis == "noise Hz/px" else 0.0
            c_scale = v if axis == "c_on / true C" else 1.0
            clean = speed == 1.0 and contrast == 0.6 and noise == 0.0
            if clean and base is not None:
                ev, at, truth_log = base["ev"], base["at"], base["truth_log"]
            else:
                ev, at, truth_log, _ = _simulate(_rotation_scene(speed, contrast, sensor), sensor, duration_us,
                                                 "ideal", shot_noise_hz=noise)
                if clean:
                    base = {"ev": ev, "at": at, "truth_log": truth_log}
            s = _score(_hp(ev, at, c_on=0.2 * c_scale), truth_log)
            rows.append({"axis": axis, "value": v, "pearson": s["pearson"], "ssim": s["ssim"],
                         "mse_affine": s["mse_affine"], "events": len(ev)})
    return rows


# -- real data ------------------------------------------------------------------------------------
def ecd() -> list[dict[str, Any]]:
    data = shared_data()
    path = data / "ecd" / "slider_depth" / "events.txt" if data else None
    if path is None or not path.exists() or not (path.parent / "images.txt").exists():
        print("ecd/slider_depth absent: no real-data rows")
        return []
    import tectum
    from tectum.testing import ListSink

    p = tectum.Pipeline()
    sink = ListSink()
    p.sink(sink, p.source(str(path)))  # events and, from images.txt beside them, the APS frames
    tectum.run(p)
    by: dict[Kind, list[Any]] = {}
    for q in sink.packets:
        by.setdefault(q.kind, []).append(q)
    ev, fr = concat(by[Kind.EVENTS]), concat(by[Kind.FRAMES])
    assert isinstance(ev, EventPacket) and isinstance(fr, FramePacket)
    inside = (fr.t > ev.t[0]) & (fr.t <= ev.t[-1])

    def log_aps(images: np.ndarray) -> np.ndarray:
        return np.log(images / 255.0 + 1.0 / 255)

    rows = []
    hp = _hp(ev, fr.t[inside])
    s = _median([intensity_scores(m, L) for m, L in zip(hp.image, log_aps(fr.images[inside]))])
    rows.append({"method": "high_pass", "frames scored": int(inside.sum()), **_pick(s)})
    even = FramePacket(fr.t[::2], images=fr.images[::2], t_start=fr.t_start, t_end=fr.t_end)
    odd = np.flatnonzero(inside & (np.arange(len(fr)) % 2 == 1))
    comp = _maps(Complementary(at_us=tuple(int(v) for v in fr.t[odd])), ev, even)
    s = _median([intensity_scores(m, L) for m, L in zip(comp.image, log_aps(fr.images[odd]))])
    rows.append({"method": "complementary (even frames in, odd scored)", "frames scored": len(odd), **_pick(s)})
    prev = log_aps(fr.images[odd - 1]).astype(np.float32)
    s = _median([intensity_scores(m, L) for m, L in zip(prev, log_aps(fr.images[odd]))])
    rows.append({"method": "previous frame held (baseline)", "frames scored": len(odd), **_pick(s)})
    return [{"recording": "ecd/slider_depth", **r} for r in rows]


def _pick(s: dict[str, float]) -> dict[str, float]:
    return {k: s[k] for k in ("pearson", "ssim", "mse_affine", "mse")}


# -- pictures -------------------------------------------------------------------------------------------
def _pictures(out: Path, pics: list[dict[str, Any]], fail: list[dict[str, Any]],
              tradeoff: list[tuple[str, float, float]]) -> list[str]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib missing (pip install tectum[charts]): no pictures")
        return []
    out.mkdir(parents=True, exist_ok=True)
    written = []
    cols = max(len(p) - 1 for p in pics)
    fig, axes = plt.subplots(len(pics), cols, figsize=(3.2 * cols, 2.6 * len(pics)), squeeze=False)
    for row, p in zip(axes, pics):
        for ax, (name, img) in zip(row, [(k, v) for k, v in p.items() if k != "title"]):
            ax.imshow(img, cmap="gray")
            ax.set_title(f"{p['title']}\n{name}" if name == "truth" else name, fontsize=8)
        for ax in row:
            ax.axis("off")
    fig.tight_layout()
    path = out / "map_reconstruction.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(str(path))
    axes_names = list(dict.fromkeys(r["axis"] for r in fail))
    fig, axs = plt.subplots(1, len(axes_names), figsize=(3.2 * len(axes_names), 2.8), squeeze=False)
    for ax, name in zip(axs[0], axes_names):
        rs = [r for r in fail if r["axis"] == name]
        ax.plot([r["value"] for r in rs], [r["pearson"] for r in rs], "o-", label="Pearson")
        ax.plot([r["value"] for r in rs], [r["ssim"] for r in rs], "s--", label="SSIM")
        ax.axhline(0.6, color="grey", lw=0.8)
        ax.set_xlabel(name)
        ax.set_ylim(0, 1)
    axs[0][0].legend(fontsize=8)
    axs[0][0].set_title("map.high_pass failure map (rotation, ideal)", fontsize=8, loc="left")
    fig.tight_layout()
    path = out / "map_reconstruction_failure.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(str(path))
    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    for name, mev, r in tradeoff:
        ax.scatter([mev], [r])
        ax.annotate(name, (mev, r), fontsize=7, xytext=(4, 4), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("Mev/s, one core (CPU time)")
    ax.set_ylabel("median Pearson (realistic plane_6dof)")
    ax.set_ylim(0, 1)
    fig.tight_layout()
    path = out / "map_reconstruction_speed_accuracy.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(str(path))
    return written


def run(out: Path, quick: bool) -> dict[str, Any]:
    sensor, duration = ("96x72", 300_000) if quick else ("240x180", 600_000)
    spd = speed(quick)
    print(table(spd, ["method", "scene", "events", "mev_s", "cpu_mev_s", "ns_per_event"]))
    acc, pics = accuracy(quick, sensor, duration)
    print(f"\nsimulator {sensor}, {duration // 1000} ms, maps at the truth's 100 Hz instants from "
          f"{SKIP_US // 1000} ms on; medians over the maps")
    print(table(acc, ["method", "scene", "preset", "pixels", "pearson", "ssim", "mse_affine", "coverage"]))
    comp, cpics = complementary(quick, sensor, duration)
    print()
    print(table(comp, ["method", "scene", "preset", "pearson", "ssim", "mse_affine", "mse"]))
    fail = failure_map(quick, sensor, duration)
    print("\nfailure map (rotation, ideal; one axis at a time from speed 1, contrast 0.6, no noise, right C)")
    print(table(fail, ["axis", "value", "pearson", "ssim", "mse_affine", "events"]))
    real = ecd()
    if real:
        print()
        print(table(real, ["recording", "method", "frames scored", "pearson", "ssim", "mse_affine", "mse"]))
    on_plane = {r["method"]: r["pearson"] for r in comp if r["scene"].startswith("plane_6dof")}
    tradeoff = [("map.high_pass", spd[0]["cpu_mev_s"], on_plane["high_pass"]),
                ("map.complementary", spd[1]["cpu_mev_s"], on_plane["complementary"])]
    charts = _pictures(out, pics + cpics, fail, tradeoff)
    clean = [r["pearson"] for r in acc if r["preset"] == "ideal" and r["scene"] in TEXTURED and r["pixels"] == "all"]
    targets = [
        target("high_pass median Pearson, clean textured scenes (worst of rotation, plane_6dof; whole image)",
               min(clean), 0.6, ""),
        target("high_pass speed, one core (CPU time, maps every 10 ms, 346x260)", spd[0]["cpu_mev_s"], 50.0,
               "Mev/s"),
    ]
    return {"rows": spd + acc + comp + fail + real, "speed": spd, "accuracy": acc, "complementary": comp,
            "failure_map": fail, "real": real, "charts": charts, "targets": targets}
