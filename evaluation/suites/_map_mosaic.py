"""The ``mosaic`` part of ``tectum bench map``: ``map.poisson_mosaic`` on the
simulator's ``rotation`` scene (a panorama texture under pure rotation)
against the panorama itself (:mod:`tectum.evaluation.panorama`), scored on
the observed pixels (Pearson, SSIM of the affinely fitted mosaic), with the
share of the swept panorama observed; a failure map (sensor noise, wrong
contrast C, rotation speed, pose noise, added translation); speed of the
event part (Mev/s, one core) and of the Poisson solve per panorama size;
speed against accuracy over ``pano_width`` and ``emit_us``; a picture of
the mosaic above the truth (``map_mosaic.png``) and charts of the failure
map and of speed against accuracy (``mosaic_failure.png``,
``mosaic_speed_vs_accuracy.png``, when matplotlib is installed).

Translation. The ``rotation`` scene's panorama is at infinity, where
translation changes nothing, so the translation rows use a room instead: six
textured walls (5 x 3 x 5 m, the camera starting at its centre; median
range of the swept pixels 2.8 m), the ``rotation`` scene's rotation plus a lateral
(x) translation at constant speed reaching ``T`` m at the end. The truth is
the room ray-cast from the first camera centre
(:func:`tectum.evaluation.panorama.cast_panorama`): the mosaic's convention
puts the world at the first pose, and under translation no single
panorama exists, so the start is where the mosaic "should" be seen from
(the mean position would halve the parallax; the first is the convention).
The room without translation is also the check of that truth. Rows give
``T`` over the median range of the swept pixels (``t_over_depth``) and the
Pearson against the room's mosaic without translation (``vs_still``), a
truth-free measure of what translation alone changes; ``parallax_px`` is
that ratio in panorama pixels (the angle a point at the median depth moves
by over the run, over 2π/``pano_width``)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from tectum import EventPacket, PosePacket
from tectum.camera import quat_conj, quat_mul, quat_to_rot, rot_to_quat, so3_exp
from tectum.evaluation.harness import table, target
from tectum.evaluation.metrics.maps import intensity_scores, pearson
from tectum.evaluation.panorama import cast_panorama, swept_mask, truth_panorama
from tectum.plugins.map._panorama import INFO_FIELDS
from tectum.plugins.map._poisson import poisson_solve
from tectum.plugins.map.poisson_mosaic import PoissonMosaic, mosaic_image
from tectum.sinks.display.maps import intensity_picture
from tectum.sources.simulate import load_scene, simulate
from tectum.sources.simulate.scenes import compile_scene

WIDTH = 1024  # the texture's own resolution: one texel per panorama pixel


def _run_case(scene: dict[str, Any], duration_us: int, preset: str = "ideal", seed: int = 1,
              ) -> tuple[EventPacket, PosePacket, tuple[float, float, float]]:
    ev, tr = simulate(scene, duration_us, seed=seed, preset=preset)
    poses = PosePacket(tr["pose_t"], position=tr["pose_position"], orientation=tr["pose_orientation"])
    f, cx, cy = (float(v) for v in tr["camera"])
    return ev, poses, (f, cx, cy)


def _mosaic(ev: EventPacket, poses: PosePacket, cam: tuple[float, float, float], width: int = WIDTH,
            emit_us: int = 10**12, **kw: Any) -> tuple[np.ndarray, PoissonMosaic, float, float]:
    """The last mosaic, the operator, the seconds spent on the events (with
    the emissions inside the stream) and in all (with the last emission)."""
    f, cx, cy = cam
    op = PoissonMosaic(calib=f"{f};{f};{cx};{cy}", pano_width=width, emit_us=emit_us, **kw)
    op.warmup()
    op.process_ports({"poses": poses})
    t0 = time.perf_counter()
    out = op.process_ports({"events": ev})
    dt = time.perf_counter() - t0
    out += op.finish()
    return out[-1].image[0], op, dt, time.perf_counter() - t0


_TRUTH: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}


def _swept(poses: PosePacket, cam: tuple[float, float, float], sensor: tuple[int, int], width: int) -> np.ndarray:
    q = np.asarray(poses.orientation)
    rel = quat_to_rot(np.asarray(quat_mul(quat_conj(q[0]), q[:: max(1, len(q) // 40)])).reshape(-1, 4))
    return swept_mask(width, rel, cam[0], cam[1], cam[2], sensor)


def _score(img: np.ndarray, scene: dict[str, Any], poses: PosePacket, cam: tuple[float, float, float],
           sensor: tuple[int, int]) -> dict[str, float]:
    width = img.shape[1]
    key = (id(poses), width)
    if key not in _TRUTH:  # the truth and the swept pixels of one run, computed once
        truth = truth_panorama(compile_scene(scene), width, quat_to_rot(np.asarray(poses.orientation)[0]))
        _TRUTH[key] = truth, _swept(poses, cam, sensor, width)
    return _scores(img, *_TRUTH[key])


def _scores(img: np.ndarray, truth: np.ndarray, swept: np.ndarray) -> dict[str, float]:
    s = intensity_scores(img, truth, swept)
    s["observed"] = float((np.isfinite(img) & swept).sum() / max(int(swept.sum()), 1))
    return s


def _noisy_poses(poses: PosePacket, sigma_rad: float, seed: int = 0) -> PosePacket:
    if sigma_rad == 0:
        return poses
    rng = np.random.default_rng(seed)
    jitter = rot_to_quat(so3_exp(rng.normal(0.0, sigma_rad, (len(poses), 3))))
    q = np.asarray(quat_mul(np.asarray(poses.orientation), jitter))
    return PosePacket(poses.t, position=poses.position, orientation=q)


def room_scene(sensor: tuple[int, int], translation_m: float, duration_us: int) -> dict[str, Any]:
    """Six textured walls around the start (x ±2.5, y ±1.5, z ±2.5 m; one
    noise texture each, 1.5 cm texels), the ``rotation`` scene's rotation and
    a lateral translation at constant speed, ``translation_m`` m at the end."""
    tex = {"kind": "noise", "size": 512, "blur": 1.5, "contrast": 0.6, "mean": 0.35}
    hx, hy, hz = 2.5, 1.5, 2.5
    walls = [([0, 0, hz], [0, 0, 0], 2 * hx, 2 * hy), ([0, 0, -hz], [0, np.pi, 0], 2 * hx, 2 * hy),
             ([hx, 0, 0], [0, np.pi / 2, 0], 2 * hz, 2 * hy), ([-hx, 0, 0], [0, -np.pi / 2, 0], 2 * hz, 2 * hy),
             ([0, hy, 0], [np.pi / 2, 0, 0], 2 * hx, 2 * hz), ([0, -hy, 0], [-np.pi / 2, 0, 0], 2 * hx, 2 * hz)]
    planes = [{"center": c, "orientation": o, "size": [a, b], "texture": {**tex, "seed": 10 + i}, "texel_m": 0.015}
              for i, (c, o, a, b) in enumerate(walls)]
    motion = dict(load_scene("rotation", sensor)["motion"])
    motion["velocity"] = [translation_m / (duration_us * 1e-6), 0.0, 0.0]
    return load_scene({"name": "room", "sensor": list(sensor), "planes": planes, "motion": motion})


def _translation(sensor: tuple[int, int], dur: int, values: tuple[float, ...]) -> list[dict[str, Any]]:
    """Failure-map rows for added translation ``values`` (m; the first, 0,
    is the still run the others are compared with; see the module docstring)."""
    rows: list[dict[str, Any]] = []
    still: np.ndarray | None = None
    swept = np.zeros(0, bool)
    for T in values:
        scene = room_scene(sensor, T, dur)
        ev, poses, cam = _run_case(scene, dur)
        img, _, _, _ = _mosaic(ev, poses, cam)
        R0 = quat_to_rot(np.asarray(poses.orientation)[0])
        truth, rng = cast_panorama(compile_scene(scene), WIDTH, R0, np.asarray(poses.position)[0])
        if still is None:  # the same rotation in every run: the same swept pixels
            still, swept = img, _swept(poses, cam, sensor, WIDTH)
        depth = float(np.median(rng[swept & np.isfinite(rng)]))
        rows.append({"factor": "translation m (room)", "value": T, **_scores(img, truth, swept),
                     "t_over_depth": T / depth, "depth_m": depth, "parallax_px": T / depth / (2 * np.pi / WIDTH),
                     "vs_still": pearson(img, still, swept)})
    return rows


def _tradeoff(ev: EventPacket, poses: PosePacket, cam: tuple[float, float, float], scene: dict[str, Any],
              sensor: tuple[int, int], quick: bool) -> list[dict[str, Any]]:
    """Pearson and Mev/s (all the operator's time, emissions included; the
    best of 2 (quick) or 3 runs: the machine may be shared) per panorama
    width and emission period on one run."""
    rows = []
    for w in (512, 1024, 2048):
        for e in ((10**12, 200_000) if quick else (10**12, 200_000, 50_000)):
            best = 0.0
            for _ in range(2 if quick else 3):
                img, op, _, total = _mosaic(ev, poses, cam, width=w, emit_us=e)
                best = max(best, op.counts["mapped"] / total / 1e6)
            rows.append({"pano_width": w, "emit_ms": "end" if e == 10**12 else e // 1000, "mev_s": best,
                         **_score(img, scene, poses, cam, sensor)})
    return rows


def _charts(out: Path, base: dict[str, float], fail: list[dict[str, Any]], trade: list[dict[str, Any]]) -> list[str]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.ticker import ScalarFormatter
    except ImportError:
        print("matplotlib missing (pip install tectum[charts]): no charts")
        return []
    # each factor from the clean run (its value there first), one panel each
    clean = {"C_off given (C_on 0.2, true 0.2)": 0.2, "pose noise rad": 0.0, "sensor preset (noise)": "ideal",
             "rotation speed x": 1.0}
    factors = [f for f in dict.fromkeys(r["factor"] for r in fail) if f in clean or f.startswith("translation")]
    fig, axes = plt.subplots(1, len(factors), figsize=(3.2 * len(factors), 3.2), squeeze=False)
    for ax, f in zip(axes[0], factors):
        rows = [r for r in fail if r["factor"] == f]
        if f in clean:  # the clean run in its place (first among the presets)
            rows = [{"value": clean[f], **base}, *rows]
            if not isinstance(clean[f], str):
                rows.sort(key=lambda r: float(r["value"]))
        if f.startswith("translation"):
            x = [100 * r["t_over_depth"] for r in rows]
            ax.set_xlabel("translation / median depth (%), room")
        else:
            x = list(range(len(rows))) if isinstance(rows[0]["value"], str) else [r["value"] for r in rows]
            ax.set_xlabel(f)
            if isinstance(rows[0]["value"], str):
                ax.set_xticks(x, [r["value"] for r in rows])
        ax.plot(x, [r["pearson"] for r in rows], "o-", label="Pearson")
        ax.plot(x, [r["ssim"] for r in rows], "s--", label="SSIM")
        if f.startswith("translation"):
            ax.plot(x, [r["vs_still"] for r in rows], "^:", label="vs mosaic without translation")
        ax.axhline(0.9, color="grey", lw=0.5)
        ax.set_ylim(0, 1)
    axes[0][0].legend(fontsize=7)
    axes[0][-1].legend(fontsize=7)
    fig.suptitle("map.poisson_mosaic failure map (one factor at a time from the clean run)")
    fig.tight_layout()
    p1 = out / "mosaic_failure.png"
    fig.savefig(p1, dpi=100)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for e in dict.fromkeys(r["emit_ms"] for r in trade):
        rows = [r for r in trade if r["emit_ms"] == e]
        ax.plot([r["mev_s"] for r in rows], [r["pearson"] for r in rows], "o-",
                label="emit at end only" if e == "end" else f"emit every {e} ms")
        for r in rows:
            ax.annotate(f"{r['pano_width']} ({100 * r['observed']:.0f}% seen)", (r["mev_s"], r["pearson"]),
                        fontsize=7, xytext=(4, 4 if e == "end" else -10), textcoords="offset points")
    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(ScalarFormatter())
    ax.set_xlabel("Mev/s (one core, emissions included)")
    ax.set_ylabel("Pearson against the panorama")
    ax.set_title("map.poisson_mosaic: speed vs accuracy (pano_width, emit_us)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    p2 = out / "mosaic_speed_vs_accuracy.png"
    fig.savefig(p2, dpi=100)
    plt.close(fig)
    return [str(p1), str(p2)]


def _picture(img: np.ndarray, truth_scene: dict[str, Any], poses: PosePacket, path: Path) -> None:
    truth = truth_panorama(compile_scene(truth_scene), WIDTH, quat_to_rot(np.asarray(poses.orientation)[0]))
    rows, cols = np.nonzero(np.isfinite(img))
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    est = intensity_picture(img[r0:r1, c0:c1])
    tru = intensity_picture(np.where(np.isfinite(img), truth, np.nan)[r0:r1, c0:c1])
    pic = np.vstack([est, np.full((4, est.shape[1], 3), 255, np.uint8), tru])
    scale = min(1.0, 480 / pic.shape[1])
    if scale < 1:
        pic = cv2.resize(pic, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(path), pic, [cv2.IMWRITE_PNG_COMPRESSION, 9])


def _solve_cost(repeat: int) -> list[dict[str, Any]]:
    rows = []
    rng = np.random.default_rng(0)
    for w in (512, 1024, 2048):
        info = np.abs(rng.standard_normal((w // 2, w, len(INFO_FIELDS))))
        g = rng.standard_normal((w // 2, w))
        best_all, best_solve = np.inf, np.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            poisson_solve(g, g, wrap_x=True)
            best_solve = min(best_solve, time.perf_counter() - t0)
            t0 = time.perf_counter()
            mosaic_image(info, 0.0025)
            best_all = min(best_all, time.perf_counter() - t0)
        rows.append({"pano": f"{w}x{w // 2}", "poisson_ms": best_solve * 1e3, "emission_ms": best_all * 1e3,
                     "state_MB": w * w // 2 * len(INFO_FIELDS) * 8 / 1e6})
    return rows


def run(out: Path, quick: bool) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    sensor = (128, 96) if quick else (346, 260)
    dur = 800_000 if quick else 2_000_000
    scene = load_scene("rotation", sensor)
    ev, poses, cam = _run_case(scene, dur)
    img, op, dt, _ = _mosaic(ev, poses, cam)
    base = _score(img, scene, poses, cam, sensor)
    speed = op.counts["mapped"] / dt / 1e6
    _picture(img, scene, poses, out / "map_mosaic.png")
    rows = [{"case": "clean", **base, "events": len(ev), "mev_s": speed}]
    print(table(rows, ["case", "pearson", "ssim", "observed", "mse_affine", "events", "mev_s"]))

    fail: list[dict[str, Any]] = []
    im, *_ = _mosaic(ev, poses, cam, contrast=0.4)  # a common C only scales the mosaic
    fail.append({"factor": "C_on = C_off given (true 0.2)", "value": 0.4, **_score(im, scene, poses, cam, sensor)})
    for c in ((0.1, 0.3) if quick else (0.1, 0.15, 0.25, 0.3)):  # ON and OFF unbalanced
        im, *_ = _mosaic(ev, poses, cam, contrast_off=c)
        fail.append({"factor": "C_off given (C_on 0.2, true 0.2)", "value": c, **_score(im, scene, poses, cam,
                                                                                        sensor)})
    for s in ((0.002, 0.01) if quick else (0.001, 0.002, 0.005, 0.01, 0.02)):
        im, *_ = _mosaic(ev, _noisy_poses(poses, s), cam)
        fail.append({"factor": "pose noise rad", "value": s, **_score(im, scene, poses, cam, sensor)})
    for preset in (("realistic",) if quick else ("realistic", "noisy")):
        e2, p2, c2 = _run_case(scene, dur, preset=preset)
        im, *_ = _mosaic(e2, p2, c2)
        fail.append({"factor": "sensor preset (noise)", "value": preset, **_score(im, scene, p2, c2, sensor)})
    for k in ((4.0,) if quick else (2.0, 4.0, 8.0)):
        fast = dict(scene)
        m = dict(scene["motion"])
        m["angular_velocity"] = [k * v for v in m["angular_velocity"]]
        m["rotation_freq_hz"] = [k * v for v in m["rotation_freq_hz"]]
        fast["motion"] = m
        e2, p2, c2 = _run_case(fast, int(dur / k))  # the same sweep, k times faster
        im, *_ = _mosaic(e2, p2, c2)
        fail.append({"factor": "rotation speed x", "value": k, **_score(im, fast, p2, c2, sensor)})
    print("\nfailure map (mosaic against the panorama, swept pixels)")
    print(table(fail, ["factor", "value", "pearson", "ssim", "observed"]))
    moves = (0.0, 0.01, 0.03, 0.1) if quick else (0.0, 0.005, 0.01, 0.02, 0.03, 0.05, 0.1, 0.3)
    move = _translation(sensor, dur, moves)
    print("\nadded translation (room, truth ray-cast from the first camera centre)")
    print(table(move, ["factor", "value", "depth_m", "t_over_depth", "parallax_px", "pearson", "ssim", "observed",
                       "vs_still"]))
    fail += move

    trade = _tradeoff(ev, poses, cam, scene, sensor, quick)
    print("\nspeed against accuracy (rotation scene; Mev/s of all the operator's time)")
    print(table(trade, ["pano_width", "emit_ms", "mev_s", "pearson", "ssim", "observed"]))
    charts = _charts(out, base, fail, trade)
    for chart in charts:
        print("chart:", chart)

    solve = _solve_cost(2 if quick else 5)
    print("\nper emission: 2x2 solves + Poisson (ms, one core), state memory")
    print(table(solve, ["pano", "poisson_ms", "emission_ms", "state_MB"]))
    targets = [
        target("mosaic Pearson (rotation scene, observed pixels)", base["pearson"], 0.9, ""),
        target("mosaic swept panorama observed", base["observed"], 0.5, ""),
        target("mosaic events (one core)", speed, 1.0, "Mev/s"),
    ]
    return {"rows": rows, "failure": fail, "tradeoff": trade, "solve": solve, "targets": targets,
            "sensor": list(sensor), "picture": "map_mosaic.png", "charts": charts}
