"""Embedding a pipeline: direct stepping, and a background thread for
programs with no event loop (robot control loops).

Both leave the pipeline's **file sinks** closed unless asked
(``file_sinks=True``): a pipeline that :func:`tectum.run` has written is
often stepped or watched next, and opening its ``.npz``/``.raw``/``.h5``
... sinks again would replace what the run wrote with what the stepping
pushed. A file sink is one whose class names file extensions; every other
sink (a :class:`tectum.testing.ListSink`, a network or live-view sink) runs."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable, Iterable
from contextlib import aclosing
from types import MappingProxyType
from typing import Any

import trio

from ._graph import END, Graph
from ._packet import Packet
from ._pipeline import Pipeline, Plan
from ._registry import Registry
from ._scheduler import open_pipeline
from ._stats import Stats
from .errors import TectumError

__all__ = ["Stepper", "ThreadedPipeline"]


class Stepper:
    """Run a pipeline's operators with no scheduler: push a packet, get the
    outputs. For hard loops that own their timing.

    The pipeline's sources are not opened: :meth:`push` delivers packets as
    if source ``into`` had emitted them. Its sinks are opened and written
    synchronously (closed by :meth:`close`), except file sinks, which stay
    closed unless ``file_sinks=True`` (see the module docstring; their ids
    are in :attr:`left_out`). ``outputs`` names the nodes whose packets
    :meth:`push` returns.
    """

    def __init__(self, pipeline: Pipeline | Plan, outputs: Iterable[str] = (), *,
                 registry: Registry | None = None, file_sinks: bool = False) -> None:
        plan = pipeline if isinstance(pipeline, Plan) else pipeline.validate(registry)
        plan, self.left_out = (plan, ()) if file_sinks else without_file_sinks(plan)
        self.plan = plan
        self.outputs = tuple(outputs)
        self.graph = Graph(plan, taps=self.outputs, offload=False)
        self._sinks = {n.id: n.instantiate() for n in plan.of_role("sink")}
        for s in self._sinks.values():
            s.bind_stats(self.graph.stats)
            s.open()
        self._sources = [n.id for n in plan.of_role("source")]
        self._ended: set[str] = set()
        self._closed = False

    @property
    def stats(self) -> Stats:
        self.graph.collect_counters()
        return self.graph.stats

    def _route(self, deliveries: list[tuple[str, Any]]) -> dict[str, list[Packet]]:
        out: dict[str, list[Packet]] = {o: [] for o in self.outputs}
        for target, pkt in deliveries:
            if pkt is END:
                continue
            if target.startswith("tap:"):
                out[target[4:]].append(pkt)
            else:
                self._sinks[target].write(pkt)
        return out

    def _source(self, into: str | None) -> str:
        if into is None:
            if len(self._sources) != 1:
                raise TectumError(f"the pipeline has sources {self._sources}: say which with into=")
            return self._sources[0]
        if into not in self._sources:
            raise TectumError(f"{into!r} is not a source of the pipeline ({self._sources})")
        return into

    def push(self, packet: Packet, into: str | None = None) -> dict[str, list[Packet]]:
        """Push one packet as the output of source ``into``; returns the
        packets each output node emitted in response."""
        return self._route(self.graph.push(self._source(into), packet))

    def end(self, into: str | None = None) -> dict[str, list[Packet]]:
        """End the stream of source ``into``: operators flush (once every
        source has ended, a feedback loop that waits on itself runs on
        without its feedback: :meth:`Graph.unstall`)."""
        sid = self._source(into)
        deliveries = self.graph.end(sid)
        self._ended.add(sid)
        if len(self._ended) == len(self._sources):
            deliveries += self.graph.unstall()
        return self._route(deliveries)

    def close(self) -> None:
        """Close the sinks (commit files)."""
        if not self._closed:
            self._closed = True
            for s in self._sinks.values():
                s.close()

    def __enter__(self) -> Stepper:
        return self

    def __exit__(self, *exc: Any) -> None:
        if exc[0] is None:
            self.close()
        else:
            self._closed = True
            for s in self._sinks.values():
                s.abort()


class ThreadedPipeline:
    """Run a pipeline in a background thread (its own trio loop), for
    programs with no event loop.

    ``latest(node)`` returns the newest packet a watched node emitted, with
    the ``time.monotonic()`` at which it was produced, or None before the
    first one (right after :meth:`start` the pipeline has usually produced
    nothing yet); ``wait_latest(node, timeout)`` waits for the first.
    ``on_output(node, fn)`` calls ``fn(packet)`` in the pipeline's thread
    for each one (keep it short). Watched nodes are read through a
    keep-latest edge of depth 1, so a slow reader never holds the pipeline
    back; what it skipped is counted. File sinks stay closed unless
    ``file_sinks=True`` (see the module docstring; their ids are in
    :attr:`left_out`); :meth:`stop` before the end commits what a file sink
    has written so far.
    """

    def __init__(self, pipeline: Pipeline | Plan, watch: Iterable[str], *,
                 registry: Registry | None = None, file_sinks: bool = False) -> None:
        plan = pipeline if isinstance(pipeline, Plan) else pipeline.validate(registry)
        self.plan, self.left_out = (plan, ()) if file_sinks else without_file_sinks(plan)
        self.watch = tuple(watch)
        self._lock = threading.Condition()
        self._latest: dict[str, tuple[Packet, float] | None] = {w: None for w in self.watch}
        self._callbacks: dict[str, list[Callable[[Packet], None]]] = {w: [] for w in self.watch}
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._token: trio.lowlevel.TrioToken | None = None
        self._running: Any = None
        self._started = threading.Event()
        self._done = threading.Event()
        self.stats: Stats | None = None

    def on_output(self, node: str, fn: Callable[[Packet], None]) -> None:
        """Call ``fn(packet)`` for each packet ``node`` emits (pipeline thread)."""
        self._callbacks[node].append(fn)

    def latest(self, node: str) -> tuple[Packet, float] | None:
        """The newest packet of ``node`` and when it came (monotonic s), or
        None when it has emitted nothing yet."""
        with self._lock:
            return self._latest[node]

    def wait_latest(self, node: str, timeout: float | None = None) -> tuple[Packet, float] | None:
        """:meth:`latest`, waiting up to ``timeout`` s (None: for ever) for
        ``node``'s first packet; None if the pipeline ended without one.
        Raises :class:`TimeoutError` when the time is up."""
        with self._lock:
            if not self._lock.wait_for(lambda: self._latest[node] is not None or self._done.is_set(), timeout):
                raise TimeoutError(f"{node!r} emitted nothing within {timeout} s")
            return self._latest[node]

    def start(self) -> ThreadedPipeline:
        self._thread = threading.Thread(target=self._main, name="tectum-pipeline", daemon=True)
        self._thread.start()
        self._started.wait()
        return self

    def _main(self) -> None:
        try:
            trio.run(self._amain)
        except BaseException as e:  # reported by join()
            self._error = e
        finally:
            self._started.set()
            with self._lock:
                self._done.set()
                self._lock.notify_all()

    async def _amain(self) -> None:
        self._token = trio.lowlevel.current_trio_token()
        async with open_pipeline(self.plan, taps=self.watch, tap_buffer=1, tap_policy="keep_latest") as run:
            self._running = run
            self.stats = run.stats
            self._started.set()
            async with trio.open_nursery() as n:
                for w in self.watch:
                    n.start_soon(self._pump, run, w)

    async def _pump(self, run: Any, node: str) -> None:
        async with aclosing(run.outputs(node)) as outputs:  # closed when the run stops, not by the collector
            async for pkt in outputs:
                with self._lock:
                    self._latest[node] = (pkt, time.monotonic())
                    self._lock.notify_all()
                for fn in self._callbacks[node]:
                    fn(pkt)

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def stop(self) -> None:
        """Ask the pipeline to stop (sinks are closed cleanly)."""
        if self._token is not None and not self._done.is_set():
            try:
                trio.from_thread.run_sync(self._running.cancel, trio_token=self._token)
            except trio.RunFinishedError:
                pass

    def join(self, timeout: float | None = None) -> Stats | None:
        """Wait for the end; re-raises the pipeline's error in this thread."""
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                raise TimeoutError("the pipeline is still running")
        if self._error is not None:
            raise self._error
        return self.stats

    def __enter__(self) -> ThreadedPipeline:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()
        self.join()


def without_file_sinks(plan: Plan) -> tuple[Plan, tuple[str, ...]]:
    """``plan`` without its file sinks (sinks whose class names file
    extensions), and their ids."""
    drop = {n.id for n in plan.of_role("sink") if getattr(n.cls, "extensions", ())}
    if not drop:
        return plan, ()
    nodes = {nid: dataclasses.replace(n, children=tuple(c for c in n.children if c not in drop))
             for nid, n in plan.nodes.items() if nid not in drop}
    order = tuple(nid for nid in plan.order if nid not in drop)
    return dataclasses.replace(plan, nodes=MappingProxyType(nodes), order=order), tuple(sorted(drop))
