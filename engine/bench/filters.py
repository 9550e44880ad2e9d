"""``tectum bench filters``: speed and accuracy of the filter and repr families.

* Speed: Mev/s on a stream of moving edges plus 2 Hz/px noise on a 346x260
  sensor (5 M events; 1 M with ``--quick``), fed in 10 ms packets as a
  pipeline would, for background activity, STCF, refractory, hot pixel,
  undistort, event frame and time surface; side by side with dv-processing,
  tonic, faery and evlib where they install and offer the operation (slow
  pure-Python peers run on a prefix and say so in ``events``).
* Accuracy: ROC sweeps (signal kept vs noise passed, from the ``noise``
  column of the ``pattern:`` source or any labelled source) of BA over dt
  and STCF over (dt, k) at 0.1-10 Hz/px noise and two scene speeds, with
  AUC; peers' BA on the same labelled streams.
* Real recordings (``../shared/data/ecd``): fraction of events kept, and a
  before/after picture.
* Charts (matplotlib, extra ``charts``): ``filters-speed-auc.png`` (one
  point per filter setting, peers marked) and ``filters-roc.png``.
"""

from __future__ import annotations

import datetime
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from tectum import EventPacket, concat
from tectum.bench import peer, table, throughput
from tectum.plugins.filter import (
    BackgroundActivity, Camera, HotPixel, Refractory, SpatioTemporalCorrelation, Undistort, denoise_rates, roc_auc,
)
from tectum.plugins.filter._state import padded_timestamps
from tectum.plugins.filter.background_activity import background_activity_kernel
from tectum.plugins.filter.stcf import stcf_kernel
from tectum.plugins.repr import EventFrame, TimeSurface, color
from tectum.sources.pattern import PatternSource

__all__ = ["run", "labelled_stream", "roc_sweep"]

SENSOR = (346, 260)
CHUNK_US = 10_000
CAMERA = Camera(np.array([[300.0, 0, 173.0], [0, 300.0, 130.0], [0, 0, 1]]), np.array([-0.1, 0.05, 0.0, 0.0, 0.0]))
BA_DTS = (100, 300, 1000, 2000, 4000, 6000, 10_000, 20_000, 50_000, 100_000)
STCF_KS = (1, 2, 3, 4)
NOISE_HZ = (0.1, 1.0, 2.0, 10.0)
SPEEDS = (100.0, 400.0)


# -- inputs ----------------------------------------------------------------------
def labelled_stream(n_events: int | None = None, *, sensor: tuple[int, int] = SENSOR, duration_us: int | None = None,
                    noise_hz: float = 2.0, speed: float = 200.0, seed: int = 0) -> EventPacket:
    """Moving bars plus labelled Poisson noise (the ``pattern:`` source) as
    one packet: ``n_events`` events, or ``duration_us`` µs."""
    if duration_us is None:
        assert n_events is not None
        rate = 2 * speed / 24 * sensor[1] * sensor[0] + noise_hz * sensor[0] * sensor[1]
        duration_us = int(n_events / rate * 1e6 * 1.05) + CHUNK_US
    src = PatternSource(sensor=f"{sensor[0]}x{sensor[1]}", duration_us=duration_us, noise_hz=noise_hz, speed=speed,
                        seed=seed, window_us=50_000)
    ev: EventPacket = concat(list(src.packets()))  # type: ignore[assignment]
    if n_events is not None and len(ev) > n_events:
        ev = ev.slice_time(None, int(ev.t[n_events]))  # type: ignore[assignment]
    return ev


def chunks(ev: EventPacket, chunk_us: int = CHUNK_US) -> list[EventPacket]:
    return [ev.slice_time(a, a + chunk_us) for a in range(ev.t_start, ev.t_end, chunk_us)]  # type: ignore[misc]


def _dv_stores(dv: Any, pieces: list[EventPacket]) -> list[Any]:
    stores = []
    for q in pieces:
        s = dv.EventStore()
        for a, b, c, d in zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), (q.p > 0).tolist()):
            s.push_back(a, b, c, d)
        stores.append(s)
    return stores


def _structured(ev: EventPacket, dtype: Any) -> np.ndarray:
    arr = np.zeros(len(ev), dtype)
    for name in ("t", "x", "y", "p"):
        if name in arr.dtype.names:
            arr[name] = ev[name] if name != "p" else (ev.p > 0)
    return arr


def _keys(t: np.ndarray, x: np.ndarray, y: np.ndarray, sensor: tuple[int, int]) -> np.ndarray:
    w, h = sensor
    return t.astype(np.int64) * (w * h) + y.astype(np.int64) * w + x.astype(np.int64)


