"""``tectum run``: run a chain from the command line, or a pipeline file."""

from __future__ import annotations

import argparse
import json
import sys

from tectum import BatchPolicy, Pipeline
from tectum._stats import amounts

from . import _scale
from ._args import split_op, split_query
from ._progress import attach
from ._signals import exit_status, run_until_signal
from ._unwritten import unwritten_lines

HELP = "run SOURCE (or each file of a pattern) through operators into sinks, or run PIPELINE.toml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="a file, a URL (pattern:, tcp://HOST:PORT ...) or a pipeline .toml; "
                   "source parameters after '?' (pattern:?speed=500)")
    p.add_argument("--op", action="append", default=[], metavar="NAME[:k=v,...]",
                   help="an operator, applied in order (repeatable)")
    p.add_argument("--sink", action="append", default=[], metavar="SINK",
                   help="a file or URL written with the chain's output (repeatable); parameters after '?'")
    p.add_argument("--stats", action="store_true", help="print per-node counts, time and latency")
    p.add_argument("--stats-json", metavar="FILE", help="write the stats as JSON")
    p.add_argument("--max-events", type=int, help="largest packet in events (1: event by event)")
    p.add_argument("--max-latency-us", type=int, help="with --pace: release events in windows of this many µs")
    p.add_argument("--pace", type=float, help="replay speed (1 = real time); default as fast as possible")
    p.add_argument("--explain", action="store_true",
                   help="print the pipeline as it will run (macros expanded: nodes, parameters, edges with ports "
                   "and delays, feedback loops) and exit without running")
    p.add_argument("--repair", type=int, metavar="US",
                   help="repair the source stream (re-sort within US µs, drop bad events) instead of failing")
    _scale.add_arguments(p)


def build(args: argparse.Namespace) -> Pipeline:
    kw = {}
    if args.max_events is not None:
        kw["max_events"] = args.max_events
    if args.max_latency_us is not None:
        kw["max_latency_us"] = args.max_latency_us
    if args.pace is not None:
        kw["pace"] = args.pace
    if args.source.endswith(".toml"):
        p = Pipeline.from_toml(args.source)
        if kw:
            p.batch = BatchPolicy(**{**p.batch.__dict__, **kw})
        if args.op or args.sink:
            from tectum.errors import PipelineError

            raise PipelineError("--op and --sink do not combine with a pipeline file")
        return p
    p = Pipeline(BatchPolicy(**kw))
    uri, params = split_query(args.source)
    node = p.source(uri, id="source", repair=args.repair, **params)
    for i, spec in enumerate(args.op):
        name, oparams = split_op(spec)
        node = p.op(name, node, id=f"{i + 1}:{name}", **oparams)
    for i, spec in enumerate(args.sink):
        uri, sparams = split_query(spec)
        p.sink(uri, node, id=f"sink{i + 1}" if len(args.sink) > 1 else "sink", **sparams)
    return p


def _span(p: Pipeline) -> int | None:
    """The stream time the first source covers, when its parameters say
    (``duration_us``, or ``t_start_us`` and ``t_end_us``), in µs."""
    src = next((n for n in p.nodes if n.role == "source"), None)
    params = src.params if src is not None else {}
    try:
        if "duration_us" in params:
            return int(params["duration_us"])
        if "t_start_us" in params and "t_end_us" in params:
            return int(params["t_end_us"]) - int(params["t_start_us"])
    except (TypeError, ValueError):  # validation will name the bad value
        pass
    return None


def main(args: argparse.Namespace) -> int:
    if args.explain:
        print(build(args).explain())
        return 0
    if args.shards is not None or args.executor is not None or _scale.is_glob(args.source):
        return _scale.main_scaled(args, build)
    p = build(args)
    if p.nodes and not any(n.role == "sink" for n in p.nodes):
        from tectum.sinks.null import NullSink

        p.sink(NullSink(), p.nodes[-1].id, id="count")
    attach(p, args.quiet, total_us=_span(p))
    plan = p.validate()
    stats = run_until_signal(plan)
    for node in plan.of_role("sink"):
        for line in unwritten_lines(node.spec.name, node.cls, stats.nodes[node.id].not_written):
            print(line, file=sys.stderr)
    for node in plan.of_role("operator"):
        replaced = {k: n for k, n in stats.nodes[node.id].replaced.items() if n}
        if replaced:
            print(f"{node.id}: not passed on: {amounts(replaced)} from upstream ({node.spec.name} makes its own "
                  f"{', '.join(replaced)})", file=sys.stderr)
    if args.stats:
        print(stats.report())
    else:
        last = [n.id for n in p.nodes if n.role != "sink"][-1]
        s = stats.nodes.get(last)
        if s is not None:
            what = amounts({"events": s.events_out, **s.samples_out}) or "0 events"
            print(f"{what} out of {last!r} in {stats.wall_s:.2f} s")
    if args.stats_json:
        with open(args.stats_json, "w") as f:
            json.dump(stats.as_dict(), f, indent=1)
    if any(s.counters.get("interrupted") for s in stats.nodes.values()):  # a live source ended on Ctrl-C
        print("tectum run: interrupted (what was received before it is kept)", file=sys.stderr)
        return exit_status()
    return 0
