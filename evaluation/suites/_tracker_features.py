"""``tectum bench tracker``, part ``features``: ``tracker.features`` (EKLT
and ICP) against the simulator's truth and against KLT on real frames.

* accuracy (the field's protocol, :mod:`tectum.evaluation.metrics.tracks`):
  the simulator's ``rotation`` scene as a DAVIS (240x180, ideal sensor,
  APS frames at 20 Hz, 2 ms exposure; the camera turns at up to ~1.3
  rad/s, features move at up to ~400 px/s). Every track starts at a corner
  the operator found on a frame; its truth track is the rotation's image
  of that pixel (:func:`tectum.sources.simulate.feature_scenes.rotation_tracks`).
  Tracking error (px) over the rows before the error first exceeds 5 px;
  age ratio: the track's life until then over the truth's time in the
  image (a truth track ends half a patch, 12 px, from the border, where
  the tracker's patch leaves the image). EKLT (translation, and with the
  rotation) against ICP.
* failure map (120x90, EKLT): speed (motion scaled), noise (background
  activity, Hz per pixel), texture (the panorama's contrast), frame rate.
  Measured (full run): the error stays 0.21-0.30 px up to 8x the scene's
  motion (features at up to ~1,600 px/s at 120x90), 100 Hz/px of noise and 2 fps; it grows with less
  texture (0.40 px at contrast 0.3, 0.70 at 0.15, 1.4 at 0.08: few events
  per patch) and at 16x the speed (0.56 px).
* speed: CPU time of the operator on the accuracy stream (50 tracks,
  ~10 Mev/s of simulated events at 240x180) in Mev/s; latency: the
  operator's processing time per packet of 1,000 events (1 ms at 1 Mev/s;
  p50, p99), fed as a live pipeline would feed it. A row is stamped at the event that completes its
  window, so the result is late by the processing time only.
* real: ``ecd/slider_depth`` (DAVIS240C, 4 APS frames in its 170 ms of
  events) and ``aedat/davis346.aedat4`` (DAVIS346, 59 frames over 2.4 s),
  against KLT (``cv2.calcOpticalFlowPyrLK``, frame to frame, 21 px
  windows, 3 levels) started from each track's detection: error at the
  rows (KLT interpolated linearly between frames) and age against KLT's
  own track length. slider_depth's errors fall by half when its frames
  are taken as 10 ms later than stamped (a row with that shift is shown):
  its ``images.txt`` times look like exposure starts, not mid-exposure.
  The DAVIS346 recording has few events (33 kev/s) and a mostly still
  scene: most features get no event and keep their one row (``unmoved``,
  not scored: they say nothing about accuracy).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from tectum import EventPacket, FramePacket, TrackPacket, concat
from tectum.evaluation.harness import shared_data, table, target
from tectum.evaluation.metrics.tracks import TrackScore, score_tracks

SENSOR = (240, 180)
SMALL = (120, 90)
MARGIN = 12.0  # px: half the default patch
#: slider_depth's frames taken as stamped 10 ms before their content (exposure start?): both methods' error
#: against KLT falls from 1.4 / 0.9 px to 0.7 / 0.5 px with it (measured over 0, 5, 10, 15 ms)
SLIDER_SHIFT_US = 10_000
COLS = ["case", "method", "tracks", "unmoved", "median_err_px", "mean_err_px", "age_ratio", "mean_age_ms", "cpu_mev_s"]


def _run(ev: EventPacket, frames: FramePacket, **params: Any) -> tuple[TrackPacket, float, dict[str, int]]:
    """The operator on a whole stream: (tracks, CPU seconds, counters)."""
    from tectum.plugins.tracker import FeatureTracker
    from tectum.testing import feed_ports

    op = FeatureTracker(**params)
    op.warmup()
    c0 = time.process_time()
    out = feed_ports(op, {"events": [ev], "frames": [frames]})
    cpu = time.process_time() - c0
    tr = concat([q for q in out if len(q)]) if any(len(q) for q in out) else TrackPacket.empty(0)
    assert isinstance(tr, TrackPacket)
    return tr, cpu, dict(op.counts)


def _score(tr: TrackPacket, truth_fn: Callable[..., np.ndarray], t_end: int, sensor: tuple[int, int]) -> TrackScore:
    return score_tracks(tr.t, tr.id, np.stack([tr.x, tr.y], 1), truth_fn, t_end, sensor, margin=MARGIN)


def _row(case: str, method: str, s: TrackScore, n_events: int, cpu: float) -> dict[str, Any]:
    return {"case": case, "method": method, "tracks": s.tracks, "unmoved": s.unmoved,
            "median_err_px": s.median_error_px,
            "mean_err_px": s.mean_error_px, "age_ratio": s.median_age_ratio, "mean_age_ms": s.mean_age_us / 1e3,
            "cpu_mev_s": n_events / max(cpu, 1e-9) / 1e6}


def _simulated(sensor: tuple[int, int], duration_us: int, **kw: Any) -> tuple[EventPacket, FramePacket, Any]:
    from tectum.sources.simulate.feature_scenes import davis_rotation, rotation_tracks

    ev, frames, truth = davis_rotation(sensor, duration_us, **kw)

    def truth_fn(t0: np.ndarray, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        return rotation_tracks(truth, t0, x0, t)

    return ev, frames, truth_fn


def accuracy(quick: bool) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """EKLT and ICP on the clean 240x180 rotation; the events, frames and
    EKLT's CPU time for the speed table."""
    duration = 250_000 if quick else 500_000
    ev, frames, truth_fn = _simulated(SENSOR, duration)
    rows = []
    for label, params in (("eklt", {}), ("eklt, rotation=true", {"rotation": True}), ("icp", {"method": "icp"})):
        tr, cpu, counts = _run(ev, frames, **params)
        rows.append({**_row("clean rotation 240x180", label, _score(tr, truth_fn, duration, SENSOR), len(ev), cpu),
                     "lost_residual": counts["lost_residual"], "lost_border": counts["lost_border"]})
    return rows, {"events": ev, "frames": frames}