def _kept_mask(ev: EventPacket, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Which input events a peer kept, matched on (t, x, y)."""
    return np.isin(_keys(ev.t, ev.x, ev.y, ev.sensor), _keys(t, x, y, ev.sensor))


# -- speed -----------------------------------------------------------------------
def _feed_all(make: Callable[[], Any], pieces: list[EventPacket]) -> Callable[[], None]:
    def fn() -> None:
        op = make()
        for q in pieces:
            op.process(q)
        op.finish()
    return fn


def _tectum_ops() -> dict[str, Callable[[], Any]]:
    return {
        "background_activity": lambda: BackgroundActivity(),
        "stcf": lambda: SpatioTemporalCorrelation(),
        "refractory": lambda: Refractory(period_us=1000),
        "hot_pixel": lambda: HotPixel(learn_us=100_000),
        "undistort": lambda: Undistort(camera=CAMERA),
        "event_frame": lambda: EventFrame(window_us=CHUNK_US),
        "time_surface": lambda: TimeSurface(window_us=CHUNK_US, tau_us=50_000.0),
    }


def _peer_ops(ev: EventPacket, pieces: list[EventPacket], quick: bool) -> list[tuple[str, str, Callable[[], Any], int]]:
    """(operation, peer, fn, events processed) for every peer that imports."""
    out: list[tuple[str, str, Callable[[], Any], int]] = []
    n = len(ev)
    small = ev.slice_time(None, int(ev.t[min(n - 1, 20_000 if quick else 50_000)]))
    dv = peer("dv_processing")
    if dv is not None:
        stores = _dv_stores(dv, pieces)

        def dv_ba() -> None:
            f = dv.noise.BackgroundActivityNoiseFilter(SENSOR, backgroundActivityDuration=datetime.timedelta(microseconds=6000))
            for s in stores:
                f.accept(s)
                f.generateEvents()

        model = dv.camera.DistortionModel.RADIAL_TANGENTIAL
        k = CAMERA.K
        geom = dv.camera.CameraGeometry(list(CAMERA.D), k[0, 0], k[1, 1], k[0, 2], k[1, 2], SENSOR, model)

        def dv_undistort() -> None:
            for s in stores:
                geom.undistortEvents(s)

        def dv_frame() -> None:
            acc = dv.EdgeMapAccumulator(SENSOR)
            for s in stores:
                acc.accept(s)
                acc.generateFrame()

        def dv_surface() -> None:
            ts = dv.TimeSurface(SENSOR)
            for s in stores:
                ts.accept(s)
                ts.generateFrame()

        out += [("background_activity", "dv-processing", dv_ba, n), ("undistort", "dv-processing", dv_undistort, n),
                ("event_frame", "dv-processing (EdgeMapAccumulator)", dv_frame, n),
                ("time_surface", "dv-processing (TimeSurface, no decay)", dv_surface, n)]
    tonic = peer("tonic.functional")
    if tonic is not None:
        tdt = np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i1")])
        arr, arr_small = _structured(ev, tdt), _structured(small, tdt)
        out += [("background_activity", "tonic", lambda: tonic.denoise_numpy(arr_small, filter_time=6000), len(small)),
                ("refractory", "tonic", lambda: tonic.refractory_period_numpy(arr_small, 1000), len(small)),
                ("event_frame", "tonic", lambda: tonic.to_frame_numpy(arr, (*SENSOR, 2), time_window=CHUNK_US), n),
                ("time_surface", "tonic", lambda: tonic.to_timesurface_numpy(arr_small, (*SENSOR, 2), dt=CHUNK_US,
                                                                              tau=50_000), len(small))]
    faery = peer("faery")
    if faery is not None:
        farr = _structured(ev, faery.EVENTS_DTYPE)
        out.append(("hot_pixel", "faery", lambda: faery.events_stream_from_array(farr, SENSOR)
                    .filter_hot_pixels(10.0).to_array(), n))
    evlib_f, evlib_r, pl = peer("evlib.filtering"), peer("evlib.representations"), peer("polars")
    if evlib_f is not None and evlib_r is not None and pl is not None:
        df = pl.DataFrame({"x": ev.x.astype(np.int16), "y": ev.y.astype(np.int16),
                           "t": pl.Series(ev.t).cast(pl.Duration("us")), "polarity": (ev.p > 0).astype(np.int8)})
        bins = max(1, (ev.t_end - ev.t_start) // CHUNK_US)
        out += [("refractory", "evlib", lambda: evlib_f.filter_noise(df, method="refractory",
                                                                    refractory_period_us=1000).collect(), n),
                ("hot_pixel", "evlib", lambda: evlib_f.filter_hot_pixels(df, threshold_percentile=99.9).collect(), n),
                ("event_frame", "evlib", lambda: evlib_r.create_event_frame(df, SENSOR[1], SENSOR[0], n_time_bins=bins), n),
                ("time_surface", "evlib", lambda: evlib_r.create_time_surface(df, SENSOR[1], SENSOR[0], dt=float(CHUNK_US),
                                                                                tau=50_000.0), n)]
    return out


def speed(ev: EventPacket, quick: bool) -> list[dict[str, Any]]:
    """Throughput rows: one per (operation, implementation)."""
    pieces = chunks(ev)
    rows: list[dict[str, Any]] = []
    repeat = 3 if quick else 5
    for op, make in _tectum_ops().items():
        r = throughput(_feed_all(make, pieces), len(ev), repeat=repeat)
        rows.append({"operation": op, "impl": "tectum", **r})
    keep = np.empty(len(ev), np.bool_)

    def ba_kernel() -> None:
        background_activity_kernel(ev.t, ev.x, ev.y, padded_timestamps(ev.sensor), 6000, keep)

    rows.append({"operation": "background_activity", "impl": "tectum (kernel, one array)",
                 **throughput(ba_kernel, len(ev), repeat=repeat)})
    for op, name, fn, n in _peer_ops(ev, pieces, quick):
        try:
            r = throughput(fn, n, repeat=1 if n < len(ev) else 3, warmup=1)
        except Exception as e:  # a peer's API drift must not end the bench
            rows.append({"operation": op, "impl": name, "error": f"{type(e).__name__}: {e}"})
            continue
        rows.append({"operation": op, "impl": name, **r})
    ours = {r["operation"]: r["mev_s"] for r in rows if r["impl"] == "tectum"}
    for r in rows:
        if "mev_s" in r and not r["impl"].startswith("tectum"):
            r["tectum_ratio"] = ours[r["operation"]] / r["mev_s"]
    return rows


# -- accuracy --------------------------------------------------------------------
def roc_sweep(ev: EventPacket) -> dict[str, list[dict[str, float]]]:
    """Signal kept / noise passed of BA (per dt) and STCF (per dt and k) on
    a labelled packet (``noise`` column)."""
    keep = np.empty(len(ev), np.bool_)
    out: dict[str, list[dict[str, float]]] = {"background_activity": []}
    for dt in BA_DTS:
        background_activity_kernel(ev.t, ev.x, ev.y, padded_timestamps(ev.sensor), dt, keep)
        tpr, fpr = denoise_rates(ev, keep)
        out["background_activity"].append({"dt_us": dt, "signal_kept": tpr, "noise_passed": fpr})
    for k in STCF_KS:
        for pol in (False, True) if k == 2 else (False,):
            name = f"stcf_k{k}" + ("_polarity" if pol else "")
            out[name] = []
            for dt in BA_DTS:
                stcf_kernel(ev.t, ev.x, ev.y, ev.p, padded_timestamps(ev.sensor, 2 if pol else 1), dt, k, pol, keep)
                tpr, fpr = denoise_rates(ev, keep)
                out[name].append({"dt_us": dt, "k": k, "signal_kept": tpr, "noise_passed": fpr})
    return out


def peer_roc(ev: EventPacket, quick: bool) -> dict[str, list[dict[str, float]]]:
    """The same sweep for the peers' BA filters (decisions matched on t, x, y)."""
    out: dict[str, list[dict[str, float]]] = {}
    dv = peer("dv_processing")
    if dv is not None:
        (store,) = _dv_stores(dv, [ev])
        out["dv-processing BA"] = []
        for dt in BA_DTS:
            f = dv.noise.BackgroundActivityNoiseFilter(ev.sensor, backgroundActivityDuration=datetime.timedelta(microseconds=dt))
            f.accept(store)
            a = f.generateEvents().numpy()
            tpr, fpr = denoise_rates(ev, _kept_mask(ev, a["timestamp"], a["x"], a["y"]))
            out["dv-processing BA"].append({"dt_us": dt, "signal_kept": tpr, "noise_passed": fpr})
    tonic = peer("tonic.functional")
    if tonic is not None:
        small = ev.slice_time(None, ev.t_start + (50_000 if quick else 100_000))
        arr = _structured(small, np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i1")]))
        out["tonic denoise"] = []
        for dt in BA_DTS[::2]:
            a = tonic.denoise_numpy(arr, filter_time=dt)
            tpr, fpr = denoise_rates(small, _kept_mask(small, a["t"], a["x"], a["y"]))  # type: ignore[arg-type]
            out["tonic denoise"].append({"dt_us": dt, "signal_kept": tpr, "noise_passed": fpr})
    return out


def _auc(points: list[dict[str, float]]) -> float:
    return roc_auc([(p["signal_kept"], p["noise_passed"]) for p in points])


def accuracy(quick: bool) -> dict[str, Any]:
    """ROC sweeps and AUCs over noise rates and scene speeds (128x96 sensor)."""
    sensor, dur = (128, 96), 150_000 if quick else 300_000
    res: dict[str, Any] = {"sensor": sensor, "duration_us": dur, "conditions": []}
    for noise in NOISE_HZ:
        for spd in SPEEDS:
            ev = labelled_stream(sensor=sensor, duration_us=dur, noise_hz=noise, speed=spd, seed=int(noise * 10))
            sweeps = roc_sweep(ev)
            if noise == 2.0:
                sweeps.update(peer_roc(ev, quick))
            res["conditions"].append({
                "noise_hz": noise, "speed_px_s": spd, "events": len(ev),
                "noise_fraction": float(ev.columns["noise"].mean()),
                "sweeps": sweeps, "auc": {k: _auc(v) for k, v in sweeps.items()},
            })
    return res


def setting_speeds(ev: EventPacket, quick: bool) -> list[dict[str, Any]]:
    """Mev/s of every swept setting (BA dt, STCF dt and k), and dv's BA."""
    pieces = chunks(ev)
    rows = []
    for dt in BA_DTS:
        r = throughput(_feed_all(lambda: BackgroundActivity(dt_us=dt), pieces), len(ev), repeat=3)
        rows.append({"filter": "background_activity", "dt_us": dt, "mev_s": r["mev_s"]})
        for k in STCF_KS:
            r = throughput(_feed_all(lambda: SpatioTemporalCorrelation(dt_us=dt, k=k), pieces), len(ev), repeat=3)
            rows.append({"filter": f"stcf_k{k}", "dt_us": dt, "mev_s": r["mev_s"]})
    dv = peer("dv_processing")
    if dv is not None:
        stores = _dv_stores(dv, pieces)
        for dt in BA_DTS:
            def fn() -> None:
                f = dv.noise.BackgroundActivityNoiseFilter(ev.sensor, backgroundActivityDuration=datetime.timedelta(microseconds=dt))
                for s in stores:
                    f.accept(s)
                    f.generateEvents()
            rows.append({"filter": "dv-processing BA", "dt_us": dt, "mev_s": throughput(fn, len(ev), repeat=2)["mev_s"]})
    return rows


# -- real recordings -------------------------------------------------------------
def _shared_data() -> Path | None:
    env = os.environ.get("TECTUM_SHARED_DATA")
    p = Path(env) if env else Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
    return p if p.is_dir() else None


def read_ecd_events(path: Path, sensor: tuple[int, int] = (240, 180)) -> EventPacket:
    """An ECD ``events.txt`` (``t x y p``, t in seconds) as a packet."""
    a = np.loadtxt(path, ndmin=2)
    return EventPacket.from_arrays(np.rint(a[:, 0] * 1e6).astype(np.int64), a[:, 1], a[:, 2], a[:, 3], sensor=sensor)


def real_recordings(out: Path) -> dict[str, Any]:
    root = _shared_data()
    if root is None:
        return {"skipped": "../shared/data is absent (set TECTUM_SHARED_DATA)"}
    res: dict[str, Any] = {}
    for d in sorted((root / "ecd").glob("*/events.txt")):
        ev = read_ecd_events(d)
        row = {"events": len(ev)}
        for name, op in (("background_activity", BackgroundActivity()), ("stcf", SpatioTemporalCorrelation()),
                         ("refractory_1ms", Refractory(period_us=1000))):
            row[name] = len(op.process(ev)[0]) / len(ev)
        res[d.parent.name] = row
        if d.parent.name == "slider_depth":
            kept = BackgroundActivity().process(ev)[0]
            t1 = ev.t_start + 30_000  # 30 ms: long enough to see edges, short enough not to saturate
            res["picture"] = str(_before_after(ev.slice_time(None, t1), kept.slice_time(None, t1),  # type: ignore[arg-type]
                                               out / "filters-real-before-after.png"))
    return res


def _before_after(before: EventPacket, after: EventPacket, path: Path) -> Path:
    import cv2

    a, b = color(before), color(after)
    sep = np.full((a.shape[0], 4, 3), 128, np.uint8)
    img = np.concatenate([a, sep, b], axis=1)
    img = cv2.resize(img, (img.shape[1] * 2, img.shape[0] * 2), interpolation=cv2.INTER_NEAREST)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img[:, :, ::-1])
    return path


# -- charts ----------------------------------------------------------------------
def charts(out: Path, acc: dict[str, Any], settings: list[dict[str, Any]]) -> list[str]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    files = []
    cond = next(c for c in acc["conditions"] if c["noise_hz"] == 2.0 and c["speed_px_s"] == SPEEDS[0])
    fig, ax = plt.subplots(figsize=(7, 5))
    for name, marker in (("background_activity", "o"), ("stcf_k1", "v"), ("stcf_k2", "s"), ("stcf_k3", "^"),
                         ("stcf_k4", "D"), ("dv-processing BA", "x")):
        pts = {p["dt_us"]: p for p in cond["sweeps"].get(name, [])}
        xs, ys = [], []
        for s in settings:
            if s["filter"] == name and s["dt_us"] in pts:
                p = pts[s["dt_us"]]
                xs.append(s["mev_s"])
                ys.append(roc_auc([(p["signal_kept"], p["noise_passed"])]))
        if xs:
            ax.scatter(xs, ys, marker=marker, label=name + (" (peer)" if "dv" in name else ""), s=40 if "dv" in name else 25)
    ax.set_xscale("log")
    ax.set_xlabel("throughput (Mev/s, one core, 10 ms packets)")
    ax.set_ylabel("AUC of the setting's ROC point")
    ax.set_title(f"speed vs accuracy, one point per dt setting\n(noise 2 Hz/px, bars at {SPEEDS[0]:.0f} px/s)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = out / "filters-speed-auc.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(str(p))
    fig, axes = plt.subplots(1, len(NOISE_HZ), figsize=(4 * len(NOISE_HZ), 4), sharey=True)
    for ax, noise in zip(axes, NOISE_HZ):
        c = next(c for c in acc["conditions"] if c["noise_hz"] == noise and c["speed_px_s"] == SPEEDS[0])
        for name, sw in c["sweeps"].items():
            if name.endswith("_polarity"):
                continue
            f = [q["noise_passed"] for q in sw]
            t = [q["signal_kept"] for q in sw]
            style = "x--" if ("dv" in name or "tonic" in name) else ".-"
            ax.plot(f, t, style, label=f"{name} (AUC {c['auc'][name]:.3f})")
        ax.set_xscale("symlog", linthresh=1e-3)
        ax.set_xlim(0, 1)
        ax.set_title(f"noise {noise} Hz/px")
        ax.set_xlabel("noise passed")
        ax.legend(fontsize=6)
    axes[0].set_ylabel("signal kept")
    fig.suptitle(f"ROC over dt, bars at {SPEEDS[0]:.0f} px/s (pattern source, labelled noise)")
    fig.tight_layout()
    p = out / "filters-roc.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(str(p))
    return files


# -- entry point -----------------------------------------------------------------
def run(out: Path, quick: bool) -> dict[str, Any]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    n = 1_000_000 if quick else 5_000_000
    ev = labelled_stream(n)
    print(f"stream: {len(ev)} events, {(ev.t_end - ev.t_start) / 1e6:.2f} s, {ev.sensor[0]}x{ev.sensor[1]}, "
          f"{ev.columns['noise'].mean():.1%} noise")
    ev_plain = ev.without_columns("noise", "vx", "vy")
    rows = speed(ev_plain, quick)
    print(table(rows, ["operation", "impl", "mev_s", "mev_s_median", "events", "tectum_ratio", "error"]))
    acc = accuracy(quick)
    auc_rows = [{"noise_hz": c["noise_hz"], "speed": c["speed_px_s"], **c["auc"]} for c in acc["conditions"]]
    print(table(auc_rows, list(auc_rows[0])))
    settings = setting_speeds(ev_plain.slice_time(None, int(ev.t[min(len(ev) - 1, 1_000_000)])), quick)  # type: ignore[arg-type]
    real = real_recordings(out)
    print("real recordings, fraction kept:", {k: v for k, v in real.items() if k != "picture"})
    files = charts(out, acc, settings)
    for f in files:
        print("wrote", f)
    return {"speed": rows, "accuracy": acc, "setting_speeds": settings, "real": real, "charts": files,
            "stream": {"events": len(ev), "sensor": list(ev.sensor), "noise_hz": 2.0, "speed_px_s": 200.0}}
