"""Scaling out (tectum.scale): speed-up of time shards and of many recordings.

A large recording is generated straight to a Prophesee DAT file by numpy
(640x480, 20 Mev/s of uniformly scattered events; >= 200 M events in the full
run, 10 M with ``--quick``) in a temporary folder, deleted afterwards. The
chain is the "representations for every recording" job: a denoiser, plane-fit
flow and count images every 50 ms (``filter.background_activity`` ->
``flow.plane_fit`` -> ``repr.count``). Measured by the wall clock:

* one sequential ``tectum.run`` (the reference) against the same chain in 1
  and 2 time shards on a Dask ``LocalCluster`` of 2 single-threaded worker
  processes (started once, its start-up reported apart) and on the local
  process pool; the output is checked to be identical frame for frame;
* the warm-up overlap: events read twice (in a shard's warm-up and by the
  shard before) as a share of the recording;
* many recordings: the recording cut into 4 files, run one after another
  against one pipeline per file on 2 workers;
* the seek cost per format: time to the first event of a range starting 3/4
  into a 2 M-event recording (DAT bisection, AEDAT 4 packet table, DSEC
  HDF5 ``ms_to_idx``, EVT 2.0 bisection on its time bases, EVT 3.0 with no
  index: decoded from the start).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

import tectum
from tectum.evaluation.harness import table, target, targets_table
from tectum.testing import ListSink

SENSOR = (640, 480)
RATE_HZ = 20e6
OPS: list[tuple[str, dict[str, Any]]] = [("filter.background_activity", {"dt_us": 1000}),
                                         ("flow.plane_fit", {}), ("repr.count", {"window_us": 50_000})]
_CHUNK = 5_000_000


def write_dat(path: Path, n: int, t0: int = 0, seed: int = 0) -> Path:
    """``n`` events at :data:`RATE_HZ` from ``t0`` µs, pixels uniform on
    :data:`SENSOR`, random polarity: a DAT file written chunk by chunk."""
    rng = np.random.default_rng(seed)
    w, h = SENSOR
    with open(path, "wb") as f:
        f.write(f"% Data file containing CD events\n% Version 2\n% Width {w}\n% Height {h}\n".encode())
        f.write(bytes([12, 8]))
        for a in range(0, n, _CHUNK):
            m = min(_CHUNK, n - a)
            rec = np.empty((m, 2), "<u4")
            rec[:, 0] = t0 + (np.arange(a, a + m, dtype=np.float64) * (1e6 / RATE_HZ)).astype(np.uint32)
            x = rng.integers(0, w, m, dtype=np.uint32)
            y = rng.integers(0, h, m, dtype=np.uint32)
            rec[:, 1] = x | (y << 14) | (rng.integers(0, 2, m, dtype=np.uint32) << 28)
            rec.tofile(f)
    return path


def _pipeline(path: Path) -> tuple[tectum.Pipeline, ListSink]:
    p = tectum.Pipeline()
    node = p.source(str(path))
    for name, params in OPS:
        node = p.op(name, node, **params)
    sink = ListSink()
    p.sink(sink, node)
    return p, sink


def _same(a: ListSink, b: ListSink) -> bool:
    """The same frames: times and images."""
    fa, fb = ([p for p in s.packets if isinstance(p, tectum.FramePacket) and len(p)] for s in (a, b))
    return sum(len(p) for p in fa) == sum(len(p) for p in fb) and all(
        np.array_equal(x.t, y.t) and np.array_equal(x.images, y.images)
        for x, y in zip(tectum.concat(fa).batches(1), tectum.concat(fb).batches(1)))


def _timed(fn: Any) -> tuple[float, Any]:
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def _measured(fn: Any) -> tuple[float, float, Any]:
    """Wall time, this process's CPU time and the result of ``fn()``."""
    c0 = time.process_time()
    wall, out = _timed(fn)
    return wall, time.process_time() - c0, out


def _row(run: str, executor: str, n: int, wall: float, seq_wall: float, seq_cpu: float, driver_cpu: float,
         stats: Any) -> dict[str, Any]:
    """A sharded run's measures. ``cpu_bound_x``: the speed-up the CPU times
    allow on 2 free cores: the sequential run's CPU time over the longest
    of a shard's, half the shards' total and the driver's (plan and join)
    CPU time. The machine is shared, so the wall clock's speed-up depends on
    what else runs; this one does not."""
    shards = stats.shard_rows()
    cpus = [r["cpu_s"] for r in shards]
    work = max(max(cpus), sum(cpus) / 2, driver_cpu)
    return {"run": run, "executor": executor, "shards": len(shards), "wall_s": wall, "speed_up": seq_wall / wall,
            "cpu_bound_x": seq_cpu / work, "shard_cpu_s": sum(r["cpu_s"] for r in shards),
            "driver_cpu_s": driver_cpu, "mev_s": n / wall / 1e6,
            "warmup_share": sum(r["warmup_events"] for r in shards) / n}


def _shard_rows(path: Path, n: int, client: Any) -> tuple[list[dict[str, Any]], dict[str, float]]:
    p, ref = _pipeline(path)
    seq_s, seq_cpu, _ = _measured(lambda: tectum.run(p))
    rows = [{"run": "sequential", "executor": "-", "shards": 1, "wall_s": seq_s, "speed_up": 1.0,
             "cpu_bound_x": 1.0, "shard_cpu_s": seq_cpu, "mev_s": n / seq_s / 1e6, "warmup_share": 0.0,
             "identical": True}]
    for executor in ("dask", "local"):
        for shards in (1, 2):
            p, sink = _pipeline(path)
            ex = client if executor == "dask" else "local"
            wall, cpu, stats = _measured(lambda p=p, shards=shards, ex=ex: tectum.run(p, shards=shards, workers=2,
                                                                                      executor=ex))
            rows.append({**_row("time shards", executor, n, wall, seq_s, seq_cpu, cpu, stats),
                         "identical": _same(ref, sink)})
    return rows, {"sequential_s": seq_s, "sequential_cpu_s": seq_cpu}