def failure_map(quick: bool) -> list[dict[str, Any]]:
    """EKLT at 120x90 as one factor moves from the clean case (which is
    every factor's baseline row: speed 1, no noise, contrast 0.6, 20 fps)."""
    duration = 250_000
    clean = {"speed": 1.0, "noise_hz": 0.0, "contrast": 0.6, "aps_hz": 20.0}
    keys = {"speed": "speed", "noise_hz": "shot_noise_hz", "contrast": "contrast", "aps_hz": "aps_rate_hz"}
    varied = ({"speed": [4.0], "noise_hz": [5.0], "contrast": [0.15], "aps_hz": [5.0]} if quick else
              {"speed": [0.5, 2.0, 4.0, 8.0, 16.0], "noise_hz": [1.0, 5.0, 20.0, 100.0],
               "contrast": [0.08, 0.15, 0.3, 0.9], "aps_hz": [2.0, 5.0, 10.0, 50.0]})

    def case(**kw: Any) -> dict[str, Any]:
        ev, frames, truth_fn = _simulated(SMALL, duration, **kw)
        tr, cpu, _ = _run(ev, frames)
        return _row("", "eklt", _score(tr, truth_fn, duration, SMALL), len(ev), cpu)

    base = case()
    rows = []
    for factor, values in varied.items():
        runs = [(clean[factor], base)] + [(v, case(**{keys[factor]: v})) for v in values]
        rows += [{"factor": factor, "value": v, **r} for v, r in sorted(runs, key=lambda vr: vr[0])]
    return rows


