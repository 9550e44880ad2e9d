"""``tectum plugins``: what is registered, and by which plugin."""

from __future__ import annotations

import argparse
import json

from tectum import get_registry

HELP = "list the registered operators, sources and sinks with their owners"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="machine-readable output")


def main(args: argparse.Namespace) -> int:
    reg = get_registry()
    tables = {"operators": reg.operators, "sources": reg.sources, "sinks": reg.sinks}
    if args.json:
        out = {
            role: [
                {"name": e.name, "plugin": e.owner, "class": f"{e.cls.__module__}.{e.cls.__qualname__}",
                 **({"schemes": list(e.cls.schemes), "extensions": list(e.cls.extensions)} if role != "operators" else
                    {"consumes": [str(k) for k in e.cls.consumes], "produces": [str(k) for k in e.cls.produces]})}
                for e in sorted(t.values(), key=lambda e: e.name)
            ]
            for role, t in tables.items()
        }
        out["plugins"] = reg.plugins
        print(json.dumps(out, indent=1))
        return 0
    for role, t in tables.items():
        print(f"{role}:")
        for e in sorted(t.values(), key=lambda e: e.name):
            doc = (e.cls.__doc__ or "").strip().splitlines()
            print(f"  {e.name:<34} [{e.owner}] {doc[0] if doc else ''}")
    return 0
