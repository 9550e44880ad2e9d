"""A shard as a small task description, and the function a worker runs.

A :class:`ShardTask` holds the pipeline as data (the dict form of
:meth:`tectum.Pipeline.from_dict`, sources given their shard's time range,
sinks left out), the nodes whose output the sinks want, the shard and the
folder for its output parts: no events travel to a worker. The worker reads
its range, pushes it through the operators with a :class:`tectum.Stepper`,
drops what they emit while the input is still before the shard's start (the
warm-up), and writes what follows to one part file per output node: pickled
packets in order, written under a temporary name and renamed when complete.
The last shard ends the stream (operators flush); the others stop when the
input reaches their end, as a sequential run has at that time.

Bad input (a damaged file, an invalid parameter) comes back as the result's
``error`` rather than as an exception, so an executor does not retry it; a
worker that dies is retried by the executor, and each attempt leaves a
marker file, so the run can tell which shards ran twice.
"""

from __future__ import annotations

import heapq
import os
import pickle
import socket
import time
import uuid
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, cast

from tectum._boundary import Guard
from tectum._packet import EventPacket, Packet, packet_class
from tectum._pipeline import Pipeline
from tectum._samples import SamplePacket

from ._memory import NotShardable
from ._plan import Shard

__all__ = ["ShardTask", "ShardResult", "pipeline_dict", "run_shard", "read_part"]


@dataclass(frozen=True)
class ShardTask:
    """What a worker needs for one shard (small, picklable). ``pipeline`` is
    the dict form without sinks; ``outputs`` the node ids the sinks read;
    ``label`` names the recording(s) in messages; ``job`` numbers the
    pipeline within a run of many."""

    job: int
    shard: Shard
    pipeline: Mapping[str, Any]
    outputs: tuple[str, ...]
    part_dir: str
    label: str


@dataclass
class ShardResult:
    """What a worker returns: the part file per output node, events read
    (warm-up included) and kept, the warm-up's events, wall and CPU time
    (of the worker process), where it ran, and ``error`` (one line) when
    the input was bad."""

    job: int
    index: int
    parts: dict[str, str] = field(default_factory=dict)
    events_in: int = 0
    warmup_events: int = 0
    events_out: int = 0
    wall_s: float = 0.0
    cpu_s: float = 0.0
    host: str = ""
    error: str | None = None


def pipeline_dict(p: Pipeline, source_params: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, Any]:
    """``p`` as the dict :meth:`Pipeline.from_dict` reads, without sinks;
    ``source_params`` adds parameters per source id (a time range). Paths
    are made absolute, for workers in another folder. Nodes given as
    instances cannot travel (:class:`NotShardable`)."""
    extra = source_params or {}
    out: dict[str, Any] = {"pipeline": dict(vars(p.batch)), "source": [], "op": []}
    for s in p.nodes:
        if s.component is not None and s.role != "sink":
            raise NotShardable(f"node {s.id!r} is an instance; shards rebuild the pipeline on the workers "
                               "from names: give it by registry name (or path) and parameters")
        if s.role == "source":
            uri = os.path.abspath(s.name) if os.path.exists(s.name) else s.name
            entry: dict[str, Any] = {"id": s.id, "uri": uri, "params": {**s.params, **extra.get(s.id, {})}}
            if s.repair is not None:
                entry["repair"] = s.repair
            out["source"].append(entry)
        elif s.role == "operator":
            params = dict(s.params)
            ports: dict[str, Any] = {q: {"from": up, "delay_us": s.delays[q]} if q in s.delays else up
                                     for q, up in s.ports.items()}  # a delayed port as a file gives it
            if s.inputs and ports:
                inp: Any = list(s.inputs)
                if any(q in s.delays for q in ports):
                    raise NotShardable(f"node {s.id!r}: a delayed port beside plain inputs cannot travel to a "
                                       "worker; name every input by its port")
                params.update(ports)
            else:
                inp = ports if ports else list(s.inputs)
            op: dict[str, Any] = {"id": s.id, "name": s.name, "input": inp, "params": params, "buffer": s.buffer}
            if s.offload is not None:
                op["offload"] = s.offload
            out["op"].append(op)
    return out


def run_shard(task: ShardTask) -> ShardResult:
    """Run one shard (in a worker); see the module docstring."""
    from tectum.errors import TectumError

    began, cpu = time.perf_counter(), time.process_time()
    res = ShardResult(task.job, task.shard.index, host=f"{socket.gethostname()}:{os.getpid()}")
    marker = os.path.join(task.part_dir, f"attempt-{task.job:05d}-{task.shard.index:05d}-{uuid.uuid4().hex[:8]}")
    with open(marker, "w") as fh:  # the worker's pid: which process ran (or died in) this attempt
        fh.write(str(os.getpid()))
    try:
        _run(task, res)
    except (TectumError, ValueError, OSError) as e:  # bad input: reported, not retried
        res.error = f"{task.label} {task.shard.describe()}: {_one_line(e)}"
    res.wall_s, res.cpu_s = time.perf_counter() - began, time.process_time() - cpu
    return res