def latency(ev: EventPacket, frames: FramePacket, packet_events: int = 1000) -> dict[str, Any]:
    """Processing time per packet of ``packet_events`` events (ms, p50 and
    p99: 1 ms of data at 1 Mev/s), the frames of its span with it, and the
    CPU rate (Mev/s) when the stream comes in such packets."""
    from tectum.plugins.tracker import FeatureTracker

    op = FeatureTracker()
    op.warmup()
    times = []
    bounds = [ev.t_start, *(int(ev.t[i]) for i in range(packet_events, len(ev), packet_events)), ev.t_end]
    c0 = time.process_time()
    for t0, t1 in zip(bounds, bounds[1:]):
        ports = {"events": ev.slice_time(t0, t1), "frames": frames.slice_time(t0, t1)}
        w0 = time.perf_counter()
        op.process_ports(ports)
        times.append(time.perf_counter() - w0)
    cpu = time.process_time() - c0
    ms = np.asarray(times) * 1e3
    return {"case": f"{packet_events}-event packets, 240x180, 50 tracks", "packets": len(ms),
            "latency_p50_ms": float(np.percentile(ms, 50)), "latency_p99_ms": float(np.percentile(ms, 99)),
            "cpu_mev_s": len(ev) / max(cpu, 1e-9) / 1e6}


# -- real data ------------------------------------------------------------------------------------------
def klt_truth(frames: FramePacket) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """A truth function from KLT on ``frames``: the pixel ``x0`` at frame
    time ``t0`` followed frame to frame by pyramidal Lucas-Kanade; linear
    between frames, NaN before ``t0``, after KLT loses it or for a ``t0``
    that is no frame's time."""
    import cv2

    imgs = [np.asarray(i if i.ndim == 2 else i.mean(axis=2)).astype(np.uint8) for i in frames.images]
    ft = frames.t.astype(np.float64)
    cache: dict[tuple[float, float, float], np.ndarray] = {}

    def path(t0: float, x: float, y: float) -> np.ndarray:
        key = (t0, x, y)
        if key not in cache:
            k = int(np.searchsorted(ft, t0))
            pts = np.full((len(ft), 2), np.nan)
            if k < len(ft) and ft[k] == t0:
                p = np.array([[[x, y]]], np.float32)
                pts[k] = x, y
                for j in range(k + 1, len(ft)):
                    nxt, st, _ = cv2.calcOpticalFlowPyrLK(imgs[j - 1], imgs[j], p, p.copy(), winSize=(21, 21),
                                                          maxLevel=3)
                    if not st[0, 0]:
                        break
                    p = np.asarray(nxt, np.float32)
                    pts[j] = p[0, 0]
            cache[key] = pts
        return cache[key]

    def truth(t0: np.ndarray, x0: np.ndarray, t: np.ndarray) -> np.ndarray:
        out = np.full((len(t), 2), np.nan)
        for i in range(len(t)):
            pts = path(float(t0[i]), float(x0[i, 0]), float(x0[i, 1]))
            ok = np.isfinite(pts[:, 0])
            if ok.any() and ft[ok][0] <= t[i] <= ft[ok][-1]:
                out[i, 0] = np.interp(t[i], ft[ok], pts[ok, 0])
                out[i, 1] = np.interp(t[i], ft[ok], pts[ok, 1])
        return out

    return truth


def _recording(path: Path) -> tuple[EventPacket, FramePacket] | None:
    import tectum
    from tectum.testing import ListSink

    p = tectum.Pipeline()
    src = p.source(str(path))
    sink = ListSink()
    p.sink(sink, src)
    tectum.run(p)
    ev = [q for q in sink.packets if isinstance(q, EventPacket) and len(q)]
    fr = [q for q in sink.packets if isinstance(q, FramePacket) and len(q)]
    if not ev or not fr:
        return None
    e, f = concat(ev), concat(fr)
    assert isinstance(e, EventPacket) and isinstance(f, FramePacket)
    return e, f.with_interval(min(f.t_start, e.t_start), max(f.t_end, e.t_end))  # type: ignore[return-value]


