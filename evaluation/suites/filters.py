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
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, cast

import numpy as np
from numba import njit

from tectum import EventPacket, concat
from tectum.evaluation.harness import (
    TARGET_COLUMNS,
    interleaved,
    memory_bandwidth,
    peer,
    shared_data,
    table,
    target,
    target_row,
    throughput,
    versus,
)
from tectum.evaluation.metrics import denoise_rates, roc_auc
from tectum.plugins.filter import (
    BackgroundActivity,
    Camera,
    HotPixel,
    Refractory,
    SpatioTemporalCorrelation,
    Undistort,
)
from tectum.plugins.filter._state import padded_timestamps
from tectum.plugins.filter.background_activity import background_activity_kernel
from tectum.plugins.filter.stcf import stcf_kernel
from tectum.plugins.repr import CountImage, EventFrame, TimeSurface, color
from tectum.sources.pattern import PatternSource
from tectum.sources.simulate import load_scene, simulate

__all__ = ["run", "labelled_stream", "sim_stream", "roc_sweep", "at_defaults", "dt_for_signal"]

SENSOR = (346, 260)
CHUNK_US = 10_000
CAMERA = Camera(np.array([[300.0, 0, 173.0], [0, 300.0, 130.0], [0, 0, 1]]), np.array([-0.1, 0.05, 0.0, 0.0, 0.0]))
BA_DTS = (100, 300, 1000, 2000, 4000, 6000, 10_000, 20_000, 50_000, 100_000)
STCF_KS = (1, 2, 3, 4)
NOISE_HZ = (0.1, 1.0, 2.0, 10.0)
SPEEDS = (100.0, 400.0)
# simulator accuracy: 346x260, preset ideal plus labelled shot noise at these rates (Hz/px)
SIM_SENSOR = (346, 260)
SIM_NOISE_HZ = (0.1, 0.5, 2.0, 10.0)
SIM_WARMUP_US = 50_000  # events before this feed the filters but are not scored
#: bench scene -> (built-in scene, background velocity px/s override, duration µs quick, full)
SIM_SCENES: dict[str, tuple[str, tuple[float, float] | None, int, int]] = {
    "shapes": ("shapes", None, 250_000, 500_000),
    "translation_edges": ("translation_edges", None, 250_000, 500_000),
    "texture_fast": ("moving_texture", None, 100_000, 200_000),
    "texture_slow": ("moving_texture", (30.0, 12.0), 250_000, 500_000),
    "low_texture": ("low_texture", None, 400_000, 800_000),
}
SIM_REFERENCE = ("shapes", 2.0)  # the condition of the speed-vs-AUC chart and the peers' ROC


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
    ev: EventPacket = concat(list(src.packets()))
    if n_events is not None and len(ev) > n_events:
        ev = ev.slice_time(None, int(ev.t[n_events]))
    return ev


def chunks(ev: EventPacket, chunk_us: int = CHUNK_US) -> list[EventPacket]:
    return [ev.slice_time(a, a + chunk_us) for a in range(ev.t_start, ev.t_end, chunk_us)]


def _dv_stores(dv: Any, pieces: list[EventPacket]) -> list[Any]:
    stores = []
    for q in pieces:
        s = dv.EventStore()
        for a, b, c, d in zip(q.t.tolist(), q.x.tolist(), q.y.tolist(), (q.p > 0).tolist()):
            s.push_back(a, b, c, d)
        stores.append(s)
    return stores


def _dv_ba(dv: Any, sensor: tuple[int, int], dt_us: int) -> Any:
    """dv-processing's background activity filter with a ``dt_us`` µs window."""
    window = datetime.timedelta(microseconds=dt_us)
    return dv.noise.BackgroundActivityNoiseFilter(sensor, backgroundActivityDuration=window)


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


def _dv_runs(dv: Any, stores: list[Any]) -> dict[str, Callable[[], None]]:
    """dv-processing's undistortion, edge-map accumulator and time surface
    over ``stores`` (one frame generated per store), by operation name."""
    k = CAMERA.K
    geom = dv.camera.CameraGeometry(list(CAMERA.D), k[0, 0], k[1, 1], k[0, 2], k[1, 2], SENSOR,
                                    dv.camera.DistortionModel.RADIAL_TANGENTIAL)

    def undistort() -> None:
        for s in stores:
            geom.undistortEvents(s)

    def frame() -> None:
        acc = dv.EdgeMapAccumulator(SENSOR)
        for s in stores:
            acc.accept(s)
            acc.generateFrame()

    def surface() -> None:
        ts = dv.TimeSurface(SENSOR)
        for s in stores:
            ts.accept(s)
            ts.generateFrame()

    return {"undistort": undistort, "event_frame": frame, "time_surface": surface}


