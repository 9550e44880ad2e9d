"""``tectum bench tracker``, part ``angular``: ``tracker.angular_velocity``
against the simulator's true angular velocity and a real gyro.

* accuracy: the ``rotation`` scene's panorama (240x180, realistic sensor
  model, thresholds 0.4) turning at a constant rate about a fixed oblique
  axis, speeds up to 1000 °/s, clean and with 2 Hz/px uniform noise events
  added; per axis RMS error (rad/s and % of the peak rate) and the largest
  speed whose error stays under 10 %. The first 50 ms of every run are left
  out (the simulator references every pixel to the first image, a transient
  no real sensor has). Each estimate is scored against the truth averaged
  over its window.
* failure map: speed, noise rate, texture scale, added translation (a plane
  2 m away instead of the panorama), window size.
* real: ``aedat/davis240_imu_rotdisk.aedat`` against its gyro (camera =
  ``ROTDISK_CAMERA_FROM_IMU`` @ IMU = diag(-1, 1, -1), a half turn about y,
  measured: the estimates' x and z correlate with the gyro's at -0.94 and
  +0.99 under diag(1, 1, -1); DAVIS240 intrinsics assumed: f = 200 px,
  centre); the ECD ``*_rotation`` excerpts
  have no imu.txt in the shared data, so only their focus gain is shown.
* speed: real-time factor at 1 Mev/s on 240x180 on one core (CPU time),
  result every ``step_events`` events, per-window latency p50/p99.

Windows: 60,000 events sliding by 10,000, thinned to the operator's
``max_events`` (30,000): at 1 Mev/s a result every 10 ms from 60 ms of
events (30,000-event windows had 7-10 % error at 100 deg/s, too little
motion).

* reference: the ST-PPP authors' public code (:mod:`tectum.evaluation.reference_stppp`,
  its ``cmax`` and ``st-ppp`` methods, run where ``TECTUM_STPPP`` points at a
  clone and torch imports) on the same windows (30,000 events, back to back)
  of simulated rotations, against the truth, and on the ECD ``*_rotation``
  excerpts (one window each: the three estimates side by side); error and
  events/s per window (tectum CPU time, the reference's own wall-clock
  durations, one thread each).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from tectum import AngularVelocityPacket, EventPacket, concat
from tectum.evaluation.harness import shared_data, table, target

SENSOR = (240, 180)
WINDOW, STEP = 60_000, 10_000
AXIS = np.array([0.5, -0.8, 0.33]) / np.linalg.norm([0.5, -0.8, 0.33])
SKIP_US = 50_000
#: camera-from-IMU axes of the rotdisk recording (events read with a top-left origin)
ROTDISK_CAMERA_FROM_IMU = np.diag([-1.0, 1.0, -1.0])
#: batch size of the reference comparison (the reference's default)
REF_NE = 30_000


def _scene(speed_dps: float, tex_size: int = 256, translation: float = 0.0) -> dict[str, Any]:
    w = (AXIS * np.radians(speed_dps)).tolist()
    tex = {"kind": "noise", "size": tex_size, "blur": 1.5, "contrast": 0.6, "mean": 0.35}
    if translation:
        return {"planes": [{"center": [0, 0, 2.0], "texture": tex, "texel_m": 0.012}],
                "motion": {"angular_velocity": w, "velocity": [translation, 0.0, 0.0]}}
    return {"panorama": {"texture": tex, "texel_deg": 360 / 1024}, "motion": {"angular_velocity": w}}


def _simulate(scene: dict[str, Any], n_windows: int, noise_hz: float = 0.0,
              seed: int = 1) -> tuple[EventPacket, Any, str]:
    """Events after the start-up transient (about ``n_windows`` windows), the truth and the calibration."""
    from tectum.sources.simulate import make_simulator

    sim = make_simulator(scene, None, seed=seed, preset="realistic", sensor=SENSOR, c_on=0.4, c_off=0.4)
    parts, n = [], 0
    for ev, _side in sim.windows(5_000):
        if ev.t_start >= SKIP_US:
            parts.append(EventPacket.from_arrays(ev.t, ev.x, ev.y, ev.p, sensor=SENSOR, t_start=ev.t_start,
                                                 t_end=ev.t_end))
            n += len(ev)
            if n >= WINDOW + (n_windows - 1) * STEP:
                break
    ev = concat(parts)
    assert isinstance(ev, EventPacket)
    if noise_hz > 0:
        ev = _add_noise(ev, noise_hz, seed)
    f, cx, cy = sim.truth["camera"]
    return ev, sim.truth, f"{f};{f};{cx};{cy}"


def _add_noise(ev: EventPacket, rate_hz: float, seed: int) -> EventPacket:
    """``rate_hz`` uniform noise events per pixel per second added."""
    rng = np.random.default_rng(seed)
    w, h = ev.sensor
    n = rng.poisson(rate_hz * w * h * (ev.t_end - ev.t_start) * 1e-6)
    t = np.concatenate([ev.t, rng.integers(ev.t_start, ev.t_end, n)])
    x = np.concatenate([ev.x, rng.integers(0, w, n)])
    y = np.concatenate([ev.y, rng.integers(0, h, n)])
    p = np.concatenate([ev.p, rng.choice([-1, 1], n)])
    o = np.argsort(t, kind="stable")
    return EventPacket.from_arrays(t[o], x[o], y[o], p[o], sensor=ev.sensor, t_start=ev.t_start, t_end=ev.t_end)


def _estimate(ev: EventPacket, calib: str, window: int = WINDOW, step: int = STEP) -> tuple[AngularVelocityPacket,
                                                                                             list[float], float]:
    """Estimates, per-window CPU seconds (fed one step at a time) and total CPU s."""
    from tectum.plugins.tracker import AngularVelocity

    op = AngularVelocity(calib=calib, window_events=window, step_events=step)
    op.warmup()
    outs, lat = [], []
    c_all = time.process_time()
    n = len(ev)
    for a in range(0, n, step):
        b = min(a + step, n)
        piece = EventPacket.from_arrays(ev.t[a:b], ev.x[a:b], ev.y[a:b], ev.p[a:b], sensor=ev.sensor,
                                        t_start=int(ev.t[a]), t_end=int(ev.t[b - 1]) + 1 if b < n else ev.t_end)
        c0 = time.process_time()
        got = op.process(piece)
        if got:
            lat.append(time.process_time() - c0)
        outs += got
    total = time.process_time() - c_all
    return concat(outs), lat, total  # type: ignore[return-value]


def _truth_per_window(out: AngularVelocityPacket, ev: EventPacket, truth: Any, window: int) -> np.ndarray:
    """The true ω averaged over each estimate's window (from its first to its last event)."""
    tt, tw = truth["pose_t"], truth["pose_angular_velocity"]
    rows = []
    for t in out.t:
        last = int(np.searchsorted(ev.t, t, side="right")) - 1
        t0 = int(ev.t[max(0, last - window + 1)])
        sel = (tt >= t0) & (tt <= t)
        rows.append(tw[sel].mean(axis=0) if sel.any() else tw[np.searchsorted(tt, t) - 1])
    return np.array(rows)


