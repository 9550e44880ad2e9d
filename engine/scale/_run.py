"""Running pipelines in shards: plan, execute, join in order.

:func:`run_many` takes pipelines (one per recording), cuts each into time
shards (:mod:`._plan`, warm-up from :mod:`._memory`), runs the shards on an
executor (:mod:`._executors`) and, in a thread beside it, joins each
pipeline's parts in shard order into its sinks through an ordinary run of
the scheduler: file sinks write to a temporary name and rename it when
complete, so a failed shard leaves no output, and outputs appear pipeline
by pipeline as they complete. The parts live in a scratch folder beside the
first file output (visible to a cluster's workers wherever the output is),
removed at the end.
"""

from __future__ import annotations

import glob
import os
import shutil
import tempfile
import threading
import time
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import trio

from tectum._operator import Source
from tectum._packet import Kind, Packet
from tectum._pipeline import Pipeline, Plan
from tectum._registry import Registry
from tectum._stats import Stats

from ._executors import ShardFailed, executor_for
from ._memory import Warmup, warmup_of
from ._plan import Shard, file_sources, plan_shards, stream_span
from ._task import ShardResult, ShardTask, pipeline_dict, read_part

__all__ = ["run", "run_many", "ShardedStats", "Job"]


@dataclass
class Job:
    """One pipeline of a sharded run: its plan, warm-up, shards, the
    results as they come, and the join's stats."""

    index: int
    pipeline: Pipeline
    plan: Plan
    warmup: Warmup
    shards: list[Shard]
    label: str
    plan_s: float
    results: dict[int, ShardResult] = field(default_factory=dict)
    error: str | None = None
    stats: Stats | None = None


class ShardedStats(Stats):
    """The stats of a sharded run: the sinks' nodes (from the join), plus
    per shard what it read (warm-up included) and kept, where it ran, its
    wall time, and which shards ran more than once (a worker died)."""

    def __init__(self) -> None:
        super().__init__()
        self.jobs: list[Job] = []
        self.attempts: dict[tuple[int, int], int] = {}

    @property
    def rerun(self) -> list[str]:
        """The shards that ran more than once, as ``label [a, b) µs: N runs``."""
        out = []
        for (j, k), n in sorted(self.attempts.items()):
            if n > 1:
                job = self.jobs[j]
                out.append(f"{job.label} {job.shards[k].describe()}: {n} runs")
        return out

    def shard_rows(self) -> list[dict[str, Any]]:
        return [{"file": job.label, "shard": r.index, "range": job.shards[r.index].describe(),
                 "events_in": r.events_in, "warmup_events": r.warmup_events, "events_out": r.events_out,
                 "wall_s": round(r.wall_s, 3), "cpu_s": round(r.cpu_s, 3), "host": r.host,
                 "runs": self.attempts.get((job.index, r.index), 1)}
                for job in self.jobs for _, r in sorted(job.results.items())]

    def as_dict(self) -> dict[str, Any]:
        return {**super().as_dict(), "shards": self.shard_rows(), "rerun": self.rerun,
                "warmup_us": {job.label: job.warmup.span_us for job in self.jobs},
                "plan_s": {job.label: job.plan_s for job in self.jobs}}

    def report(self) -> str:
        lines = [super().report(), "", "shards:"]
        for job in self.jobs:
            if len(job.shards) > 1:
                lines.append(f"  {job.label}: warm-up {job.warmup.span_us:,} µs"
                             + (f" on a {job.warmup.grid_us:,} µs grid" if job.warmup.grid_us > 1 else "")
                             + f", span found in {job.plan_s * 1e3:.0f} ms")
        for row in self.shard_rows():
            lines.append(f"  {row['file']} #{row['shard']} {row['range']}: {row['events_in']:,} events read "
                         f"({row['warmup_events']:,} warm-up), {row['events_out']:,} out, {row['wall_s']:.2f} s "
                         f"on {row['host']}" + (f", ran {row['runs']} times" if row["runs"] > 1 else ""))
        lines += [f"  ran twice: {r}" for r in self.rerun]
        return "\n".join(lines)