def _peer_ops(ev: EventPacket, pieces: list[EventPacket], quick: bool) -> list[tuple[str, str, Callable[[], Any], int]]:
    """(operation, peer, fn, events processed) for every peer that imports."""
    out: list[tuple[str, str, Callable[[], Any], int]] = []
    n = len(ev)
    small = ev.slice_time(None, int(ev.t[min(n - 1, 20_000 if quick else 50_000)]))
    dv = peer("dv_processing")
    if dv is not None:
        stores = _dv_stores(dv, pieces)

        runs = _dv_runs(dv, stores)
        out += [("background_activity", "dv-processing", _dv_ba_fn(dv, stores, SENSOR, 6000), n),
                ("undistort", "dv-processing", runs["undistort"], n),
                ("event_frame", "dv-processing (EdgeMapAccumulator)", runs["event_frame"], n),
                ("time_surface", "dv-processing (TimeSurface, no decay)", runs["time_surface"], n)]
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
                ("event_frame", "evlib",
                 lambda: evlib_r.create_event_frame(df, SENSOR[1], SENSOR[0], n_time_bins=bins), n),
                ("time_surface", "evlib",
                 lambda: evlib_r.create_time_surface(df, SENSOR[1], SENSOR[0], dt=float(CHUNK_US), tau=50_000.0), n)]
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
    ours = {row["operation"]: row["mev_s"] for row in rows if row["impl"] == "tectum"}
    for row in rows:
        if "mev_s" in row and not row["impl"].startswith("tectum"):
            row["tectum_ratio"] = ours[row["operation"]] / row["mev_s"]
    return rows


# -- targets: the pipeline against its kernels, tectum against the fastest peer ----
#: BA windows (µs) and event rates (Mev/s) of the peer comparison
TARGET_DTS = (1000, 2000, 6000, 10_000, 20_000)
TARGET_RATES = (0.1, 0.5, 1.0, 2.0, 5.0)


def at_rate(ev: EventPacket, rate_mev_s: float) -> EventPacket:
    """``ev`` with its timestamps stretched or squeezed to ``rate_mev_s``
    (the same scene, slower or faster); validated (checked), in arrays of
    its own (as a source decodes them: its slices join as views)."""
    now = len(ev) / max(ev.t_end - ev.t_start, 1)  # events per µs
    t = ev.t_start + np.round((ev.t - ev.t_start) * (now / rate_mev_s)).astype(np.int64)
    return EventPacket(t, ev.x.copy(), ev.y.copy(), ev.p.copy(), sensor=ev.sensor).validate()


def _pipeline(make: Callable[[], Any], pieces: list[EventPacket]) -> Callable[[], None]:
    """A run of the whole pipeline: a source of ``pieces`` (checked, as a
    source that validated them gives them), the operator, a null sink. The
    source is told it gives events (else the test double reads every
    piece's kind when made, each run: 130-170 µs of 3,100 pieces that a file
    source does not pay)."""
    import tectum
    from tectum.sinks.null import NullSink
    from tectum.testing import ListSource

    def fn() -> None:
        p = tectum.Pipeline()
        src = p.source(ListSource(pieces, produces=[tectum.Kind.EVENTS]), id="src")
        p.sink(NullSink(), p.op(make(), src, id="op"), id="sink")
        tectum.run(p)
    return fn


def _one_array(make: Callable[[], Any], ev: EventPacket) -> Callable[[], None]:
    """The operator's kernels on the whole stream as one packet (no packet
    or engine cost: the kernel-only figure)."""
    def fn() -> None:
        op = make()
        op.process(ev)
        op.finish()
    return fn


#: operators that hand out a frame per window: on one array they make every
#: frame of the stream at once (5 M events: 312 event frames, 225 MB of fresh
#: pages), which times the page faults, not the kernels; their kernel-only
#: figure is the operator fed the 10 ms packets in a plain loop (no engine)
WINDOWED = ("event_frame", "time_surface")


