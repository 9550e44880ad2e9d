"""``tectum bench``: measure speed (and, per suite, accuracy) on this machine."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "run benchmark suites (engine, io, filters, flow, simulate, net and plugins' own) and write JSON/PNG results"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("suite", nargs="*", help="suites to run (default: all registered; see --list)")
    p.add_argument("--out", default="bench-out", help="folder for JSON and charts (default bench-out)")
    p.add_argument("--quick", action="store_true", help="smaller inputs, fewer repeats")
    p.add_argument("--list", action="store_true", help="list the registered suites and exit")


def main(args: argparse.Namespace) -> int:
    import tectum
    from tectum.errors import RegistryError
    from tectum.evaluation.harness import write_results

    suites = tectum.get_registry().bench_suites
    if args.list:
        width = max((len(n) for n in suites), default=0)
        for name, s in suites.items():
            print(f"{name:<{width}}  {s.description}  (plugin {s.owner})")
        return 0
    unknown = [s for s in args.suite if s not in suites]
    if unknown:
        print(f"tectum bench: error: unknown suite(s) {', '.join(unknown)}; registered: {', '.join(suites)}",
              file=sys.stderr)
        return 2
    out = Path(args.out)
    for name in args.suite or list(suites):
        print(f"== {name}", flush=True)
        res = suites[name].run(out, args.quick)
        if not isinstance(res, dict):
            raise RegistryError(f"bench suite {name!r} (plugin {suites[name].owner!r}) returned "
                                f"{type(res).__name__}, not a dict")
        print(f"-> {write_results(out, name, res)}")
        targets = res.get("targets", [])
        missed = [t["name"] for t in targets if not t["met"]]
        if targets:
            print(f"targets: {len(targets) - len(missed)} of {len(targets)} met"
                  + (f"; MISSED: {'; '.join(missed)}" if missed else ""))
    return 0
