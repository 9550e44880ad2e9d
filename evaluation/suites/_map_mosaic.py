"""The ``mosaic`` part of ``tectum bench map``: ``map.poisson_mosaic`` on the
simulator's ``rotation`` scene (a panorama texture under pure rotation)
against the panorama itself (:mod:`tectum.evaluation.panorama`), scored on
the observed pixels (Pearson, SSIM of the affinely fitted mosaic), with the
share of the swept panorama observed; a failure map (sensor noise, wrong
contrast C, rotation speed, pose noise); speed of the event part (Mev/s,
one core) and of the Poisson solve per panorama size; a picture of the
mosaic above the truth (``map_mosaic.png``)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from tectum import EventPacket, PosePacket
from tectum.camera import quat_conj, quat_mul, quat_to_rot, rot_to_quat, so3_exp
from tectum.evaluation.harness import table, target
from tectum.evaluation.metrics.maps import intensity_scores
from tectum.evaluation.panorama import swept_mask, truth_panorama
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


def _mosaic(ev: EventPacket, poses: PosePacket, cam: tuple[float, float, float], **kw: Any) -> tuple[
        np.ndarray, PoissonMosaic, float]:
    f, cx, cy = cam
    op = PoissonMosaic(calib=f"{f};{f};{cx};{cy}", pano_width=WIDTH, emit_us=10**12, **kw)
    op.warmup()
    op.process_ports({"poses": poses})
    t0 = time.perf_counter()
    op.process_ports({"events": ev})
    dt = time.perf_counter() - t0
    out = op.finish()
    return out[-1].image[0], op, dt


_TRUTH: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _score(img: np.ndarray, scene: dict[str, Any], poses: PosePacket, cam: tuple[float, float, float],
           sensor: tuple[int, int]) -> dict[str, float]:
    if id(poses) not in _TRUTH:  # the truth and the swept pixels of one run, computed once
        q = np.asarray(poses.orientation)
        truth = truth_panorama(compile_scene(scene), WIDTH, quat_to_rot(q[0]))
        rel = quat_to_rot(np.asarray(quat_mul(quat_conj(q[0]), q[:: max(1, len(q) // 40)])).reshape(-1, 4))
        _TRUTH[id(poses)] = truth, swept_mask(WIDTH, rel, cam[0], cam[1], cam[2], sensor)
    truth, swept = _TRUTH[id(poses)]
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
    img, op, dt = _mosaic(ev, poses, cam)
    base = _score(img, scene, poses, cam, sensor)
    speed = op.counts["mapped"] / dt / 1e6
    _picture(img, scene, poses, out / "map_mosaic.png")
    rows = [{"case": "clean", **base, "events": len(ev), "mev_s": speed}]
    print(table(rows, ["case", "pearson", "ssim", "observed", "mse_affine", "events", "mev_s"]))

    fail: list[dict[str, Any]] = []
    im, _, _ = _mosaic(ev, poses, cam, contrast=0.4)  # a common C only scales the mosaic
    fail.append({"factor": "C_on = C_off given (true 0.2)", "value": 0.4, **_score(im, scene, poses, cam, sensor)})
    for c in ((0.1, 0.3) if quick else (0.1, 0.15, 0.25, 0.3)):  # ON and OFF unbalanced
        im, _, _ = _mosaic(ev, poses, cam, contrast_off=c)
        fail.append({"factor": "C_off given (C_on 0.2, true 0.2)", "value": c, **_score(im, scene, poses, cam,
                                                                                        sensor)})
    for s in ((0.002, 0.01) if quick else (0.001, 0.002, 0.005, 0.01, 0.02)):
        im, _, _ = _mosaic(ev, _noisy_poses(poses, s), cam)
        fail.append({"factor": "pose noise rad", "value": s, **_score(im, scene, poses, cam, sensor)})
    for preset in (("realistic",) if quick else ("realistic", "noisy")):
        e2, p2, c2 = _run_case(scene, dur, preset=preset)
        im, _, _ = _mosaic(e2, p2, c2)
        fail.append({"factor": "sensor preset (noise)", "value": preset, **_score(im, scene, p2, c2, sensor)})
    for k in ((4.0,) if quick else (2.0, 4.0, 8.0)):
        fast = dict(scene)
        m = dict(scene["motion"])
        m["angular_velocity"] = [k * v for v in m["angular_velocity"]]
        m["rotation_freq_hz"] = [k * v for v in m["rotation_freq_hz"]]
        fast["motion"] = m
        e2, p2, c2 = _run_case(fast, int(dur / k))  # the same sweep, k times faster
        im, _, _ = _mosaic(e2, p2, c2)
        fail.append({"factor": "rotation speed x", "value": k, **_score(im, fast, p2, c2, sensor)})
    print("\nfailure map (mosaic against the panorama, swept pixels)")
    print(table(fail, ["factor", "value", "pearson", "ssim", "observed"]))

    solve = _solve_cost(2 if quick else 5)
    print("\nper emission: 2x2 solves + Poisson (ms, one core), state memory")
    print(table(solve, ["pano", "poisson_ms", "emission_ms", "state_MB"]))
    targets = [
        target("mosaic Pearson (rotation scene, observed pixels)", base["pearson"], 0.9, ""),
        target("mosaic swept panorama observed", base["observed"], 0.5, ""),
        target("mosaic events (one core)", speed, 1.0, "Mev/s"),
    ]
    return {"rows": rows, "failure": fail, "solve": solve, "targets": targets, "sensor": list(sensor),
            "picture": "map_mosaic.png"}