def real(quick: bool) -> list[dict[str, Any]]:
    data = shared_data()
    if data is None:
        print("../shared/data absent: no real recordings")
        return []
    rows = []
    for name, rel, shifts in (("ecd/slider_depth (DAVIS240C)", "ecd/slider_depth/events.txt", (0, SLIDER_SHIFT_US)),
                              ("aedat/davis346.aedat4 (DAVIS346)", "aedat/davis346.aedat4", (0,))):
        path = data / rel
        if not path.is_file():
            continue
        rec = _recording(path)
        if rec is None:
            print(f"{name}: no events or no frames")
            continue
        ev, frames = rec
        for shift in shifts:
            fr = FramePacket(frames.t + shift, images=frames.images, t_start=frames.t_start,
                             t_end=frames.t_end + shift)
            e = ev.with_interval(fr.t_start, fr.t_end)
            truth_fn = klt_truth(fr)
            case = name + (f", frames +{shift / 1e3:g} ms" if shift else "")
            for method in ("eklt", "icp"):
                tr, cpu, _ = _run(e, fr, method=method)
                rows.append({**_row(case, method, _score(tr, truth_fn, int(e.t[-1]), e.sensor), len(e), cpu),
                             "frames": len(fr)})
    return rows


def _chart(out: Path, fmap: list[dict[str, Any]]) -> str | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    factors = list(dict.fromkeys(r["factor"] for r in fmap))
    fig, axes = plt.subplots(1, len(factors), figsize=(3.2 * len(factors), 3.0))
    for ax, f in zip(np.atleast_1d(axes), factors):
        rs = [r for r in fmap if r["factor"] == f]
        x = [r["value"] for r in rs]
        ax.plot(x, [r["median_err_px"] for r in rs], "o-", label="median error (px)")
        ax.plot(x, [r["age_ratio"] for r in rs], "s--", label="age ratio")
        ax.set_xlabel(f)
        ax.axhline(0.5, color="grey", lw=0.5)
        ax.set_ylim(0, max(1.6, max(r["median_err_px"] for r in rs if np.isfinite(r["median_err_px"])) + 0.1)
                    if any(np.isfinite(r["median_err_px"]) for r in rs) else 1.6)
    np.atleast_1d(axes)[0].legend(fontsize=7)
    fig.suptitle("tracker.features (EKLT), 120x90 simulated DAVIS rotation")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "tracker_features_failure_map.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def run(out: Path, quick: bool) -> dict[str, Any]:
    rows, stream = accuracy(quick)
    print(table(rows, COLS + ["lost_residual", "lost_border"]))
    fmap = failure_map(quick)
    print("\nfailure map (EKLT, 120x90, clean rotation unless varied)")
    print(table(fmap, ["factor", "value", "tracks", "median_err_px", "age_ratio", "mean_age_ms", "cpu_mev_s"]))
    lat = latency(stream["events"], stream["frames"])
    print("\n" + table([lat], ["case", "packets", "latency_p50_ms", "latency_p99_ms", "cpu_mev_s"]))
    real_rows = real(quick)
    if real_rows:
        print("\nreal recordings, against KLT on the frames")
        print(table(real_rows, ["case", "method", "frames", "tracks", "unmoved", "median_err_px", "mean_err_px",
                                "age_ratio", "mean_age_ms", "cpu_mev_s"]))
    chart = _chart(out, fmap)
    if chart:
        print(f"chart: {chart}")
    eklt = next(r for r in rows if r["method"] == "eklt")
    targets = [
        target("features: EKLT median error, clean simulated rotation", eklt["median_err_px"], 0.5, "px",
               higher_is_better=False),
        target("features: EKLT age ratio, clean simulated rotation", eklt["age_ratio"], 0.8, ""),
        target("features: EKLT speed, 50 tracks, one core (CPU time)", eklt["cpu_mev_s"], 1.0, "Mev/s"),
    ]
    return {"rows": {"accuracy": rows, "failure_map": fmap, "latency": lat, "real": real_rows, "chart": chart},
            "targets": targets}