def _warm(folder: Path, client: Any) -> None:
    """Compile or load the kernels here and in every worker before timing."""
    small = write_dat(folder / "warm.dat", 200_000)
    tectum.run(_pipeline(small)[0])
    for executor in (client, "local"):
        tectum.run(_pipeline(small)[0], shards=2, workers=2, executor=executor)


def _glob_rows(folder: Path, n: int, client: Any) -> list[dict[str, Any]]:
    files = [write_dat(folder / f"part{i}.dat", n // 4, seed=i + 1) for i in range(4)]
    seq_s, seq_cpu, _ = _measured(lambda: [tectum.run(_pipeline(f)[0]) for f in files])
    rows = [{"run": "4 files, one after another", "executor": "-", "wall_s": seq_s, "speed_up": 1.0,
             "cpu_bound_x": 1.0, "mev_s": n / seq_s / 1e6}]
    from tectum.scale import run_many

    for executor in ("dask", "local"):
        ex = client if executor == "dask" else "local"
        wall, cpu, stats = _measured(lambda ex=ex: run_many([_pipeline(f)[0] for f in files], shards=1, workers=2,
                                                            executor=ex))
        rows.append(_row("4 files, a pipeline each", executor, n, wall, seq_s, seq_cpu, cpu, stats))
    return rows


def _seek_rows(folder: Path) -> list[dict[str, Any]]:
    """Time to the first event of a range 3/4 into a 2 M-event recording, per
    format (writers: tectum's own), against reading it from the start."""
    n = 2_000_000
    dat = write_dat(folder / "seek.dat", n)
    span = int(n * 1e6 / RATE_HZ)
    rows: list[dict[str, Any]] = []
    for ext in (".dat", ".aedat4", ".h5", ".raw", ".evt3.raw"):
        path = dat if ext == ".dat" else folder / f"seek{ext}"
        if ext != ".dat":
            try:
                p = tectum.Pipeline()
                p.sink(str(path), p.source(str(dat)))
                tectum.run(p)
            except Exception as e:  # an optional writer (h5py) missing
                rows.append({"format": ext, "note": f"not measured: {e}"})
                continue

        def first(path: Path = path, **kw: Any) -> None:
            cls: Any = tectum.get_registry().source_for(str(path))
            src = cls(str(path), **kw)
            try:
                next(iter(src.packets()))
            finally:
                src.close()

        first()  # compiled, cached
        whole, _ = _timed(lambda: first())
        seek, _ = _timed(lambda: first(t_start_us=3 * span // 4))
        rows.append({"format": ext, "first_packet_ms": whole * 1e3, "seek_3/4_ms": seek * 1e3,
                     "how": {".dat": "bisection", ".aedat4": "packet table", ".h5": "ms_to_idx",
                             ".raw": "bisection on time bases",
                             ".evt3.raw": "no index: decoded from the start"}[ext]})
    return rows


def run(out: Path, quick: bool) -> dict[str, Any]:
    n = 10_000_000 if quick else 200_000_000
    folder = Path(tempfile.mkdtemp(prefix="tectum-bench-scale-"))
    try:
        gen_s, path = _timed(lambda: write_dat(folder / "large.dat", n))
        print(f"generated {n:,} events ({os.path.getsize(path) / 1e9:.2f} GB DAT) in {gen_s:.1f} s")
        try:
            import distributed
        except ImportError:
            raise tectum.TectumError('bench scale needs dask.distributed: pip install "tectum[dask]"') from None
        up_s, cluster = _timed(lambda: distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                                dashboard_address=":0"))
        with cluster, distributed.Client(cluster) as client:
            print(f"LocalCluster of 2 worker processes up in {up_s:.1f} s")
            _warm(folder, client)
            rows, _ = _shard_rows(path, n, client)
            path.unlink()
            print(table(rows, ["run", "executor", "shards", "wall_s", "speed_up", "cpu_bound_x", "shard_cpu_s",
                               "driver_cpu_s", "mev_s", "warmup_share", "identical"]))
            glob_rows = _glob_rows(folder, n, client)
        print(table(glob_rows, ["run", "executor", "wall_s", "speed_up", "cpu_bound_x", "mev_s"]))
        seek = _seek_rows(folder)
        print(table(seek, ["format", "first_packet_ms", "seek_3/4_ms", "how", "note"]))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    two = next(r for r in rows if r["executor"] == "dask" and r["shards"] == 2)
    many = next(r for r in glob_rows if r["executor"] == "dask")
    targets = [target("identical output, every sharded run", float(all(r["identical"] for r in rows)), 1.0, "bool"),
               target("2 shards on 2 cores (Dask LocalCluster), speed-up by the wall clock", two["speed_up"], 1.6,
                      "x"),
               target("2 shards (Dask), speed-up the CPU times allow", two["cpu_bound_x"], 1.6, "x"),
               target("4 files on 2 workers (Dask), speed-up by the wall clock", many["speed_up"], 1.6, "x"),
               target("warm-up overlap, 2 shards", two["warmup_share"] * 100, 1.0, "% of events", False)]
    print(targets_table(targets))
    return {"events": n, "generate_s": gen_s, "cluster_start_s": up_s, "shards": rows, "files": glob_rows,
            "seek": seek, "targets": targets}