def run(pipeline: Pipeline | Plan, *, registry: Registry | None = None, clock: Any = None,
        shards: int | None = None, executor: Any = None, scheduler: str | None = None,
        workers: int | None = None, scratch: str | None = None) -> Stats:
    """Run a pipeline to the end; returns its :class:`tectum.Stats`.

    With ``shards=N`` or an ``executor``, the recording is cut into ``N``
    time shards (default: one per worker) run in parallel, each started a
    warm-up earlier (from the operators' declared memory), and their outputs
    joined in order: the result is identical to one sequential run.
    ``executor``: ``"local"`` (a process pool, the default), ``"dask"`` (a
    client to ``scheduler``, or a LocalCluster) or a ``distributed.Client``.
    Returns :class:`ShardedStats` then."""
    from tectum._scheduler import run as run_sequential

    if shards is None and executor is None:
        return run_sequential(pipeline, registry=registry, clock=clock)
    if isinstance(pipeline, Plan):
        raise TypeError("a sharded run takes a Pipeline (it is rebuilt on the workers), not a Plan")
    return run_many([pipeline], shards=shards, executor=executor, scheduler=scheduler, workers=workers,
                    scratch=scratch, registry=registry)


def run_many(pipelines: Sequence[Pipeline], *, shards: int | None = None, executor: Any = None,
             scheduler: str | None = None, workers: int | None = None, scratch: str | None = None,
             registry: Registry | None = None,
             progress: Callable[[ShardedStats, int], None] | None = None) -> ShardedStats:
    """Run several pipelines (one per recording), each in ``shards`` time
    shards (default 1 per pipeline when there are several, one per worker
    otherwise), on one executor; outputs are joined pipeline by pipeline.
    ``progress(stats, jobs_done)`` is called as shards finish. Raises
    :class:`ShardFailed` naming the recording and time range of a failed
    shard (outputs of pipelines already joined stay; none is half-written)."""
    ex = executor_for(executor, scheduler, workers)
    if shards is None:
        shards = 1 if len(pipelines) > 1 else max(1, workers or os.cpu_count() or 1)
    out = ShardedStats()
    began = time.perf_counter()
    scratch_dir = _scratch(pipelines, scratch)
    try:
        jobs = [_job(i, p, shards, registry) for i, p in enumerate(pipelines)]
        out.jobs = jobs
        tasks = [_task(job, s, scratch_dir) for job in jobs for s in job.shards]
        ready = threading.Condition()
        joiner = _Joiner(jobs, ready)
        joiner.start()
        done_jobs = 0
        results = ex.run(tasks)
        try:
            for res in results:
                job = jobs[res.job]
                with ready:
                    job.results[res.index] = res
                    if res.error is not None:
                        job.error = res.error
                    ready.notify_all()
                if res.error is not None:
                    raise ShardFailed(res.error)
                if len(job.results) == len(job.shards):
                    done_jobs += 1
                if progress is not None:
                    progress(out, done_jobs)
        except BaseException as e:
            joiner.fail(str(e) or type(e).__name__)
            raise
        finally:
            stop = getattr(results, "close", None)  # a generator: the executor stops, running shards end
            if stop is not None:
                stop()
            joiner.join()
        if joiner.error is not None:
            raise joiner.error
        out.attempts = _attempts(scratch_dir)
        for job in jobs:
            if job.stats is not None:
                for nid, st in job.stats.nodes.items():
                    out.nodes[nid if len(jobs) == 1 else f"{job.label}:{nid}"] = st
    finally:
        shutil.rmtree(scratch_dir, ignore_errors=True)
    out.wall_s = time.perf_counter() - began
    return out


def _job(index: int, p: Pipeline, shards: int, registry: Registry | None) -> Job:
    plan = p.validate(registry)
    file_sources(plan)  # refuses what cannot read a time range
    warm = warmup_of(plan) if shards > 1 else Warmup(0)
    label = ", ".join(n.spec.name for n in plan.of_role("source"))
    if shards > 1:
        span, took = stream_span(plan)
        cut = plan_shards(shards, span, warm)
    else:
        cut, took = [Shard(0, None, None, None)], 0.0
    return Job(index, p, plan, warm, cut, label, took)


