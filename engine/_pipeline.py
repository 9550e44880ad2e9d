"""Pipelines as data: a declared DAG, validated before anything runs.

A :class:`Pipeline` is a list of frozen :class:`NodeSpec` (sources, operators,
sinks, each with a unique id and its inputs). :meth:`Pipeline.validate` checks
it against a registry and returns a :class:`Plan`: topologically ordered,
names resolved to classes, parameters converted to their declared types and
stream kinds checked along every edge, and the named ports of multi-input
operators wired (by name, or by kind where that is unambiguous). Errors name
the node (and port) and say what is wrong; nothing is opened or started by
validation.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Literal

from ._operator import Operator, Port, Sink, Source, coerce_param, component_params
from ._packet import Kind, accepts
from ._registry import Registry, get_registry
from .errors import PipelineError, RegistryError

__all__ = ["Pipeline", "NodeSpec", "Plan", "PlanNode", "BatchPolicy", "EdgePolicy"]

Role = Literal["source", "operator", "sink"]
EdgePolicy = Literal["block", "keep_latest", "drop"]
_POLICIES = ("block", "keep_latest", "drop")


@dataclass(frozen=True)
class BatchPolicy:
    """How sources cut their stream into packets.

    max_events:
        Largest packet, in events (samples of one timestamp stay together);
        1 is event-by-event mode.
    max_latency_us:
        With pacing, events are released in windows of this many µs (0: each
        event as soon as it is due, so batches grow only under load).
    pace:
        None replays as fast as possible; 1.0 in real time; 2.0 twice as
        fast. Live sources (devices, sockets) are never paced.
    """

    max_events: int = 65536
    max_latency_us: int = 0
    pace: float | None = None

    def __post_init__(self) -> None:
        if self.max_events < 1:
            raise PipelineError(f"max_events must be >= 1, got {self.max_events}")
        if self.max_latency_us < 0:
            raise PipelineError(f"max_latency_us must be >= 0, got {self.max_latency_us}")
        if self.pace is not None and not self.pace > 0:
            raise PipelineError(f"pace must be > 0 or None, got {self.pace}")


@dataclass(frozen=True)
class NodeSpec:
    """One declared node. ``name`` is the operator's registry name, or the
    source/sink argument (a path or URL); ``component`` holds an instance
    given directly through the Python API instead. ``ports`` wires named
    input ports (port name to node id); ``offload`` runs an operator in a
    worker thread behind an edge of ``buffer`` packets (None: the operator's
    own ``heavy`` default)."""

    id: str
    role: Role
    name: str
    params: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    inputs: tuple[str, ...] = ()
    policy: EdgePolicy = "block"
    buffer: int = 64
    component: Any = None
    repair: int | None = None
    ports: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    offload: bool | None = None


class Pipeline:
    """A DAG of sources, operators and sinks, built before it runs.

    Example::

        p = Pipeline()
        cam = p.source("pattern:")
        ba = p.op("filter.refractory", cam, period_us=1000)
        p.sink("out.npz", ba)
        tectum.run(p)
    """

    def __init__(self, batch: BatchPolicy | None = None, **batch_kw: Any) -> None:
        self.batch = batch or BatchPolicy(**batch_kw)
        self._nodes: dict[str, NodeSpec] = {}

    @property
    def nodes(self) -> tuple[NodeSpec, ...]:
        return tuple(self._nodes.values())

    def __getitem__(self, node_id: str) -> NodeSpec:
        return self._nodes[node_id]

    def _add(self, spec: NodeSpec) -> str:
        if not spec.id or any(c in spec.id for c in " \t\n,"):
            raise PipelineError(f"bad node id {spec.id!r}")
        if spec.id in self._nodes:
            raise PipelineError(f"node id {spec.id!r} is used twice")
        self._nodes[spec.id] = spec
        return spec.id

    def _auto_id(self, base: str, role: Role = "source") -> str:
        if role == "operator":
            base = base.split(".")[-1]
        elif "://" in base or base.endswith(":") or (":" in base and "/" not in base.split(":")[0]):
            base = base.split(":")[0]  # a URL: its scheme
        else:
            base = os.path.splitext(os.path.basename(base))[0]  # a path: its stem
        base = base or "node"
        i, cand = 1, base
        while cand in self._nodes:
            i += 1
            cand = f"{base}{i}"
        return cand

    def source(self, arg: str | Source, *, id: str | None = None, repair: int | None = None,
               **params: Any) -> str:
        """Add a source: a path or URL (``pattern:``, ``tcp://...``), or a
        :class:`Source` instance. Returns the node id.

        Its packets are checked where they enter and a bad one stops the run
        with a :class:`PacketError`; with ``repair=W`` they are repaired
        instead (re-sorted within ``W`` µs, bad events dropped, all counted
        in the stats)."""
        comp = arg if isinstance(arg, Source) else None
        name = comp.name if comp is not None else str(arg)
        if repair is not None and repair < 0:
            raise PipelineError("repair window must be >= 0 µs")
        return self._add(NodeSpec(id or self._auto_id("source" if comp else name), "source", name,
                                  MappingProxyType(dict(params)), (), component=comp, repair=repair))

    def op(self, name: str | Operator, input: str | Sequence[str] | Mapping[str, str] | None = None, *,
           id: str | None = None, offload: bool | None = None, buffer: int = 64, **params: Any) -> str:
        """Add an operator by registry name (``filter.refractory``) or instance.

        ``input`` is one node id, or several to merge by timestamp. An
        operator with named ports takes them by name, as a mapping or as
        keywords (``p.op("map.emvs", events=cam, poses=gt)``); given plain
        node ids instead, each port is filled by kind where exactly one
        input provides it. ``offload=True`` runs the operator in a worker
        thread behind an edge of ``buffer`` packets (the default for
        operators that declare themselves heavy), so sources and sinks keep
        pace while it works."""
        comp = name if isinstance(name, Operator) else None
        nm = comp.name if comp is not None else str(name)
        ports: dict[str, str] = {}
        if input is None:
            inputs: tuple[str, ...] = ()
        elif isinstance(input, str):
            inputs = (input,)
        elif isinstance(input, Mapping):
            ports = {str(k): str(v) for k, v in input.items()}
            inputs = ()
        else:
            inputs = tuple(input)
        if buffer < 1:
            raise PipelineError("buffer must be >= 1 packet")
        return self._add(NodeSpec(id or self._auto_id(nm or "op", "operator"), "operator", nm,
                                  MappingProxyType(dict(params)), inputs, buffer=buffer, component=comp,
                                  ports=MappingProxyType(ports), offload=offload))

    def sink(self, arg: str | Sink, input: str, *, id: str | None = None,
             policy: EdgePolicy = "block", buffer: int = 64, **params: Any) -> str:
        """Add a sink fed by node ``input``. The edge into it holds ``buffer``
        packets; when full, ``policy`` says what happens: ``block`` (lossless:
        upstream waits), ``keep_latest`` (the oldest is dropped) or ``drop``
        (the new one is dropped). Drops are counted in the stats."""
        comp = arg if isinstance(arg, Sink) else None
        name = comp.name if comp is not None else str(arg)
        return self._add(NodeSpec(id or self._auto_id("sink" if comp else name), "sink", name,
                                  MappingProxyType(dict(params)), (input,), policy, buffer, comp))

    # -- files ----------------------------------------------------------------
    @classmethod
    def from_toml(cls, path: str | os.PathLike[str]) -> Pipeline:
        """Read a pipeline file; relative paths in it are taken from its folder."""
        with open(path, "rb") as f:
            try:
                data = tomllib.load(f)
            except tomllib.TOMLDecodeError as e:
                raise PipelineError(f"{path}: {e}") from None
        return cls.from_dict(data, base_dir=os.path.dirname(os.path.abspath(path)), origin=str(path))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, base_dir: str | None = None,
                  origin: str = "pipeline") -> Pipeline:
        """Build from the TOML structure::

            [pipeline]            # optional batch policy
            max_events = 4096
            [[source]]
            id = "cam"
            uri = "pattern:"
            [[op]]
            id = "rf"
            name = "filter.refractory"
            input = "cam"         # or a list, merged by timestamp,
                                  # or named ports: { events = "cam", poses = "gt" }
            params = { period_us = 1000 }
            offload = false       # true: run in a worker thread
            [[sink]]
            uri = "out.npz"
            input = "rf"
        """
        known = {"pipeline", "source", "op", "sink"}
        extra = set(data) - known
        if extra:
            raise PipelineError(f"{origin}: unknown section(s) {sorted(extra)}; expected {sorted(known)}")
        try:
            p = cls(BatchPolicy(**dict(data.get("pipeline", {}))))
        except TypeError as e:
            raise PipelineError(f"{origin}: [pipeline]: {e}") from None

        def where(kind: str, i: int, d: Mapping[str, Any]) -> str:
            return f"{origin}: [[{kind}]] #{i + 1}" + (f" ({d['id']!r})" if "id" in d else "")

        def path_arg(v: str) -> str:
            if base_dir and "://" not in v and ":" not in v[1:2] and not os.path.isabs(v) and not v.endswith(":"):
                return os.path.join(base_dir, v)
            return v

        def check_keys(d: Mapping[str, Any], allowed: set[str], w: str) -> None:
            bad = set(d) - allowed
            if bad:
                raise PipelineError(f"{w}: unknown key(s) {sorted(bad)}; allowed: {sorted(allowed)}")

        for i, d in enumerate(data.get("source", [])):
            w = where("source", i, d)
            check_keys(d, {"id", "uri", "params", "repair"}, w)
            if "uri" not in d:
                raise PipelineError(f"{w}: needs 'uri'")
            p.source(path_arg(d["uri"]), id=d.get("id"), repair=d.get("repair"), **d.get("params", {}))
        for i, d in enumerate(data.get("op", [])):
            w = where("op", i, d)
            check_keys(d, {"id", "name", "input", "params", "offload", "buffer"}, w)
            if "name" not in d or "input" not in d:
                raise PipelineError(f"{w}: needs 'name' and 'input'")
            p.op(d["name"], d["input"], id=d.get("id"), offload=d.get("offload"), buffer=d.get("buffer", 64),
                 **d.get("params", {}))
        for i, d in enumerate(data.get("sink", [])):
            w = where("sink", i, d)
            check_keys(d, {"id", "uri", "input", "params", "policy", "buffer"}, w)
            if "uri" not in d or "input" not in d:
                raise PipelineError(f"{w}: needs 'uri' and 'input'")
            p.sink(path_arg(d["uri"]), d["input"], id=d.get("id"), policy=d.get("policy", "block"),
                   buffer=d.get("buffer", 64), **d.get("params", {}))
        return p

    def validate(self, registry: Registry | None = None) -> Plan:
        """Check the DAG and resolve it; raises :class:`PipelineError`."""
        return _validate(self, registry or get_registry())


@dataclass(frozen=True)
class PlanNode:
    """A validated node: its class, converted parameters, inputs (node ids,
    each once), children, the kinds of stream it provides downstream, its
    wired ports (port name to node id, for operators with named ports) and
    whether it runs offloaded."""

    spec: NodeSpec
    cls: type
    params: Mapping[str, Any]
    children: tuple[str, ...]
    provides: frozenset[Kind]
    inputs: tuple[str, ...] = ()
    ports: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    offload: bool = False

    @property
    def id(self) -> str:
        return self.spec.id

    @property
    def role(self) -> Role:
        return self.spec.role

    def instantiate(self) -> Any:
        """A fresh component (or the instance given through the API)."""
        if self.spec.component is not None:
            return self.spec.component
        try:
            if self.role == "operator":
                return self.cls(**self.params)
            return self.cls(self.spec.name, **self.params)
        except (TypeError, ValueError) as e:
            raise PipelineError(f"node {self.id!r} ({self.spec.name}): {e}") from e


@dataclass(frozen=True)
class Plan:
    """A validated pipeline: nodes in topological order."""

    nodes: Mapping[str, PlanNode]
    order: tuple[str, ...]
    batch: BatchPolicy

    def of_role(self, role: Role) -> list[PlanNode]:
        return [self.nodes[n] for n in self.order if self.nodes[n].role == role]


def _validate(p: Pipeline, reg: Registry) -> Plan:
    specs = {s.id: s for s in p.nodes}
    if not any(s.role == "source" for s in specs.values()):
        raise PipelineError("the pipeline has no source")
    classes = {nid: _resolve(s, reg) for nid, s in specs.items()}
    named: dict[str, dict[str, str]] = {}  # operator id -> port -> node id, as given by name
    ports_of: dict[str, Mapping[str, Port]] = {}  # operator id -> its declared ports
    params_of: dict[str, dict[str, Any]] = {}
    inputs_of: dict[str, tuple[str, ...]] = {}
    for nid, s in specs.items():
        ports = _ports_of(s, classes[nid])
        given = dict(s.ports)
        params = dict(s.params)
        if ports is None:
            if given:
                raise PipelineError(f"node {nid!r} ({s.name}) has no named ports; give its input as node ids")
        else:
            for k in list(params):
                if k in ports:
                    given[k] = str(params.pop(k))
            unknown = sorted(set(given) - set(ports))
            if unknown:
                raise PipelineError(f"node {nid!r} ({s.name}) has no port(s) {unknown}; ports: {sorted(ports)}")
            named[nid] = given
            ports_of[nid] = ports
        params_of[nid] = params
        inputs_of[nid] = tuple(dict.fromkeys((*s.inputs, *given.values())))
    children: dict[str, list[str]] = {i: [] for i in specs}
    for s in specs.values():
        inputs = inputs_of[s.id]
        if s.role == "source" and inputs:
            raise PipelineError(f"source {s.id!r} cannot have inputs")
        if s.role != "source" and not inputs:
            raise PipelineError(f"{s.role} {s.id!r} has no input")
        if s.role == "sink" and len(inputs) != 1:
            raise PipelineError(f"sink {s.id!r} takes one input; merge with an operator first")
        if len(set(s.inputs)) != len(s.inputs):
            raise PipelineError(f"node {s.id!r} lists an input twice")
        if s.role == "sink" and s.policy not in _POLICIES:
            raise PipelineError(f"sink {s.id!r}: policy {s.policy!r} is not one of {_POLICIES}")
        if s.buffer < 1:
            raise PipelineError(f"{s.role} {s.id!r}: buffer must be >= 1")
        for i in inputs:
            if i not in specs:
                raise PipelineError(f"node {s.id!r} reads from unknown node {i!r} (known: {sorted(specs)})")
            if specs[i].role == "sink":
                raise PipelineError(f"node {s.id!r} reads from sink {i!r}; sinks have no output")
            children[i].append(s.id)
    order = _toposort(specs, inputs_of)
    nodes: dict[str, PlanNode] = {}
    for nid in order:
        s = specs[nid]
        cls = classes[nid]
        if s.role == "operator" and s.component is None and "calib" in component_params(cls) \
                and not params_of[nid].get("calib"):
            found = _calibration_beside(_upstream_sources(nid, specs, inputs_of))
            if found:
                params_of[nid]["calib"] = found
        params = _check_params(s, cls, params_of[nid])
        decl: Any = s.component if s.component is not None else cls  # instances may narrow their kinds
        inputs = inputs_of[nid]
        wired: dict[str, str] = {}
        if s.role == "source":
            provides = frozenset(decl.produces if s.component is not None else decl.kinds_for(s.name, params))
        elif nid in named:
            wired = _wire_ports(s, ports_of[nid], named[nid], s.inputs, nodes)
            problem = decl.check_ports(frozenset(wired))
            if problem:
                raise PipelineError(f"node {nid!r} ({s.name}): {problem}")
            provides = frozenset(decl.produces)
        else:
            upstream = frozenset().union(*(nodes[i].provides for i in inputs))
            consumes = frozenset(decl.consumes)
            if not any(accepts(consumes, k) for k in upstream):
                raise PipelineError(
                    f"{s.role} {s.id!r} ({s.name}) consumes {_kinds(consumes)} but its input(s) "
                    f"{', '.join(repr(i) for i in inputs)} provide only {_kinds(upstream)}"
                )
            provides = (upstream - consumes) | frozenset(decl.produces) if s.role == "operator" else frozenset()
            if s.role == "sink" and s.component is None and hasattr(cls, "planned_params"):
                params = cls.planned_params(params, upstream)  # e.g. which stream a file holds
        offload = s.role == "operator" and (bool(getattr(decl, "heavy", False)) if s.offload is None else s.offload)
        nodes[nid] = PlanNode(s, cls, MappingProxyType(params), tuple(children[nid]), provides, inputs,
                              MappingProxyType(wired), offload)
    return Plan(MappingProxyType(nodes), tuple(order), p.batch)


#: Calibration files looked for beside a recording, in this order (the
#: dataset layouts: UZH/RPG calib.txt; OpenCV and ROS camera_info YAML).
CALIBRATION_NAMES = ("calib.txt", "calib.yaml", "camera.yaml", "camera_info.yaml")


def _upstream_sources(nid: str, specs: Mapping[str, NodeSpec], inputs_of: Mapping[str, tuple[str, ...]]) -> list[str]:
    out, todo, seen = [], list(inputs_of[nid]), set()
    while todo:
        n = todo.pop(0)
        if n in seen:
            continue
        seen.add(n)
        if specs[n].role == "source":
            out.append(specs[n].name)
        todo += inputs_of[n]
    return out


def _calibration_beside(sources: Sequence[str]) -> str | None:
    """The calibration file beside the one recording an operator reads, if
    there is exactly one such file (an operator's ``calib`` parameter
    defaults to it)."""
    found = set()
    for arg in sources:
        path = arg.split("?", 1)[0]
        if not os.path.exists(path):
            continue
        folder = path if os.path.isdir(path) else os.path.dirname(os.path.abspath(path))
        hit = next((os.path.join(folder, n) for n in CALIBRATION_NAMES if os.path.isfile(os.path.join(folder, n))),
                   None)
        if hit:
            found.add(hit)
    return found.pop() if len(found) == 1 else None


def _ports_of(s: NodeSpec, cls: type) -> Mapping[str, Port] | None:
    if s.role != "operator":
        return None
    decl = s.component if s.component is not None else cls
    return getattr(decl, "inputs", None)


def _wire_ports(s: NodeSpec, ports: Mapping[str, Port], given: Mapping[str, str], positional: Sequence[str],
                nodes: Mapping[str, PlanNode]) -> dict[str, str]:
    """Port name -> upstream node id: the ports given by name, then the
    others filled by kind from the positional inputs where exactly one of
    them provides the port's kind (and no other port of that kind is open)."""
    where = f"node {s.id!r} ({s.name})"
    wired = dict(given)
    for port, up in given.items():
        kind = ports[port].kind
        if kind not in nodes[up].provides:
            raise PipelineError(f"{where}: port {port!r} takes {kind} but {up!r} provides only "
                                f"{_kinds(nodes[up].provides)}")
    for port, spec in ports.items():
        if port in wired:
            continue
        candidates = [i for i in positional if spec.kind in nodes[i].provides]
        same_kind = [q for q, ps in ports.items() if ps.kind == spec.kind and q not in given]
        if len(candidates) == 1 and len(same_kind) == 1:
            wired[port] = candidates[0]
        elif len(candidates) > 1 or (candidates and len(same_kind) > 1):
            raise PipelineError(
                f"{where}: port {port!r} ({spec.kind}) could take {', '.join(repr(c) for c in candidates)}"
                + (f", and ports {same_kind} all take {spec.kind}" if len(same_kind) > 1 else "")
                + f"; name it: {port}=NODE")
    missing = [q for q, ps in ports.items() if ps.required and q not in wired]
    if missing:
        raise PipelineError(f"{where}: required port(s) {', '.join(f'{q!r} ({ports[q].kind})' for q in missing)} "
                            "not connected")
    unused = [i for i in positional if i not in wired.values()]
    if unused:
        raise PipelineError(f"{where}: input(s) {unused} fill none of its ports "
                            f"({', '.join(f'{q}: {ps.kind}' for q, ps in ports.items())})")
    return wired


def _kinds(ks: frozenset[Kind]) -> str:
    return "{" + ", ".join(sorted(str(k) for k in ks)) + "}"


def _toposort(specs: Mapping[str, NodeSpec], inputs_of: Mapping[str, tuple[str, ...]]) -> list[str]:
    state: dict[str, int] = {}
    order: list[str] = []

    def visit(n: str, path: list[str]) -> None:
        st = state.get(n, 0)
        if st == 2:
            return
        if st == 1:
            cyc = path[path.index(n):] + [n]
            raise PipelineError(f"the pipeline has a cycle: {' -> '.join(cyc)}")
        state[n] = 1
        for i in inputs_of[n]:
            visit(i, path + [n])
        state[n] = 2
        order.append(n)

    for n in specs:
        visit(n, [])
    return order


def _resolve(s: NodeSpec, reg: Registry) -> type:
    if s.component is not None:
        return type(s.component)
    try:
        if s.role == "operator":
            return reg.operator(s.name)
        if s.role == "source":
            return reg.source_for(s.name)
        return reg.sink_for(s.name)
    except RegistryError as e:
        raise PipelineError(f"node {s.id!r}: {e}") from None


def _check_params(s: NodeSpec, cls: type, params: Mapping[str, Any]) -> dict[str, Any]:
    if s.component is not None:
        if params:
            raise PipelineError(f"node {s.id!r}: parameters go to the instance, not to the pipeline")
        return {}
    accepted = component_params(cls)
    if s.role != "operator":
        accepted = dict(list(accepted.items())[1:])  # the first is the path/URL
    out = {}
    for k, v in params.items():
        if k not in accepted:
            raise PipelineError(
                f"node {s.id!r} ({s.name}): unknown parameter {k!r}; "
                f"parameters: {', '.join(accepted) or '(none)'}"
            )
        try:
            out[k] = coerce_param(cls, k, v)
        except (TypeError, ValueError) as e:
            raise PipelineError(f"node {s.id!r} ({s.name}): parameter {k!r}: {e}") from None
    missing = [n for n, prm in accepted.items() if prm.default is prm.empty and n not in out]
    if missing:
        raise PipelineError(f"node {s.id!r} ({s.name}): missing parameter(s) {missing}")
    return out