def _run(task: ShardTask, res: ShardResult) -> None:
    from tectum._embed import Stepper

    plan = Pipeline.from_dict(task.pipeline, origin=task.label).validate()
    start = task.shard.start_us
    writers = {o: _PartWriter(os.path.join(task.part_dir, f"part-{task.job:05d}-{task.shard.index:05d}-{i}"))
               for i, o in enumerate(task.outputs)}
    sources = {n.id: n.instantiate() for n in plan.of_role("source")}
    try:
        with Stepper(plan, outputs=task.outputs) as step:
            for sid, pkt in _merged(sources, plan.batch.max_events, start):
                warm = start is not None and pkt.t_end <= start
                n = len(pkt) if isinstance(pkt, EventPacket) else 0
                res.events_in += n
                res.warmup_events += n if warm else 0
                outs = step.push(pkt, into=sid)
                if not warm:
                    _keep(outs, writers, res)
            if task.shard.last:
                for sid in sources:
                    _keep(step.end(into=sid), writers, res)
        res.parts = {o: w.commit() for o, w in writers.items()}
    finally:
        for w in writers.values():
            w.discard()
        for src in sources.values():
            src.close()


def _keep(outs: Mapping[str, list[Packet]], writers: Mapping[str, _PartWriter], res: ShardResult) -> None:
    for node, pkts in outs.items():
        for pkt in pkts:
            writers[node].write(pkt)
            if isinstance(pkt, EventPacket):
                res.events_out += len(pkt)


def _merged(sources: Mapping[str, Any], max_events: int, start: int | None) -> Iterator[tuple[str, Packet]]:
    """Every source's packets, checked as the scheduler checks them, cut at
    ``start`` and to ``max_events``, in order of their ends (so every source
    reaches ``start`` before any goes past it: the warm-up ends together)."""
    its = {sid: _pieces(sid, src, max_events, start) for sid, src in sources.items()}
    heap: list[tuple[int, int, str, Packet]] = []
    seq = 0
    for sid, it in its.items():
        first = next(it, None)
        if first is not None:
            heap.append((first.t_end, seq, sid, first))
            seq += 1
    heapq.heapify(heap)
    while heap:
        _, _, sid, pkt = heapq.heappop(heap)
        yield sid, pkt
        nxt = next(its[sid], None)
        if nxt is not None:
            heapq.heappush(heap, (nxt.t_end, seq, sid, nxt))
            seq += 1


def _pieces(sid: str, src: Any, max_events: int, start: int | None) -> Iterator[Packet]:
    guard = Guard(sid)
    for raw in src.packets():
        pkt = guard(raw)
        cut = (pkt,) if start is None or not pkt.t_start < start < pkt.t_end else pkt.split_at(start)
        for piece in cut:
            yield from piece.batches(max_events)


class _PartWriter:
    """Packets pickled one after another into ``path`` (a temporary name
    until :meth:`commit`)."""

    def __init__(self, path: str) -> None:
        self.path = f"{path}-{uuid.uuid4().hex[:8]}.pkl"
        self._tmp = self.path + ".tmp"
        self._f: Any = None

    def write(self, pkt: Packet) -> None:
        if self._f is None:
            self._f = open(self._tmp, "wb")
        pickle.dump(_encode(pkt), self._f, protocol=pickle.HIGHEST_PROTOCOL)

    def commit(self) -> str:
        if self._f is None:
            open(self._tmp, "wb").close()
        else:
            self._f.close()
            self._f = None
        os.replace(self._tmp, self.path)
        return self.path

    def discard(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None
        if os.path.exists(self._tmp):
            os.remove(self._tmp)


def read_part(path: str) -> Iterator[Packet]:
    """The packets of a part file, in order."""
    with open(path, "rb") as f:
        while True:
            try:
                item = pickle.load(f)
            except EOFError:
                return
            yield _decode(item)


def _encode(pkt: Packet) -> tuple[Any, ...]:
    """A packet as plain picklable values (packets hold read-only mappings)."""
    if isinstance(pkt, EventPacket):
        return ("events", pkt.t, pkt.x, pkt.y, pkt.p, pkt.sensor, pkt.t_start, pkt.t_end, dict(pkt.columns))
    if isinstance(pkt, SamplePacket):
        return (str(pkt.kind), pkt.t, dict(pkt.data), pkt.t_start, pkt.t_end)
    raise TypeError(f"cannot store a {type(pkt).__name__} between shards")


def _decode(item: tuple[Any, ...]) -> Packet:
    if item[0] == "events":
        return EventPacket._trusted(*item[1:])
    cls: Any = packet_class(item[0])
    return cast(Packet, cls._trusted(*item[1:]))


def _one_line(e: BaseException) -> str:
    text = str(e) or type(e).__name__
    return "; ".join(line.strip() for line in text.splitlines() if line.strip())