def _task(job: Job, shard: Shard, scratch_dir: str) -> ShardTask:
    params: dict[str, dict[str, Any]] = {}
    for node in job.plan.of_role("source"):
        rng: dict[str, Any] = {}
        if shard.read_us is not None:
            rng["t_start_us"] = shard.read_us
        if shard.end_us is not None:
            rng["t_end_us"] = shard.end_us
        params[node.id] = rng
    outputs = tuple(dict.fromkeys(n.inputs[0] for n in job.plan.of_role("sink")))
    return ShardTask(job.index, shard, pipeline_dict(job.pipeline, params), outputs, scratch_dir, job.label)


def _scratch(pipelines: Sequence[Pipeline], scratch: str | None) -> str:
    """The parts' folder: ``scratch``, else beside the first file output
    (a cluster's workers see it wherever they see the output), else a
    temporary folder."""
    base = scratch
    if base is None:
        for p in pipelines:
            for s in p.nodes:
                url = "://" in s.name or s.name.endswith(":")
                if s.role == "sink" and s.component is None and not url \
                        and os.path.isdir(os.path.dirname(os.path.abspath(s.name))):
                    base = os.path.dirname(os.path.abspath(s.name))
                    break
            if base is not None:
                break
    return tempfile.mkdtemp(prefix=".tectum-shards-", dir=base)


def _attempts(scratch_dir: str) -> dict[tuple[int, int], int]:
    """How many times each (job, shard) started, from the markers."""
    out: dict[tuple[int, int], int] = {}
    for name in os.listdir(scratch_dir):
        if name.startswith("attempt-"):
            _, j, k, _ = name.split("-")
            key = (int(j), int(k))
            out[key] = out.get(key, 0) + 1
    return out


class PartsSource(Source):
    """The parts of one output node of a job, shard after shard, waiting
    (in a thread) for each shard to finish; a failed shard stops it with
    :class:`ShardFailed`."""

    name = "parts"

    def __init__(self, job: Job, output: str, ready: threading.Condition, produces: frozenset[Kind]) -> None:
        self.job, self.output, self.ready = job, output, ready
        self.produces = tuple(produces)  # type: ignore[misc]  # the node's kinds, for validation
        self.counts: dict[str, int] = {}

    def _wait(self, k: int) -> str:
        with self.ready:
            self.ready.wait_for(lambda: k in self.job.results or self.job.error is not None)
            if self.job.error is not None:
                raise ShardFailed(self.job.error)
            return self.job.results[k].parts[self.output]

    async def apackets(self) -> AsyncIterator[Packet]:
        for k in range(len(self.job.shards)):
            path = await trio.to_thread.run_sync(self._wait, k)
            for pkt in read_part(path):
                yield pkt


class _Joiner(threading.Thread):
    """Joins the jobs' parts into their sinks, job after job."""

    def __init__(self, jobs: Sequence[Job], ready: threading.Condition) -> None:
        super().__init__(name="tectum-join", daemon=True)
        self.jobs, self.ready = jobs, ready
        self.error: BaseException | None = None

    def fail(self, message: str) -> None:
        with self.ready:
            for job in self.jobs:
                if job.error is None and len(job.results) < len(job.shards):
                    job.error = message
            self.ready.notify_all()

    def run(self) -> None:
        from tectum._scheduler import run as run_sequential

        try:
            for job in self.jobs:
                job.stats = run_sequential(self._join_pipeline(job))
        except BaseException as e:  # re-raised by run_many
            self.error = _unwrap(e)
            self.fail(str(e))

    def _join_pipeline(self, job: Job) -> Pipeline:
        p = Pipeline(job.pipeline.batch)
        made: dict[str, str] = {}
        for node in job.plan.of_role("sink"):
            s, up = node.spec, node.inputs[0]
            if up not in made:
                made[up] = p.source(PartsSource(job, up, self.ready, job.plan.nodes[up].provides),
                                    id=f"parts.{len(made)}")
            p.sink(s.component if s.component is not None else s.name, made[up], id=s.id, policy=s.policy,
                   buffer=s.buffer, **s.params)
        return p


def _unwrap(e: BaseException) -> BaseException:
    """A failed join's cause: the ShardFailed inside a NodeError, if any."""
    seen: BaseException | None = e
    while seen is not None:
        if isinstance(seen, ShardFailed):
            return seen
        seen = seen.__cause__
    return e


def expand(pattern: str) -> list[str]:
    """The files a glob pattern names (``**`` recursive), sorted."""
    return sorted(f for f in glob.glob(pattern, recursive=True) if os.path.isfile(f))
