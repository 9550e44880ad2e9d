"""The ``tectum`` command line: one module per verb.

Each verb module defines ``HELP`` (one line), ``add_arguments(parser)`` and
``main(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

__all__ = ["main"]

#: Verbs in the order ``tectum --help`` lists them (module name = verb).
VERBS = ("demo", "run", "info", "convert", "simulate", "devices", "plugins", "bench")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tectum", description="Event-camera streaming engine.")
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for verb in VERBS:
        try:
            mod = importlib.import_module(f"tectum.cli.{verb}")
        except ModuleNotFoundError as e:
            if e.name == f"tectum.cli.{verb}":
                continue  # verb not built (yet)
            raise
        p = sub.add_parser(verb, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_main=mod.main)
    return parser


def _version() -> str:
    from tectum import __version__

    return f"tectum {__version__}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tectum`` command; returns the exit status."""
    from tectum.errors import TectumError

    parser = _parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_main", None):
        parser.print_help()
        return 2
    try:
        return int(args._main(args) or 0)
    except TectumError as e:
        print(f"tectum {args.verb}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