def pipeline_gap(ev: EventPacket, quick: bool) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Every filter and representation: Mev/s (CPU time, medians of
    interleaved rounds) on one array, fed the 10 ms packets in a plain loop
    (no engine) and through a pipeline at 10 ms and 1 ms packets; target
    pipeline >= 0.9 x the faster of the two engine-free figures (for
    :data:`WINDOWED`, the loop only: their one array times page faults).
    One array alone would flatter the pipeline: 5 M events of fresh output
    columns (65 MB) cost it page faults the 10 ms packets do not pay. For BA
    also the old mask-only kernel (it does not select)."""
    ev = ev.validate()
    rows, targets = [], []
    for name, make in _tectum_ops().items():
        fns = {"one array": _one_array(make, ev), "10 ms": _pipeline(make, chunks(ev, 10_000)),
               "1 ms": _pipeline(make, chunks(ev, 1_000))}
        if name == "background_activity":
            fns["mask kernel"] = partial(_mask_kernel, ev, np.empty(len(ev), np.bool_))
        fns["no engine"] = _feed_all(make, chunks(ev, 10_000))
        r = interleaved(fns, len(ev), repeat=3 if quick else 11)
        free = ("no engine",) if name in WINDOWED else ("one array", "no engine")
        ref = max(free, key=lambda k: r[k]["cpu_mev_s"])
        for k, v in r.items():
            rows.append({"operation": name, "path": k, "cpu_mev_s": v["cpu_mev_s"],
                         "spread": f"{v['cpu_mev_s_min']:.0f}-{v['cpu_mev_s_max']:.0f}", "mev_s": v["mev_s"]})
        for k in ("10 ms", "1 ms"):
            rec = versus(f"{name}: pipeline {k} packets / {ref}", r[k], r[ref], 0.9, clock="cpu", peer_name="kernel")
            targets.append(rec)
    return rows, targets


def _mask_kernel(ev: EventPacket, keep: np.ndarray) -> None:
    background_activity_kernel(ev.t, ev.x, ev.y, padded_timestamps(ev.sensor), 6000, keep)


def _dv_ba_fn(dv: Any, stores: list[Any], sensor: tuple[int, int], dt: int) -> Callable[[], None]:
    def fn() -> None:
        f = _dv_ba(dv, sensor, dt)
        for s in stores:
            f.accept(s)
            f.generateEvents()
    return fn


#: bytes a frame of the event-frame rows costs per pixel: tectum's default
#: (int32 x 2 polarities), its 8-bit count image and dv's edge map (uint8)
FRAME_BYTES = {"event frame": 8, "count image uint8": 1, "dv": 1}
#: bytes an event costs a histogram beyond its frame: x, y (2 each), p (1) read
EVENT_BYTES = 5
#: frames in the block :func:`frame_write_bandwidth` writes in turn: the
#: event frame's pooled blocks (``repr.operators.MIN_FRAMES``)
WRITE_FRAMES = 8


@njit(cache=True, nogil=True)
def _zero(a):  # type: ignore[no-untyped-def]
    a[:] = 0  # a memset, as the frame kernels zero a frame


def frame_write_bandwidth(px_bytes: int = 8, frames: int = WRITE_FRAMES, repeat: int = 41) -> float:
    """Bytes/s at which this machine writes frames where the event frame
    writes them: a block of ``frames`` frames of ``px_bytes`` per pixel of
    :data:`SENSOR`, each zeroed in turn (a memset, as the kernels zero a
    recycled frame), the block staying in cache, as the pool's blocks do
    (it hands out again the block handed out last, once nobody holds it:
    the frames of this bench never reach main memory). The median of
    ``repeat`` passes over the block after three (the first faults its pages in),
    per CPU second (see :func:`~tectum.evaluation.harness.memory_bandwidth`)."""
    block = np.zeros((frames, SENSOR[1] * SENSOR[0] * px_bytes), np.uint8)
    for _ in range(3):
        for f in block:
            _zero(f)
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        for f in block:
            _zero(f)
        times.append(max(time.process_time() - t0, 1e-9))
    return block.nbytes / float(np.median(times))


def frame_limit(n_events: int, n_frames: int, px_bytes: int, bandwidth: float,
                frame_bandwidth: float | None = None) -> float:
    """The fastest Mev/s memory allows an accumulator that writes a fresh
    frame of ``px_bytes`` per pixel of :data:`SENSOR` per window: the
    frames' bytes (spread over the events) written at ``frame_bandwidth``
    (bytes/s; :func:`frame_write_bandwidth`: in cache, where the pooled
    frames are written; None: ``bandwidth``) plus :data:`EVENT_BYTES` an
    event read at ``bandwidth`` (main memory: the bench's event columns,
    25 MB, stream from it)."""
    frame_bytes = n_frames * px_bytes * SENSOR[0] * SENSOR[1] / max(n_events, 1)
    seconds = frame_bytes / (frame_bandwidth or bandwidth) + EVENT_BYTES / bandwidth
    return 1 / seconds / 1e6


def limit_binds(ours: float, peer_mev_s: float, limit: float) -> bool:
    """Whether a frame row missing 2x the peer is judged within 1.5x of the
    memory ``limit`` instead (all Mev/s): when 2x the peer is past
    ``limit / 1.5`` and tectum does not already run faster than the limit
    (it writes fewer bytes than whole frames: a recycled frame is zeroed
    only where its last use wrote, when its windows held few events; there
    the limit does not bind, and the row stays judged by 2x the peer)."""
    return 2.0 * peer_mev_s > limit / 1.5 and ours <= limit


def peer_targets(ev: EventPacket, quick: bool) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """tectum (a whole pipeline, 10 ms packets) against dv-processing (its
    filter or accumulator fed the same 10 ms stores), medians of
    interleaved rounds, wall clock and CPU time: BA over every window of
    :data:`TARGET_DTS` at every rate of :data:`TARGET_RATES`; event frame,
    time surface and undistort at every rate. Target: 2x.

    The event frame does more work than dv's edge map: both hand out a
    fresh frame per window (dv allocates a new 8-bit image each
    ``generateFrame``), but tectum's default is two int32 channels (8 bytes
    a pixel) against dv's one uint8 channel. So a second row times
    tectum's count image in uint8 (1 byte a pixel, saturating, like dv's),
    and where 2x dv is past what memory allows for tectum's 8-byte frames
    (:func:`frame_limit`: the frames written in cache, where the pool keeps
    them, the events read from main memory), the event frame's target is
    within 1.5x of that limit instead; not where tectum runs faster than
    that limit (it did not write whole frames: :func:`limit_binds`)."""
    dv = peer("dv_processing")
    if dv is None:
        return [], []
    bw = memory_bandwidth()
    fbw = frame_write_bandwidth()
    print(f"memory copy bandwidth now: {bw / 1e9:.1f} GB/s (read + write); frames written in cache: "
          f"{fbw / 1e9:.1f} GB/s")
    rows, targets = [], []
    repeat = 3 if quick else 11
    for rate in TARGET_RATES:
        rev = at_rate(ev, rate)
        pieces = chunks(rev)
        stores = _dv_stores(dv, pieces)
        cases: list[tuple[str, Callable[[], None], Callable[[], None]]] = [
            (f"BA dt {dt // 1000} ms", _pipeline(partial(BackgroundActivity, dt_us=dt), pieces),
             _dv_ba_fn(dv, stores, SENSOR, dt)) for dt in TARGET_DTS]

        runs = _dv_runs(dv, stores)
        cases += [("event frame", _pipeline(partial(EventFrame, window_us=CHUNK_US), pieces), runs["event_frame"]),
                  ("count image uint8", _pipeline(partial(CountImage, window_us=CHUNK_US, dtype="uint8"), pieces),
                   runs["event_frame"]),
                  ("time surface", _pipeline(partial(TimeSurface, window_us=CHUNK_US, tau_us=50_000.0), pieces),
                   runs["time_surface"]),
                  ("undistort", _pipeline(partial(Undistort, camera=CAMERA), pieces), runs["undistort"])]
        for what, ours, theirs in cases:
            r = interleaved({"tectum": ours, "dv": theirs}, len(rev), repeat=repeat)
            row = {"operation": what, "rate_mev_s": rate, "tectum": r["tectum"]["mev_s"], "dv": r["dv"]["mev_s"]}
            limit = frame_limit(len(rev), len(pieces), FRAME_BYTES[what], bw, fbw) if what in FRAME_BYTES else None
            per_px = len(pieces) * SENSOR[0] * SENSOR[1] / len(rev)  # frame pixels an event
            for clock in ("wall", "cpu"):
                rec = versus(f"{what} @ {rate:g} Mev/s", r["tectum"], r["dv"], 2.0, clock=clock,
                             peer_name="dv-processing")
                targets.append(rec)
                row["ratio" if clock == "wall" else "cpu_ratio"] = rec["value"]
                if clock == "wall":
                    row["spread"] = f"{rec['ratio_min']:.2f}-{rec['ratio_max']:.2f}"
                key = "mev_s" if clock == "wall" else "cpu_mev_s"
                if limit is not None and not rec["met"] and limit_binds(r["tectum"][key], r["dv"][key], limit):
                    rec["name"] += f" [2x = {2.0 * r['dv'][key]:.0f} Mev/s is past the memory limit: next row]"
                    targets.append(target(
                        f"{what} @ {rate:g} Mev/s within 1.5x of the memory limit {limit:.0f} Mev/s "
                        f"({FRAME_BYTES[what]} B/px frames: {per_px * FRAME_BYTES[what]:.0f}"
                        f" B/event written in cache at {fbw / 1e9:.0f} GB/s, {EVENT_BYTES} B/event read at "
                        f"{bw / 1e9:.1f} GB/s) ({clock})", r["tectum"][key], limit / 1.5, "Mev/s"))
            if limit is not None:
                row["memory_limit_mev_s"] = limit
            rows.append(row)
        print(f"  peers at {rate:g} Mev/s done", flush=True)
    return rows, targets


# -- accuracy --------------------------------------------------------------------
def _sweep_names() -> list[tuple[str, int, bool]]:
    """(curve name, k, polarity match) of every swept filter; BA is k = 1."""
    out = [("background_activity", 1, False)]
    for pol in (False, True):
        out += [(f"stcf_k{k}" + ("_polarity" if pol else ""), k, pol) for k in STCF_KS]
    return out


def _keep(ev: EventPacket, name: str, k: int, pol: bool, dt: int, keep: np.ndarray) -> np.ndarray:
    if name == "background_activity":
        background_activity_kernel(ev.t, ev.x, ev.y, padded_timestamps(ev.sensor), dt, keep)
    else:
        stcf_kernel(ev.t, ev.x, ev.y, ev.p, padded_timestamps(ev.sensor, 2 if pol else 1), dt, k, pol, keep)
    return keep


def roc_sweep(ev: EventPacket, t_from: int | None = None) -> dict[str, list[dict[str, float]]]:
    """Signal kept / noise passed of BA (per dt) and STCF (per dt, k = 1..4,
    with and without polarity match) on a labelled packet (``noise``
    column); events before ``t_from`` µs feed the filters but are not scored."""
    keep = np.empty(len(ev), np.bool_)
    out: dict[str, list[dict[str, float]]] = {}
    for name, k, pol in _sweep_names():
        out[name] = []
        for dt in BA_DTS:
            tpr, fpr = denoise_rates(ev, _keep(ev, name, k, pol, dt, keep), t_from=t_from)
            out[name].append({"dt_us": dt, "k": k, "signal_kept": tpr, "noise_passed": fpr})
    return out


def at_defaults(ev: EventPacket, t_from: int | None = None) -> dict[str, dict[str, Any]]:
    """Signal kept / noise passed of the BA and STCF operators as built with
    their default parameters (run through ``process``, whatever the
    defaults are today), and of BA with ``dt_us="auto"`` (``dt_us``: the
    window it ended with)."""
    idx = ev.with_columns(index=np.arange(len(ev), dtype=np.int64))
    out: dict[str, dict[str, Any]] = {}
    ops: tuple[tuple[str, BackgroundActivity | SpatioTemporalCorrelation], ...] = (
        ("background_activity", BackgroundActivity()), ("stcf", SpatioTemporalCorrelation()),
        ("background_activity_auto", BackgroundActivity(dt_us="auto")))
    for name, op in ops:
        keep = np.zeros(len(ev), np.bool_)
        for q in [*op.process(idx), *op.finish()]:
            keep[cast(EventPacket, q).columns["index"]] = True
        tpr, fpr = denoise_rates(ev, keep, t_from=t_from)
        params: dict[str, Any] = {"dt_us": op.dt_us}
        if isinstance(op, SpatioTemporalCorrelation):
            params.update(k=op.k, polarity=op.polarity)
        out[name] = {**params, "signal_kept": tpr, "noise_passed": fpr}
    return out


def dt_for_signal(ev: EventPacket, goal: float = 0.9, *, k: int = 1, polarity: bool = False,
                  t_from: int | None = None, dt_max: int = 1_000_000) -> dict[str, float]:
    """The shortest dt (µs, to 2 %) at which a k-neighbour filter (k = 1 is
    BA) keeps the fraction ``goal`` of the signal, and the noise it then passes
    (signal kept grows with dt). NaN when even ``dt_max`` falls short."""
    name = "background_activity" if k == 1 and not polarity else "stcf"
    keep = np.empty(len(ev), np.bool_)

    def rates(dt: int) -> tuple[float, float]:
        return denoise_rates(ev, _keep(ev, name, k, polarity, dt, keep), t_from=t_from)

    if not rates(dt_max)[0] >= goal:
        return {"dt_us": float("nan"), "signal_kept": float("nan"), "noise_passed": float("nan")}
    lo, hi = 10, dt_max
    while hi > lo * 1.02 + 1:
        mid = int((lo * hi) ** 0.5)
        if rates(mid)[0] >= goal:
            hi = mid
        else:
            lo = mid
    tpr, fpr = rates(hi)
    return {"dt_us": float(hi), "signal_kept": tpr, "noise_passed": fpr}


def peer_roc(ev: EventPacket, quick: bool, t_from: int | None = None) -> dict[str, list[dict[str, float]]]:
    """The same sweep for the peers' BA filters (decisions matched on t, x, y)."""
    out: dict[str, list[dict[str, float]]] = {}
    dv = peer("dv_processing")
    if dv is not None:
        (store,) = _dv_stores(dv, [ev])
        out["dv-processing BA"] = []
        for dt in BA_DTS:
            f = _dv_ba(dv, ev.sensor, dt)
            f.accept(store)
            a = f.generateEvents().numpy()
            tpr, fpr = denoise_rates(ev, _kept_mask(ev, a["timestamp"], a["x"], a["y"]), t_from=t_from)
            out["dv-processing BA"].append({"dt_us": dt, "signal_kept": tpr, "noise_passed": fpr})
    tonic = peer("tonic.functional")
    if tonic is not None:  # pure Python: a prefix only
        t0 = ev.t_start if t_from is None else t_from
        small = ev.slice_time(None, t0 + (50_000 if quick else 100_000))
        arr = _structured(small, np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i1")]))
        out["tonic denoise"] = []
        for dt in BA_DTS[::2]:
            a = tonic.denoise_numpy(arr, filter_time=dt)
            tpr, fpr = denoise_rates(small, _kept_mask(small, a["t"], a["x"], a["y"]), t_from=t_from)
            out["tonic denoise"].append({"dt_us": dt, "signal_kept": tpr, "noise_passed": fpr})
    return out


def _auc(points: list[dict[str, float]]) -> float:
    return roc_auc([(p["signal_kept"], p["noise_passed"]) for p in points])


def sim_scene(name: str, sensor: tuple[int, int] = SIM_SENSOR) -> dict[str, Any]:
    """The scene dict of a bench scene (``SIM_SCENES``)."""
    base, velocity, _, _ = SIM_SCENES[name]
    d = load_scene(base, sensor)
    if velocity is not None:
        d["background"] = {**d["background"], "velocity": list(velocity)}
    d["name"] = name
    return d


def sim_stream(name: str, noise_hz: float, duration_us: int, *, sensor: tuple[int, int] = SIM_SENSOR,
               seed: int = 1) -> tuple[EventPacket, float]:
    """A bench scene simulated (preset ``ideal``: perfect pixels) with
    ``noise_hz`` Hz/px labelled shot noise; returns the events (columns
    ``noise``) and the median true speed (px/s) of their signal events."""
    ev, _ = simulate(sim_scene(name, sensor), duration_us, seed=seed, shot_noise_hz=noise_hz)
    sig = ev.columns["noise"] == 0
    spd = float(np.median(np.hypot(ev.columns["vx"][sig], ev.columns["vy"][sig]))) if sig.any() else float("nan")
    return ev.without_columns(*[c for c in ev.columns if c != "noise"]), spd


def sim_accuracy(quick: bool) -> dict[str, Any]:
    """ROC sweeps, AUCs, the defaults' operating points and the BA dt that
    keeps 90 % of signal, over simulator scenes x shot-noise rates."""
    res: dict[str, Any] = {"sensor": SIM_SENSOR, "warmup_us": SIM_WARMUP_US, "preset": "ideal + shot noise",
                           "conditions": []}
    for name, (_, _, d_quick, d_full) in SIM_SCENES.items():
        dur = d_quick if quick else d_full
        for noise in SIM_NOISE_HZ:
            ev, spd = sim_stream(name, noise, dur, seed=1 + int(noise * 10))
            t_from = ev.t_start + SIM_WARMUP_US
            scored = ev.t >= t_from
            sweeps = roc_sweep(ev, t_from)
            if name == SIM_REFERENCE[0] and noise == SIM_REFERENCE[1]:
                sweeps.update(peer_roc(ev, quick, t_from))
            res["conditions"].append({
                "scene": name, "noise_hz": noise, "duration_us": dur, "signal_speed_px_s": spd,
                "events": int(scored.sum()), "noise_fraction": float(ev.columns["noise"][scored].astype(bool).mean()),
                "sweeps": sweeps, "auc": {k: _auc(v) for k, v in sweeps.items()},
                "defaults": at_defaults(ev, t_from),
                "ba_dt_for_90pct_signal": dt_for_signal(ev, 0.9, t_from=t_from),
                "stcf_k2_dt_for_90pct_signal": dt_for_signal(ev, 0.9, k=2, t_from=t_from),
            })
            c = res["conditions"][-1]
            print(f"  sim {name:18s} {noise:5.1f} Hz/px  {c['events']:9d} ev  noise {c['noise_fraction']:.1%}  "
                  f"AUC BA {c['auc']['background_activity']:.3f}", flush=True)
    return res


def pattern_accuracy(quick: bool) -> dict[str, Any]:
    """ROC sweeps and AUCs on the ``pattern:`` bars (128x96 sensor) over
    noise rates and bar speeds: the earlier, simpler labelled input."""
    sensor, dur = (128, 96), 150_000 if quick else 300_000
    res: dict[str, Any] = {"sensor": sensor, "duration_us": dur, "conditions": []}
    for noise in NOISE_HZ:
        for spd in SPEEDS:
            ev = labelled_stream(sensor=sensor, duration_us=dur, noise_hz=noise, speed=spd, seed=int(noise * 10))
            sweeps = roc_sweep(ev)
            res["conditions"].append({
                "noise_hz": noise, "speed_px_s": spd, "events": len(ev),
                "noise_fraction": float(ev.columns["noise"].mean()),
                "sweeps": sweeps, "auc": {k: _auc(v) for k, v in sweeps.items()},
                "defaults": at_defaults(ev),
            })
    return res


def auc_rows(acc: dict[str, Any], keys: tuple[str, ...]) -> list[dict[str, Any]]:
    """One row per condition: its keys, then the AUC of every curve."""
    return [{**{k: c[k] for k in keys}, **{n.replace("_polarity", "p").replace("background_activity", "BA"): a
                                            for n, a in c["auc"].items()}} for c in acc["conditions"]]


def default_rows(acc: dict[str, Any], keys: tuple[str, ...]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """One row per condition: signal kept / noise passed at the defaults,
    and (simulator) the BA and STCF dt that keep 90 % of the signal; and per
    condition the target that BA at its defaults keeps 90 % of the signal
    (``BA_90`` in the rows: met or MISSED)."""
    rows, targets = [], []
    for c in acc["conditions"]:
        ba, st = c["defaults"]["background_activity"], c["defaults"]["stcf"]
        cond = ", ".join(c[k] if isinstance(c[k], str) else f"{k} {c[k]:.3g}" for k in keys)
        targets.append(target(f"BA defaults keep signal ({cond})", ba["signal_kept"], 0.9, "fraction"))
        r = {**{k: c[k] for k in keys}, "BA_sig": ba["signal_kept"], "BA_noise": ba["noise_passed"],
             "BA_90": target_row(targets[-1])["met"], "STCF_sig": st["signal_kept"], "STCF_noise": st["noise_passed"]}
        if "background_activity_auto" in c["defaults"]:  # BA dt_us="auto": not a default, no target
            au = c["defaults"]["background_activity_auto"]
            r.update({"BAauto_sig": au["signal_kept"], "BAauto_noise": au["noise_passed"], "BAauto_dt": au["dt_us"]})
        if "ba_dt_for_90pct_signal" in c:
            b, s2 = c["ba_dt_for_90pct_signal"], c["stcf_k2_dt_for_90pct_signal"]
            r.update({"BA_dt90": b["dt_us"], "BA_noise@dt90": b["noise_passed"],
                      "STCF_dt90": s2["dt_us"], "STCF_noise@dt90": s2["noise_passed"]})
        rows.append(r)
    return rows, targets


def setting_speeds(ev: EventPacket, quick: bool) -> list[dict[str, Any]]:
    """Mev/s of every swept setting (BA dt; STCF dt, k, polarity), and dv's BA."""
    pieces = chunks(ev)
    rows = []
    for name, k, pol in _sweep_names():
        for dt in BA_DTS:
            make: Callable[[], Any] = (partial(BackgroundActivity, dt_us=dt) if name == "background_activity"
                                       else partial(SpatioTemporalCorrelation, dt_us=dt, k=k, polarity=pol))
            r = throughput(_feed_all(make, pieces), len(ev), repeat=2 if quick else 3)
            rows.append({"filter": name, "dt_us": dt, "mev_s": r["mev_s"]})
    dv = peer("dv_processing")
    if dv is not None:
        stores = _dv_stores(dv, pieces)
        for dt in BA_DTS:
            rows.append({"filter": "dv-processing BA", "dt_us": dt,
                         "mev_s": throughput(_dv_ba_fn(dv, stores, ev.sensor, dt), len(ev), repeat=2)["mev_s"]})
    return rows


# -- real recordings -------------------------------------------------------------
def read_ecd_events(path: Path, sensor: tuple[int, int] = (240, 180)) -> EventPacket:
    """An ECD ``events.txt`` (``t x y p``, t in seconds) as a packet."""
    a = np.loadtxt(path, ndmin=2)
    return EventPacket.from_arrays(np.rint(a[:, 0] * 1e6).astype(np.int64), a[:, 1], a[:, 2], a[:, 3], sensor=sensor)


def real_recordings(out: Path) -> dict[str, Any]:
    root = shared_data()
    if root is None:
        return {"skipped": "../shared/data is absent (set TECTUM_SHARED_DATA)"}
    res: dict[str, Any] = {}
    for d in sorted((root / "ecd").glob("*/events.txt")):
        ev = read_ecd_events(d)
        row: dict[str, float] = {"events": len(ev)}
        for name, op in (("background_activity", BackgroundActivity()), ("stcf", SpatioTemporalCorrelation()),
                         ("refractory_1ms", Refractory(period_us=1000))):
            row[name] = len(op.process(ev)[0]) / len(ev)
        res[d.parent.name] = row
        if d.parent.name == "slider_depth":
            kept = BackgroundActivity().process(ev)[0]
            t1 = ev.t_start + 30_000  # 30 ms: long enough to see edges, short enough not to saturate
            res["picture"] = str(_before_after(ev.slice_time(None, t1), kept.slice_time(None, t1),
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
_STYLE = {"background_activity": ("k", "o"), "stcf_k1": ("C0", "v"), "stcf_k2": ("C1", "s"), "stcf_k3": ("C2", "^"),
          "stcf_k4": ("C3", "D")}


def _style(name: str) -> tuple[str, str, str]:
    """(colour, marker, line style) of a curve: STCF with polarity dashed."""
    colour, marker = _STYLE.get(name.replace("_polarity", ""), ("0.5", "x"))
    return colour, marker, "--" if name.endswith("_polarity") else "-"


def charts(out: Path, acc: dict[str, Any], settings: list[dict[str, Any]]) -> list[str]:
    """``filters-speed-auc.png`` (each setting's speed and single-point AUC
    on the reference simulator condition, peers marked) and
    ``filters-roc.png`` (ROC curves, simulator scenes x noise rates)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    files = []
    ref = next(c for c in acc["conditions"] if (c["scene"], c["noise_hz"]) == SIM_REFERENCE)
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for name in [*(n for n, _, _ in _sweep_names()), "dv-processing BA"]:
        pts = {p["dt_us"]: p for p in ref["sweeps"].get(name, [])}
        xs, ys = [], []
        for s in settings:
            if s["filter"] == name and s["dt_us"] in pts:
                p = pts[s["dt_us"]]
                xs.append(s["mev_s"])
                ys.append(roc_auc([(p["signal_kept"], p["noise_passed"])]))
        if not xs:
            continue
        if name.startswith("dv"):
            ax.scatter(xs, ys, marker="x", c="m", s=60, label=name + " (peer, C++)")
        else:
            colour, marker, ls = _style(name)
            ax.scatter(xs, ys, marker=marker, s=25, label=name, edgecolors=colour,
                       facecolors="none" if ls == "--" else colour)
    ax.set_xscale("log")
    ax.set_xlabel("throughput (Mev/s, one core, 10 ms packets)")
    ax.set_ylabel("AUC of the setting's ROC point ((1 + kept - passed) / 2)")
    ax.set_title(f"speed vs accuracy, one point per setting (dt {BA_DTS[0]}..{BA_DTS[-1]} µs)\n"
                 f"simulator '{SIM_REFERENCE[0]}' {SIM_SENSOR[0]}x{SIM_SENSOR[1]}, {SIM_REFERENCE[1]} Hz/px shot noise"
                 f" (hollow: polarity match)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    p = out / "filters-speed-auc.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files.append(str(p))

    scenes = list(dict.fromkeys(c["scene"] for c in acc["conditions"]))
    noises = list(dict.fromkeys(c["noise_hz"] for c in acc["conditions"]))
    fig, axes = plt.subplots(len(scenes), len(noises), figsize=(3.6 * len(noises), 3.2 * len(scenes)),
                             sharex=True, sharey=True, squeeze=False)
    for i, scene in enumerate(scenes):
        for j, noise in enumerate(noises):
            ax = axes[i, j]
            c = next(c for c in acc["conditions"] if c["scene"] == scene and c["noise_hz"] == noise)
            for name, sw in c["sweeps"].items():
                f = [q["noise_passed"] for q in sw]
                t = [q["signal_kept"] for q in sw]
                if name.startswith(("dv", "tonic")):
                    ax.plot(f, t, "x:", c="m" if name.startswith("dv") else "c", ms=5, label=name + " (peer)")
                else:
                    colour, marker, ls = _style(name)
                    ax.plot(f, t, ls, c=colour, marker=marker, ms=3, lw=1, label=name)
            for key, m in (("background_activity", "*"), ("stcf", "P")):
                d = c["defaults"][key]
                ax.plot(d["noise_passed"], d["signal_kept"], m, c="r", ms=10, mfc="none",
                        label=f"{key} default" if (i, j) == (0, 0) else None)
            ax.axhline(0.9, c="0.8", lw=0.5)
            ax.set_xscale("symlog", linthresh=1e-3)
            ax.set_xlim(0, 1)
            ax.set_ylim(0, 1.02)
            ax.set_title(f"{scene} ({c['signal_speed_px_s']:.0f} px/s), {noise} Hz/px\n"
                         f"AUC BA {c['auc']['background_activity']:.3f}, STCF k2 {c['auc']['stcf_k2']:.3f}", fontsize=8)
            if i == len(scenes) - 1:
                ax.set_xlabel("noise passed")
            if j == 0:
                ax.set_ylabel("signal kept")
    handles, labels = [], []
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=6, fontsize=8)
    fig.suptitle(f"ROC over dt (simulator {SIM_SENSOR[0]}x{SIM_SENSOR[1]}, labelled shot noise; "
                 f"dashed: polarity match; red: defaults; median signal speed in brackets)")
    fig.tight_layout(rect=(0, 0.04, 1, 0.98))
    p = out / "filters-roc.png"
    fig.savefig(p, dpi=90)
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
    gap_rows, gap_targets = pipeline_gap(ev_plain, quick)
    print("pipeline against the operator without the engine (one array; no engine: a plain loop over 10 ms "
          "packets; CPU time, medians of interleaved rounds; spread = min-max):")
    print(table(gap_rows, ["operation", "path", "cpu_mev_s", "spread", "mev_s"]))
    # the peers get the whole stream (the 5 M events; it was 1 M, where a
    # pipeline's fixed cost per run, about 0.15-0.3 ms, was 6-17 % of a run at 5 Mev/s)
    peer_ev = ev_plain.slice_time(None, int(ev_plain.t[min(len(ev_plain) - 1, 300_000)])) if quick else ev_plain
    n_peer = len(peer_ev)
    peer_rows, peer_tgts = peer_targets(peer_ev, quick)
    if peer_rows:
        print(f"tectum (pipeline, 10 ms packets) against dv-processing, {n_peer:,} events, medians of "
              "interleaved rounds (wall ratio, its spread over rounds, CPU ratio):")
        print(table(peer_rows, ["operation", "rate_mev_s", "tectum", "dv", "ratio", "spread", "cpu_ratio",
                                "memory_limit_mev_s"]))
    speed_targets = gap_targets + peer_tgts
    print(table([target_row(t) for t in speed_targets], TARGET_COLUMNS))

    print(f"accuracy on the simulator ({SIM_SENSOR[0]}x{SIM_SENSOR[1]}, shot noise {SIM_NOISE_HZ} Hz/px, "
          f"first {SIM_WARMUP_US // 1000} ms not scored):")
    acc = sim_accuracy(quick)
    sim_keys = ("scene", "signal_speed_px_s", "noise_hz")
    sim_auc = auc_rows(acc, sim_keys)
    print("AUC per filter (BA; STCF k = 1..4, 'p' = polarity match), simulator:")
    print(table(sim_auc, list(sim_auc[0])))
    sim_def, sim_targets = default_rows(acc, sim_keys)
    d = acc["conditions"][0]["defaults"]
    print(f"at the defaults (BA dt {d['background_activity']['dt_us']} µs; STCF dt {d['stcf']['dt_us']} µs, "
          f"k {d['stcf']['k']}): signal kept / noise passed, BA_90 the target of keeping 90 % of the signal; "
          f"dt90 = shortest dt keeping 90 % of signal; BAauto = BA with dt_us='auto' (not a default; dt: its "
          f"last window, µs):")
    print(table(sim_def, list(sim_def[0])))

    pat = pattern_accuracy(quick)
    pat_keys = ("noise_hz", "speed_px_s")
    pat_auc, (pat_def, pat_targets) = auc_rows(pat, pat_keys), default_rows(pat, pat_keys)
    print("AUC per filter, pattern: source (bars, 128x96):")
    print(table(pat_auc, list(pat_auc[0])))
    print(table(pat_def, list(pat_def[0])))

    _, _, ref_quick, ref_full = SIM_SCENES[SIM_REFERENCE[0]]
    ref_ev, _ = sim_stream(SIM_REFERENCE[0], SIM_REFERENCE[1], ref_quick if quick else ref_full,
                           seed=1 + int(SIM_REFERENCE[1] * 10))
    settings = setting_speeds(ref_ev.without_columns("noise"), quick)
    real = real_recordings(out)
    print("real recordings, fraction kept:", {k: v for k, v in real.items() if k != "picture"})
    files = charts(out, acc, settings)
    for f in files:
        print("wrote", f)
    return {"speed": rows, "accuracy": acc, "auc_table": sim_auc, "defaults_table": sim_def,
            "accuracy_pattern": pat, "auc_table_pattern": pat_auc, "defaults_table_pattern": pat_def,
            "setting_speeds": settings, "setting_speeds_stream": {"scene": SIM_REFERENCE[0], "events": len(ref_ev)},
            "real": real, "charts": files, "targets": speed_targets + sim_targets + pat_targets,
            "pipeline_gap": gap_rows, "peers": peer_rows,
            "stream": {"events": len(ev), "sensor": list(ev.sensor), "noise_hz": 2.0, "speed_px_s": 200.0}}
