"""``tectum bench``: measure speed (and, per suite, accuracy) on this machine."""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

SUITES = ("engine", "io", "filters", "flow", "simulate", "net")
HELP = "run benchmark suites (engine, io, filters, flow, simulate, net) and write JSON/PNG results"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("suite", nargs="*", help="suites to run (default: all available)")
    p.add_argument("--out", default="bench-out", help="folder for JSON and charts (default bench-out)")
    p.add_argument("--quick", action="store_true", help="smaller inputs, fewer repeats")


def main(args: argparse.Namespace) -> int:
    from tectum.evaluation.harness import write_results

    have = list(SUITES)
    suites = args.suite or have
    unknown = [s for s in suites if s not in have]
    if unknown:
        print(f"unknown or unavailable suite(s) {unknown}; available: {have}")
        return 2
    out = Path(args.out)
    for s in suites:
        print(f"== {s}")
        mod = importlib.import_module(f"tectum.evaluation.suites.{s}")
        res = mod.run(out, args.quick)
        print(f"-> {write_results(out, s, res)}")
    return 0