def _score(out: AngularVelocityPacket, truth_w: np.ndarray) -> dict[str, float]:
    w = np.stack([out["wx"], out["wy"], out["wz"]], axis=1)
    err = w - truth_w
    peak = float(np.abs(truth_w).max())
    rms = np.sqrt((err ** 2).mean(axis=0))
    r: dict[str, float] = {"windows": len(out), "peak_rad_s": peak, "rms_rad_s": float(np.sqrt((err ** 2).mean()))}
    for k, a in enumerate("xyz"):
        r[f"rms_w{a}"] = float(rms[k])
        r[f"pct_w{a}"] = 100 * float(rms[k]) / peak
    r["pct_peak"] = max(r["pct_wx"], r["pct_wy"], r["pct_wz"])
    return r


def _case(label: str, scene: dict[str, Any], n_windows: int, noise_hz: float = 0.0,
          window: int = WINDOW) -> dict[str, Any]:
    ev, truth, calib = _simulate(scene, n_windows + (window - WINDOW) // STEP, noise_hz)
    out, lat, total = _estimate(ev, calib, window)
    return {"case": label, **_score(out, _truth_per_window(out, ev, truth, window)),
            "mev_s": len(ev) / max(total, 1e-9) / 1e6}


def accuracy(quick: bool) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    speeds = [100, 250, 500, 1000] if quick else [50, 100, 250, 500, 750, 1000]
    nw = 3 if quick else 8
    clean = [{"speed_dps": s, **_case(f"clean {s} deg/s", _scene(s), nw)} for s in speeds]
    noisy = [{"speed_dps": s, **_case(f"2 Hz/px noise {s} deg/s", _scene(s), nw, noise_hz=2.0)}
             for s in (speeds[1:] if quick else speeds)]
    return clean, noisy


def failure_map(quick: bool) -> list[dict[str, Any]]:
    nw = 3 if quick else 6
    rows = []
    for hz in ([20] if quick else [5, 10, 20, 50, 100]):
        rows.append({"factor": "noise Hz/px", "value": hz, **_case(f"noise {hz}", _scene(250), nw, noise_hz=hz)})
    for size in ([64] if quick else [64, 128, 512, 1024]):
        rows.append({"factor": "texture texels/360deg", "value": size,
                     **_case(f"texture {size}", _scene(250, size), nw)})
    for v in ([0.5] if quick else [0.2, 0.5, 1.0]):
        rows.append({"factor": "translation m/s at 2 m", "value": v,
                     **_case(f"translation {v}", _scene(250, translation=v), nw)})
    for win in ([20_000] if quick else [10_000, 20_000, 30_000, 120_000]):
        rows.append({"factor": "window events", "value": win, **_case(f"window {win}", _scene(250), nw, window=win)})
    return rows


def realtime(quick: bool) -> dict[str, Any]:
    """CPU time of a 1 Mev/s stream (a 240x180 rotation whose rate is 1 Mev/s),
    fed one step at a time: real-time factor and per-window latency."""
    ev, truth, calib = _simulate(_scene(150), 6 if quick else 20)
    rate = len(ev) / ((ev.t[-1] - ev.t[0]) * 1e-6) / 1e6
    out, lat, total = _estimate(ev, calib)
    stream_s = len(ev) / 1e6  # the same events at exactly 1 Mev/s
    ms = np.array(lat) * 1e3
    return {"case": f"240x180, window {WINDOW} step {STEP} (sim rate {rate:.2f} Mev/s, timed as 1 Mev/s)",
            "realtime_factor": stream_s / total, "result_every_ms": STEP / 1e3,
            "latency_p50_ms": float(np.percentile(ms, 50)), "latency_p99_ms": float(np.percentile(ms, 99)),
            "windows": len(out)}


def rotdisk(quick: bool) -> list[dict[str, Any]]:
    data = shared_data()
    path = data / "aedat" / "davis240_imu_rotdisk.aedat" if data else None
    if path is None or not path.exists():
        return []
    from tectum.evaluation.imu_truth import imu_full_scale_factor, read_events_and_imu

    ev, imu = read_events_and_imu(str(path))
    if quick:
        ev = ev.slice_time(int(ev.t[0]), int(ev.t[0]) + 1_000_000)
    gyro = imu.gyro * imu_full_scale_factor(imu) @ ROTDISK_CAMERA_FROM_IMU.T
    window, step = 15_000, 5_000
    out, _lat, total = _estimate(ev, "200;200;119.5;89.5", window, step)
    rows = []
    truth = []
    for t in out.t:
        last = int(np.searchsorted(ev.t, t, side="right")) - 1
        sel = (imu.t >= ev.t[max(0, last - window + 1)]) & (imu.t <= t)
        truth.append(gyro[sel].mean(axis=0))
    r = _score(out, np.array(truth))
    w = np.stack([out["wx"], out["wy"], out["wz"]], axis=1)
    corr = [float(np.corrcoef(w[:, k], np.array(truth)[:, k])[0, 1]) for k in range(3)]
    rows.append({"case": "davis240 rotdisk vs gyro (camera = diag(-1,1,-1) IMU, f 200 px assumed)", **r,
                 "corr_x": corr[0], "corr_y": corr[1], "corr_z": corr[2], "mev_s": len(ev) / total / 1e6})
    return rows


def _ecd_excerpt(name: str) -> tuple[Path, EventPacket, str] | None:
    """An ECD excerpt of the shared data: its folder, events and inline
    calibration, or None where it is absent."""
    data = shared_data()
    folder = data / "ecd" / name if data else None
    if folder is None or not (folder / "events.txt").exists():
        return None
    from tectum.sources.files import open_file

    src = open_file(str(folder / "events.txt"))
    try:
        ev = concat([q for q in src.packets() if isinstance(q, EventPacket)])
    finally:
        src.close()
    assert isinstance(ev, EventPacket)
    return folder, ev, ";".join((folder / "calib.txt").read_text().split())


def ecd(quick: bool) -> list[dict[str, Any]]:
    rows = []
    for name in ("shapes_rotation", "boxes_rotation"):
        found = _ecd_excerpt(name)
        if found is None:
            continue
        _folder, ev, calib = found
        out, _lat, total = _estimate(ev, calib, 10_000, 5_000)
        w = np.stack([out["wx"], out["wy"], out["wz"]], axis=1)
        rows.append({"case": f"ecd/{name} (no imu.txt in the excerpt: no truth)", "windows": len(out),
                     "mean_w": np.round(w.mean(axis=0), 2).tolist(), "confidence": float(np.mean(out["confidence"])),
                     "mev_s": len(ev) / total / 1e6})
    return rows


def reference(quick: bool) -> tuple[list[dict[str, Any]], str]:
    """tectum and the ST-PPP authors' code (cmax and st-ppp) on the same
    windows (see the module docstring); ``([], why)`` where it cannot run."""
    from tectum.evaluation.reference_stppp import find_stppp, run_stppp, run_stppp_folder
    from tectum.plugins.tracker import AngularVelocity

    root, why = find_stppp()
    if root is None:
        return [], why
    rows: list[dict[str, Any]] = []
    nb = 1 if quick else 2  # the reference takes about a minute per window on one core
    for speed in ([250] if quick else [100, 250, 500]):
        ev, truth, calib = _simulate(_scene(speed), (nb * REF_NE - WINDOW) // STEP + 2)
        ev = ev.take(np.arange(nb * REF_NE))  # whole batches only, as the reference
        f, cx, cy = truth["camera"]
        op = AngularVelocity(calib=calib, window_events=REF_NE, step_events=REF_NE)
        op.warmup()
        c0 = time.process_time()
        out = concat(op.process(ev) + op.finish())
        cpu = time.process_time() - c0
        assert isinstance(out, AngularVelocityPacket)
        truth_w = _truth_per_window(out, ev, truth, REF_NE)
        rows.append({"case": f"sim {speed} deg/s", "impl": "tectum", **_score(out, truth_w),
                     "kev_s": len(ev) / cpu / 1e3})
        for method in ("cmax", "st-ppp"):
            ref = run_stppp(root, ev, f, cx, cy, method=method, ne=REF_NE)
            got = AngularVelocityPacket(ref.t1, wx=ref.omega[:, 0], wy=ref.omega[:, 1], wz=ref.omega[:, 2])
            rows.append({"case": f"sim {speed} deg/s", "impl": f"ST-PPP code, {method}",
                         **_score(got, _truth_per_window(got, ev, truth, REF_NE)),
                         "kev_s": REF_NE / float(np.median(ref.seconds)) / 1e3})
    for name in ("shapes_rotation",) if quick else ("shapes_rotation", "boxes_rotation"):
        found = _ecd_excerpt(name)
        if found is None:
            continue
        folder, ev, calib = found
        op = AngularVelocity(calib=calib, window_events=REF_NE, step_events=REF_NE)
        mine = concat(op.process(ev.take(np.arange(REF_NE))) + op.finish())
        assert isinstance(mine, AngularVelocityPacket)
        row: dict[str, Any] = {"case": f"ecd/{name} (one window, no truth)",
                               "tectum": np.round([mine["wx"][0], mine["wy"][0], mine["wz"][0]], 2).tolist()}
        for method in ("cmax", "st-ppp"):
            ref = run_stppp_folder(root, folder, method=method, ne=REF_NE)
            row[f"ST-PPP code, {method}"] = np.round(ref.omega[0], 2).tolist() if len(ref.omega) else "-"
        rows.append(row)
    return rows, ""


def _chart(out: Path, clean: list[dict[str, Any]], noisy: list[dict[str, Any]], ref: list[dict[str, Any]]) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for rows, lab in ((clean, "clean"), (noisy, "2 Hz/px noise")):
        ax.plot([r["speed_dps"] for r in rows], [r["pct_peak"] for r in rows], "o-", label=f"tectum, {lab}")
    marks = {"ST-PPP code, cmax": "s", "ST-PPP code, st-ppp": "^", "tectum": "x"}
    for impl, mark in marks.items():
        pts = [(float(r["case"].split()[1]), r["pct_peak"]) for r in ref if r.get("impl") == impl]
        if pts:
            ax.plot(*zip(*pts), mark, ms=8, ls="none", label=f"{impl} (reference windows: 30k events)")
    ax.axhline(10, color="grey", ls=":", label="10 %")
    ax.set_xlabel("rotation speed (deg/s)")
    ax.set_ylabel("worst-axis RMS error (% of peak)")
    ax.set_title("tracker.angular_velocity" + ("" if ref else " (reference not run)"))
    ax.legend()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "tracker-angular-speed-error.png", dpi=100, bbox_inches="tight")
    plt.close(fig)


def _largest_under(rows: list[dict[str, Any]], pct: float) -> float:
    ok = [r["speed_dps"] for r in rows if r["pct_peak"] < pct]
    return float(max(ok)) if ok else 0.0


def run(out: Path, quick: bool) -> dict[str, Any]:
    cols = ["case", "windows", "peak_rad_s", "rms_wx", "rms_wy", "rms_wz", "pct_wx", "pct_wy", "pct_wz", "mev_s"]
    clean, noisy = accuracy(quick)
    print(table(clean + noisy, cols))
    print(f"largest speed with error < 10 %: clean {_largest_under(clean, 10):.0f} deg/s, "
          f"2 Hz/px {_largest_under(noisy, 10):.0f} deg/s")
    fmap = failure_map(quick)
    print("\nfailure map (250 deg/s unless varied)")
    print(table(fmap, ["factor", "value", "windows", "pct_wx", "pct_wy", "pct_wz", "mev_s"]))
    rt = realtime(quick)
    print("\n" + table([rt], ["case", "realtime_factor", "result_every_ms", "latency_p50_ms", "latency_p99_ms"]))
    real = rotdisk(quick)
    if real:
        print("\n" + table(real, ["case", "windows", "peak_rad_s", "pct_wx", "pct_wy", "pct_wz", "corr_x", "corr_y",
                                  "corr_z", "mev_s"]))
    ecd_rows = ecd(quick)
    if ecd_rows:
        print("\n" + table(ecd_rows, ["case", "windows", "mean_w", "confidence", "mev_s"]))
    ref, why = reference(quick)
    ref_sim = [r for r in ref if "impl" in r]
    if ref_sim:
        print("\nreference (same windows of 30,000 events)")
        print(table(ref_sim, ["case", "impl", "windows", "pct_wx", "pct_wy", "pct_wz", "pct_peak", "kev_s"]))
        ref_ecd = [r for r in ref if "impl" not in r]
        if ref_ecd:
            print(table(ref_ecd, ["case", "tectum", "ST-PPP code, cmax", "ST-PPP code, st-ppp"]))
    else:
        print("\n" + why)
    _chart(out, clean, noisy, ref_sim)
    upto500 = [r for r in clean if r["speed_dps"] <= 500]
    noisy500 = [r for r in noisy if r["speed_dps"] <= 500]
    targets = [
        target("angular: clean rotation <= 500 deg/s, worst-axis RMS", max(r["pct_peak"] for r in upto500), 3.0,
               "% of peak", higher_is_better=False),
        target("angular: 2 Hz/px noise <= 500 deg/s, worst-axis RMS", max(r["pct_peak"] for r in noisy500), 5.0,
               "% of peak", higher_is_better=False),
        target("angular: real-time factor at 1 Mev/s, 240x180, one core", rt["realtime_factor"], 1.0, "x"),
        target("angular: result interval at 1 Mev/s", rt["result_every_ms"], 10.0, "ms", higher_is_better=False),
    ]
    return {"rows": {"clean": clean, "noisy": noisy, "failure_map": fmap, "realtime": rt, "rotdisk": real,
                     "ecd": ecd_rows, "reference": ref or why}, "targets": targets}
