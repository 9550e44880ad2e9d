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
from functools import cached_property
from types import MappingProxyType
from typing import Any, Literal

from ._macro import Delayed, Expansion, MacroOutputs
from ._operator import Operator, Port, Sink, Source, coerce_param, component_params
from ._packet import Kind, accepts
from ._registry import Registry, get_registry
from .errors import PipelineError, RegistryError

__all__ = ["Pipeline", "NodeSpec", "Plan", "PlanNode", "BatchPolicy", "EdgePolicy", "Delayed"]

Role = Literal["source", "operator", "sink"]
EdgePolicy = Literal["block", "keep_latest", "drop"]
_POLICIES = ("block", "keep_latest", "drop")


@dataclass(frozen=True)
class BatchPolicy:
    """How sources cut their stream into packets.

    max_events:
        Largest packet, in events (samples of one timestamp stay together);
        1 is event-by-event mode. The default, 2**18, is also what a
        source's slices are joined up to per operator call: a call through
        the engine costs 10-25 µs of CPU whatever its size (its Python, run
        on caches the kernel before it has swept), while a kernel's time per
        event is the same from 16 ki to 1 Mi events, so joining 4x more per
        call than 65,536 removes about 3/4 of that cost (the filters through
        a pipeline of 10 ms packets: 0.83-0.97 -> 0.92-1.06 of the operator
        fed them in a plain loop, loaded). An edge queues up to its
        ``buffer`` packets of this size.
    max_latency_us:
        With pacing, events are released in windows of this many µs (0: each
        event as soon as it is due, so batches grow only under load).
    pace:
        None replays as fast as possible; 1.0 in real time; 2.0 twice as
        fast. Live sources (devices, sockets) are never paced.
    """

    max_events: int = 1 << 18
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
    own ``heavy`` default). ``delays`` gives the ports whose edge is delayed
    (port name to µs); ``part_of`` names the macro node a node was expanded
    from."""

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
    delays: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    part_of: str = ""


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

    @staticmethod
    def delayed(node: str, delay_us: int) -> Delayed:
        """Node ``node``'s output ``delay_us`` µs late, as a named port's
        input: ``p.op("x", events=cam, maps=p.delayed(m, delay_us=2000))``.
        Every packet crossing the edge has its samples' times and interval
        shifted by ``delay_us``; the port's stream starts ``delay_us`` after
        the node's other inputs (nothing arrives on it before). A cycle needs
        one such edge (a feedback loop)."""
        return Delayed(node, delay_us)

    def op(self, name: str | Operator, input: str | Sequence[str] | Mapping[str, str | Delayed] | None = None,
           *, id: str | None = None, offload: bool | None = None, buffer: int = 64, **params: Any) -> str:
        """Add an operator by registry name (``filter.refractory``) or instance.

        ``input`` is one node id, or several to merge by timestamp. An
        operator with named ports takes them by name, as a mapping or as
        keywords (``p.op("map.emvs", events=cam, poses=gt)``); given plain
        node ids instead, each port is filled by kind where exactly one
        input provides it. ``offload=True`` runs the operator in a worker
        thread behind an edge of ``buffer`` packets (the default for
        operators that declare themselves heavy), so sources and sinks keep
        pace while it works. A port's input may be :meth:`delayed`. ``name``
        may also be a registered macro (several nodes, see :meth:`explain`)."""
        comp = name if isinstance(name, Operator) else None
        nm = comp.name if comp is not None else str(name)
        given: dict[str, Any] = {k: params.pop(k) for k in list(params) if isinstance(params[k], Delayed)}
        if input is None:
            inputs: tuple[str, ...] = ()
        elif isinstance(input, str):
            inputs = (input,)
        elif isinstance(input, Mapping):
            given = {**{str(k): v for k, v in input.items()}, **given}
            inputs = ()
        else:
            if any(isinstance(i, Delayed) for i in input):
                raise PipelineError(f"operator {id or nm!r}: a delayed edge goes into a named port "
                                    "(port=p.delayed(node, delay_us)), not a plain input")
            inputs = tuple(input)
        if buffer < 1:
            raise PipelineError("buffer must be >= 1 packet")
        ports = {k: v.node if isinstance(v, Delayed) else str(v) for k, v in given.items()}
        delays = {k: v.delay_us for k, v in given.items() if isinstance(v, Delayed)}
        return self._add(NodeSpec(id or self._auto_id(nm or "op", "operator"), "operator", nm,
                                  MappingProxyType(dict(params)), inputs, buffer=buffer, component=comp,
                                  ports=MappingProxyType(ports), offload=offload, delays=MappingProxyType(delays)))

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
            ports = { maps = { from = "m", delay_us = 2000 } }  # named ports (beside
                                  # or instead of input), here a delayed one
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
            check_keys(d, {"id", "name", "input", "ports", "params", "offload", "buffer"}, w)
            if "name" not in d or ("input" not in d and "ports" not in d):
                raise PipelineError(f"{w}: needs 'name' and 'input' (or 'ports')")
            inp: Any = d.get("input")
            ports = dict(d.get("ports", {}))
            if isinstance(inp, Mapping):
                ports = {**inp, **ports}
                inp = None
            ports = {k: _delayed_from(v, f"{w}: port {k!r}") if isinstance(v, Mapping) else v for k, v in ports.items()}
            p.op(d["name"], inp, id=d.get("id"), offload=d.get("offload"), buffer=d.get("buffer", 64),
                 **ports, **d.get("params", {}))
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

    def explain(self, registry: Registry | None = None) -> str:
        """The validated pipeline as text, macros expanded: its nodes (with
        operator names and parameters), its edges (with ports and delays)
        and its feedback loops. Nothing is opened or run."""
        return self.validate(registry).explain()


def _delayed_from(d: Mapping[str, Any], where: str) -> Delayed:
    """A delayed port input of a pipeline file: ``{ from = "m", delay_us = 2000 }``."""
    if set(d) != {"from", "delay_us"}:
        raise PipelineError(f"{where}: a delayed input is {{ from = NODE, delay_us = US }}, got keys {sorted(d)}")
    try:
        return Delayed(str(d["from"]), d["delay_us"])
    except PipelineError as e:
        raise PipelineError(f"{where}: {e}") from None


@dataclass(frozen=True)
class PlanNode:
    """A validated node: its class, converted parameters, inputs (node ids,
    each once), children, the kinds of stream it provides downstream, its
    wired ports (port name to node id, for operators with named ports) and
    whether it runs offloaded; ``delays`` (port to µs) its delayed ports, of
    which ``feedback`` are those closing a loop (their producer depends on
    this node's output); ``replaces`` the kinds of an operator's upstream it
    does not pass on because it makes a stream of that kind itself (an event
    frame operator on a DAVIS recording: its frames, not the APS frames)."""

    spec: NodeSpec
    cls: type
    params: Mapping[str, Any]
    children: tuple[str, ...]
    provides: frozenset[Kind]
    inputs: tuple[str, ...] = ()
    ports: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    offload: bool = False
    delays: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    feedback: frozenset[str] = frozenset()
    replaces: frozenset[Kind] = frozenset()

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
    """A validated pipeline: nodes in topological order (of the edges that
    close no loop); ``loops`` lists the node ids of each feedback loop."""

    nodes: Mapping[str, PlanNode]
    order: tuple[str, ...]
    batch: BatchPolicy
    loops: tuple[tuple[str, ...], ...] = ()

    def of_role(self, role: Role) -> list[PlanNode]:
        """The nodes of ``role``, in order (a new list each call)."""
        return list(self._roles.get(role, ()))

    @cached_property
    def _roles(self) -> dict[str, tuple[PlanNode, ...]]:
        """The nodes by role, in order: read several times per run (the
        scheduler's set-up), sorted once."""
        roles: dict[str, list[PlanNode]] = {}
        for n in self.order:
            node = self.nodes[n]
            roles.setdefault(node.spec.role, []).append(node)
        return {r: tuple(v) for r, v in roles.items()}

    def explain(self) -> str:
        """See :meth:`Pipeline.explain`."""
        return _explain(self)


def _validate(p: Pipeline, reg: Registry) -> Plan:
    specs = {s.id: s for s in _expand_macros(p.nodes, reg)}
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
    loops, feedback, order = _loops(specs, inputs_of, ports_of, named)
    nodes: dict[str, PlanNode] = {}
    provides_of: dict[str, frozenset[Kind]] = {  # a loop's nodes (named ports) give what they declare
        n: frozenset(getattr(specs[n].component or classes[n], "produces", ())) for loop in loops for n in loop}
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
        replaces: frozenset[Kind] = frozenset()
        if s.role == "source":
            provides = frozenset(decl.produces if s.component is not None else decl.kinds_for(s.name, params))
        elif nid in named:
            wired = _wire_ports(s, ports_of[nid], named[nid], s.inputs, provides_of)
            problem = decl.check_ports(frozenset(wired))
            if problem:
                raise PipelineError(f"node {nid!r} ({s.name}): {problem}")
            provides = frozenset(decl.produces)
            inputs = tuple(dict.fromkeys(wired.values()))  # a macro's part may leave some of its inputs unused
        else:
            upstream = frozenset().union(*(provides_of[i] for i in inputs))
            consumes = frozenset(decl.consumes)
            if not any(accepts(consumes, k) for k in upstream) and not isinstance(s.component, MacroOutputs):
                raise PipelineError(
                    f"{s.role} {s.id!r} ({s.name}) consumes {_kinds(consumes)} but its input(s) "
                    f"{', '.join(repr(i) for i in inputs)} provide only {_kinds(upstream)}"
                )
            provides = (upstream - consumes) | frozenset(decl.produces) if s.role == "operator" else frozenset()
            if s.role == "operator":  # its own stream of a kind it makes replaces upstream's (results add up)
                replaces = (upstream & frozenset(decl.produces)) - consumes - {Kind.RESULTS, Kind.ANY}
            if s.role == "sink" and s.component is None and hasattr(cls, "planned_params"):
                try:
                    params = cls.planned_params(params, upstream)  # e.g. which stream a file holds
                except ValueError as e:
                    raise PipelineError(f"node {nid!r} ({s.name}): {e}") from None
        offload = s.role == "operator" and (bool(getattr(decl, "heavy", False)) if s.offload is None else s.offload)
        provides_of[nid] = provides
        fb = frozenset(q for q, up in wired.items() if (nid, up) in feedback)
        nodes[nid] = PlanNode(s, cls, MappingProxyType(params), (), provides, inputs, MappingProxyType(wired),
                              offload, MappingProxyType(dict(s.delays)), fb, replaces)
    _check_macro_inputs(specs, nodes)
    children: dict[str, list[str]] = {i: [] for i in order}
    for nid in order:
        for i in nodes[nid].inputs:
            children[i].append(nid)
    for nid, n in nodes.items():  # the children, now known (a frozen dataclass: set once, as replace() would)
        object.__setattr__(n, "children", tuple(children[nid]))
    return Plan(MappingProxyType(nodes), tuple(order), p.batch, loops)


def _loops(specs: Mapping[str, NodeSpec], inputs_of: Mapping[str, tuple[str, ...]],
           ports_of: Mapping[str, Mapping[str, Port]],
           named: Mapping[str, Mapping[str, str]]
           ) -> tuple[tuple[tuple[str, ...], ...], set[tuple[str, str]], list[str]]:
    """The pipeline's feedback loops (strongly connected sets of nodes, in
    declaration order), its feedback edges ((consumer, producer): the
    delayed edges inside a loop) and its nodes in topological order of the
    other edges. Every cycle must hold a delayed edge."""
    delayed = {(n, up) for n, s in specs.items() for q, up in named.get(n, {}).items() if q in s.delays}
    for n, s in specs.items():
        if s.delays and n not in ports_of:
            raise PipelineError(f"node {n!r} ({s.name}): a delayed edge goes into a named port")
        if s.delays and not [q for q in named[n] if q not in s.delays] + list(s.inputs):
            raise PipelineError(f"node {n!r} ({s.name}): every input is delayed; a delayed port needs another, "
                                "undelayed input to the node (whose stream starts the delayed one's)")
    order = _toposort(specs, {n: tuple(i for i in ins if (n, i) not in delayed) for n, ins in inputs_of.items()},
                      loop_hint=True)
    if not delayed:  # no cycle without a delayed edge: none at all (and the order is the one just found)
        return (), set(), order
    comps = _strongly_connected(list(specs), inputs_of)
    loops: list[tuple[str, ...]] = []
    feedback: set[tuple[str, str]] = set()
    for comp in comps:
        members = set(comp)
        if len(comp) == 1 and comp[0] not in inputs_of[comp[0]]:
            continue
        loop = tuple(n for n in specs if n in members)
        for n in loop:
            if n not in ports_of:
                raise PipelineError(
                    f"node {n!r} ({specs[n].name}) is on the loop {' -> '.join(loop)}: nodes on a loop take "
                    "their inputs on named ports")
        loops.append(loop)
        feedback |= {(n, up) for n, up in delayed if n in members and up in members}
    order = _toposort(specs, {n: tuple(i for i in ins if (n, i) not in feedback) for n, ins in inputs_of.items()})
    return tuple(loops), feedback, order


def _strongly_connected(ids: Sequence[str], inputs_of: Mapping[str, tuple[str, ...]]) -> list[list[str]]:
    """Tarjan's strongly connected components of the input graph."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(n: str) -> None:
        index[n] = low[n] = len(index)
        stack.append(n)
        on.add(n)
        for i in inputs_of[n]:
            if i not in index:
                visit(i)
                low[n] = min(low[n], low[i])
            elif i in on:
                low[n] = min(low[n], index[i])
        if low[n] == index[n]:
            comp = []
            while True:
                m = stack.pop()
                on.discard(m)
                comp.append(m)
                if m == n:
                    break
            out.append(comp)

    for n in ids:
        if n not in index:
            visit(n)
    return out


def _expand_macros(specs: Sequence[NodeSpec], reg: Registry) -> list[NodeSpec]:
    """``specs`` with each macro node replaced by its parts (``<id>.<part>``)
    and a node ``<id>`` that hands on the outputs it names (macros may use
    macros)."""
    todo = list(specs)
    depth = 0
    while any(_is_macro(s, reg) for s in todo):
        depth += 1
        if depth > 8:
            raise PipelineError("macros expand into macros more than 8 levels deep")
        nxt: list[NodeSpec] = []
        for s in todo:
            nxt += _expand_one(s, reg) if _is_macro(s, reg) else [s]
        todo = nxt
    return todo


def _is_macro(s: NodeSpec, reg: Registry) -> bool:
    return s.role == "operator" and s.component is None and s.name in reg.macros


def _expand_one(s: NodeSpec, reg: Registry) -> list[NodeSpec]:
    cls = reg.macros[s.name].cls
    where = f"node {s.id!r} ({s.name})"
    named = dict(s.ports)
    params = dict(s.params)
    for k in list(params):
        if k in cls.inputs:
            named[k] = str(params.pop(k))
    unknown = sorted(set(named) - set(cls.inputs))
    if unknown:
        raise PipelineError(f"{where} has no port(s) {unknown}; ports: {sorted(cls.inputs)}")
    if s.delays:
        raise PipelineError(f"{where}: a macro's ports take no delay (delay the edge inside it)")
    if s.offload is not None:
        raise PipelineError(f"{where}: offload= applies to its parts, not to a macro")
    if not named and not s.inputs:
        raise PipelineError(f"operator {s.id!r} has no input")
    macro = cls(**_check_params(s, cls, params))
    x = Expansion(s.id, named, s.inputs)
    try:
        macro.expand(x)
    except (TypeError, ValueError) as e:
        raise PipelineError(f"{where}: {e}") from e
    if not x.outputs or any(o not in x.parts for o in x.outputs):
        raise PipelineError(f"{where}: the macro names outputs {list(x.outputs)} among its parts {list(x.parts)}")
    pid = {part: f"{s.id}.{part}" for part in x.parts}
    nodes = []
    for part in x.parts.values():
        refs = [*part.parts_in, *(v.node if isinstance(v, Delayed) else v.name for v in part.ports.values()
                                  if not isinstance(v, str))]
        unknown = [r for r in refs if r not in pid]
        if unknown:
            raise PipelineError(f"{where}: part {part.part!r} reads from {unknown}, which are not parts of the macro "
                                f"({list(pid)})")
        ports: dict[str, str] = {}
        delays: dict[str, int] = {}
        for q, v in part.ports.items():
            if isinstance(v, Delayed):
                ports[q], delays[q] = pid[v.node], v.delay_us
            else:
                ports[q] = v if isinstance(v, str) else pid[v.name]
        inputs = (*(pid[q] for q in part.parts_in), *part.inputs)
        nodes.append(NodeSpec(pid[part.part], "operator", part.name, MappingProxyType(part.params), inputs,
                              buffer=part.buffer, ports=MappingProxyType(ports), offload=part.offload,
                              delays=MappingProxyType(delays), part_of=s.id))
    outputs = tuple(pid[o] for o in x.outputs)
    nodes.append(NodeSpec(s.id, "operator", s.name, inputs=outputs, part_of=s.id,
                          component=MacroOutputs(s.name, _check_params(s, cls, params), s.inputs)))
    return nodes


def _check_macro_inputs(specs: Mapping[str, NodeSpec], nodes: Mapping[str, PlanNode]) -> None:
    """Each plain input of a macro node feeds one of its parts."""
    for nid, s in specs.items():
        if not isinstance(s.component, MacroOutputs):
            continue
        used = {i for n in nodes.values() if n.spec.part_of == nid and n.id != nid for i in n.inputs}
        spare = [i for i in s.component.positional if i not in used]
        if spare:
            raise PipelineError(f"node {nid!r} ({s.name}): input(s) {spare} fill none of its parts' ports")


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
                provides: Mapping[str, frozenset[Kind]]) -> dict[str, str]:
    """Port name -> upstream node id: the ports given by name, then the
    others filled by kind from the positional inputs where exactly one of
    them provides the port's kind (and no other port of that kind is open)."""
    where = f"node {s.id!r} ({s.name})"
    wired = dict(given)
    for port, up in given.items():
        kind = ports[port].kind
        if kind not in provides[up]:
            raise PipelineError(f"{where}: port {port!r} takes {kind} but {up!r} provides only "
                                f"{_kinds(provides[up])}")
    for port, spec in ports.items():
        if port in wired:
            continue
        candidates = [i for i in positional if spec.kind in provides[i]]
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
    if unused and not s.part_of:  # a macro's part takes what it can of the macro's inputs
        raise PipelineError(f"{where}: input(s) {unused} fill none of its ports "
                            f"({', '.join(f'{q}: {ps.kind}' for q, ps in ports.items())})")
    return wired


def _kinds(ks: frozenset[Kind]) -> str:
    return "{" + ", ".join(sorted(str(k) for k in ks)) + "}"


def _toposort(specs: Mapping[str, NodeSpec], inputs_of: Mapping[str, tuple[str, ...]], *,
              loop_hint: bool = False) -> list[str]:
    state: dict[str, int] = {}
    order: list[str] = []

    def visit(n: str, path: list[str]) -> None:
        st = state.get(n, 0)
        if st == 2:
            return
        if st == 1:
            cyc = (path[path.index(n):] + [n])[::-1]  # in the direction data flow
            hint = ("; a loop needs a delayed edge: give one of its inputs delay_us (Pipeline.delayed, or "
                    "{ from = NODE, delay_us = US } in a file)") if loop_hint else ""
            raise PipelineError(f"the pipeline has a cycle: {' -> '.join(cyc)}{hint}")
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


def _explain(plan: Plan) -> str:
    """See :meth:`Pipeline.explain`."""

    def value(v: Any) -> str:
        return repr(v) if isinstance(v, str) else str(v)

    rows: list[tuple[str, str, str]] = []
    for nid in plan.order:
        n = plan.nodes[nid]
        comp = n.spec.component
        if isinstance(comp, MacroOutputs):
            what = f"{comp.macro} (macro)"
            params: Mapping[str, Any] = comp.params
        else:
            what = n.spec.name if n.role == "operator" else f"{n.role} {n.spec.name}"
            params = n.params
        extra = " ".join(f"{k}={value(v)}" for k, v in params.items())
        if n.offload:
            extra += (" " if extra else "") + "[offloaded]"
        if n.replaces:
            extra += (" " if extra else "") + f"[replaces upstream {', '.join(sorted(map(str, n.replaces)))}]"
        rows.append((nid, what, extra))
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    lines = ["nodes:"] + [f"  {a:<{w0}}  {b:<{w1}}  {c}".rstrip() for a, b, c in rows]
    lines.append("edges:")
    for nid in plan.order:
        n = plan.nodes[nid]
        by_port = {up: [q for q, u in n.ports.items() if u == up] for up in n.inputs}
        for up in n.inputs:
            for q in by_port[up] or [""]:
                delay = n.delays.get(q)
                lines.append(f"  {up} -> {nid}" + (f" ({q})" if q else "")
                             + (f"  delayed {delay} µs" if delay else "")
                             + ("  (closes a loop)" if q in n.feedback else ""))
    if plan.loops:
        lines.append("loops:")
        lines += [f"  {' -> '.join(loop)}" for loop in plan.loops]
    return "\n".join(lines)
