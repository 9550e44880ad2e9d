"""The ``tectum`` command line: one module per verb.

Each verb module defines ``HELP`` (one line), ``add_arguments(parser)`` and
``main(args) -> int``. Errors a user can cause (bad arguments, missing or
damaged files, invalid pipelines) end the command with one line on stderr,
``tectum VERB: error: ...``, and a non-zero exit status, never a traceback.
SIGTERM is handled like SIGINT: ``tectum VERB: interrupted by SIGTERM``,
unfinished output removed, exit status 143 (130 for SIGINT); see ``_signals``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from collections.abc import Sequence
from typing import NoReturn

__all__ = ["main"]

#: Verbs in the order ``tectum --help`` lists them (module name = verb).
VERBS = ("demo", "run", "info", "convert", "simulate", "calibrate", "devices", "plugins", "bench")


class _Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line (the usage is in ``--help``)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tectum", description="Event-camera streaming engine.")
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
        p.add_argument("-q", "--quiet", action="store_true",
                       help="no progress line (it is shown only on a terminal anyway)")
        mod.add_arguments(p)
        p.set_defaults(_main=mod.main)
    return parser


def _version() -> str:
    from tectum import __version__

    return f"tectum {__version__}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``tectum`` command; returns the exit status."""
    from tectum.errors import TectumError

    from ._signals import exit_status, term_like_int

    parser = _parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_main", None):
        parser.print_help()
        return 2
    try:
        with term_like_int():
            try:
                status = int(args._main(args) or 0)
                sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
                return status
            except KeyboardInterrupt:  # SIGINT or SIGTERM: unfinished output was removed
                name = signal.Signals(exit_status() - 128).name
                print(f"tectum {args.verb}: interrupted by {name}", file=sys.stderr)
                return exit_status()
    except BrokenPipeError:  # `tectum ... | head`: the reader has gone, so stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, as a shell reports a command killed by a closed pipe
    except (TectumError, OSError, ValueError) as e:
        print(f"tectum {args.verb}: error: {_one_line(e)}", file=sys.stderr)
        return 1


def _one_line(e: BaseException) -> str:
    """The message of ``e`` on one line (an OSError as ``file: reason``)."""
    if isinstance(e, OSError) and e.strerror:
        text = f"{e.filename}: {e.strerror}" if e.filename is not None else e.strerror
    else:
        text = str(e) or type(e).__name__
    return "; ".join(line.strip() for line in text.splitlines() if line.strip())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
