"""Where shards run: a process pool on this machine, or a Dask cluster.

Both take :class:`ShardTask` descriptions and yield :class:`ShardResult` in
the order shards finish. A worker that dies mid-shard is retried (the local
pool starts a fresh pool and resubmits what the broken one held; Dask
reschedules the task on another worker, up to its ``allowed-failures``, and
``retries`` re-runs a task that raised); a shard given up on raises
:class:`ShardFailed`. ``dask.distributed`` is imported only when asked for
(``pip install "tectum[dask]"``).
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from tectum.errors import TectumError

from ._task import ShardResult, ShardTask, run_shard

__all__ = ["ShardFailed", "LocalExecutor", "DaskExecutor", "executor_for"]


class ShardFailed(TectumError):
    """A shard failed: the message names the recording and its time range."""


class LocalExecutor:
    """A pool of ``workers`` processes on this machine (default: one per
    core, at most one per shard); a shard whose worker died is run again,
    up to ``retries`` times."""

    def __init__(self, workers: int | None = None, retries: int = 2) -> None:
        self.workers = workers
        self.retries = retries

    def run(self, tasks: Sequence[ShardTask]) -> Iterator[ShardResult]:
        n = max(1, min(self.workers or os.cpu_count() or 1, len(tasks)))
        ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
        todo = list(tasks)
        deaths: dict[tuple[int, int], int] = {}
        while todo:
            pool = ProcessPoolExecutor(n, mp_context=ctx)
            futures: dict[Future[ShardResult], ShardTask] = {pool.submit(run_shard, t): t for t in todo}
            todo = []
            try:
                pending = set(futures)
                while pending:
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for f in done:
                        try:
                            yield f.result()
                        except BrokenProcessPool:
                            t = futures[f]
                            key = (t.job, t.shard.index)
                            deaths[key] = deaths.get(key, 0) + 1
                            if deaths[key] > self.retries:
                                raise ShardFailed(f"{t.label} {t.shard.describe()}: its worker died "
                                                  f"{deaths[key]} times") from None
                            todo.append(t)
            finally:
                pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
    """Shards as tasks of a ``dask.distributed`` client: the given one, one
    connected to ``scheduler`` (an address), or a ``LocalCluster`` of
    ``workers`` single-threaded processes started here (and closed after)."""

    def __init__(self, client: Any = None, scheduler: str | None = None, workers: int | None = None,
                 retries: int = 2) -> None:
        self.client, self.scheduler, self.workers, self.retries = client, scheduler, workers, retries

    def run(self, tasks: Sequence[ShardTask]) -> Iterator[ShardResult]:
        try:
            from distributed import Client, LocalCluster, as_completed
        except ImportError:
            raise TectumError('--executor dask needs dask.distributed: pip install "tectum[dask]"') from None
        own: list[Any] = []
        client = self.client
        if client is None:
            if self.scheduler:
                client = Client(self.scheduler)
            else:
                n = max(1, min(self.workers or os.cpu_count() or 1, len(tasks)))
                cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0")
                own.append(cluster)
                client = Client(cluster)
            own.insert(0, client)
        futures = [client.submit(run_shard, t, retries=self.retries, pure=False) for t in tasks]
        by_key = {f.key: t for f, t in zip(futures, tasks)}
        try:
            for f in as_completed(futures):
                try:
                    yield f.result()
                except Exception as e:  # a worker died too often (KilledWorker), or the task raised
                    t = by_key[f.key]
                    raise ShardFailed(f"{t.label} {t.shard.describe()}: {type(e).__name__}: {e}") from None
        finally:
            client.cancel(futures)
            for thing in own:
                thing.close()


def executor_for(executor: Any, scheduler: str | None = None, workers: int | None = None) -> Any:
    """An executor from what the user gave: None or ``"local"`` (a process
    pool), ``"dask"`` (a Dask client to ``scheduler``, or a LocalCluster), a
    ``distributed.Client``, or an object with ``run(tasks)``."""
    if executor is None or executor == "local":
        return LocalExecutor(workers)
    if executor == "dask":
        return DaskExecutor(scheduler=scheduler, workers=workers)
    if hasattr(executor, "run") and not hasattr(executor, "submit"):
        return executor
    if hasattr(executor, "submit") and hasattr(executor, "gather"):
        return DaskExecutor(client=executor)
    raise TectumError(f"executor {executor!r}: expected 'local', 'dask' or a dask.distributed Client")
