"""``tectum run`` over time shards and over many recordings (tectum.scale).

``tectum run rec.dat --op ... --sink out.h5 --shards 4 [--executor dask]``
cuts one recording into time shards; ``tectum run "corpus/**/*.raw" --op ...
--sink "out/{stem}.h5"`` runs the chain once per file (``{stem}``: the
file's name without extension, ``{name}``: with it, ``{parent}``: its
folder's name), skipping files whose outputs all exist (a run stopped half
way resumes where it was; outputs are written atomically, so an output that
exists is complete).
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time
from collections.abc import Callable
from typing import Any

from tectum import Pipeline
from tectum.errors import PipelineError

from ._progress import wanted

__all__ = ["add_arguments", "is_glob", "main_scaled"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--shards", type=int, metavar="N",
                   help="cut each recording into N time shards run in parallel (output identical to one run)")
    p.add_argument("--executor", choices=("local", "dask"),
                   help="where shards run: a process pool here (default with --shards or a glob) or Dask")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="with --executor dask: a running dask.distributed scheduler (default: a LocalCluster)")
    p.add_argument("--workers", type=int, metavar="N", help="processes of the local pool or LocalCluster")


def is_glob(source: str) -> bool:
    """True when ``source`` is a file pattern (``*``, ``?``, ``[``) naming
    no existing file and no URL."""
    return glob.has_magic(_split(source)[0]) and not os.path.exists(source) and "://" not in source


def _split(source: str) -> tuple[str, str]:
    """Pattern and parameters: ``?k=v...`` after the pattern (a ``?`` not
    followed by parameters is the pattern's one-character wildcard)."""
    head, sep, query = source.rpartition("?")
    return (head, query) if sep and "=" in query and "/" not in query else (source, "")


def main_scaled(args: argparse.Namespace, build: Callable[[argparse.Namespace], Pipeline]) -> int:
    from tectum.scale import run_many

    if args.source.endswith(".toml"):
        raise PipelineError("--shards, --executor and file patterns take a recording and --op/--sink, "
                            "not a pipeline file")
    if args.shards is not None and args.shards < 1:
        raise PipelineError(f"--shards must be >= 1, got {args.shards}")
    if not args.sink and not is_glob(args.source):
        args.sink = ["null:"]  # counts what comes out
    pipelines, skipped, files = _pipelines(args, build)
    if not pipelines:
        print(f"nothing to do: the outputs of all {skipped} file(s) exist", file=sys.stderr)
        return 0
    show = _Progress(len(pipelines)) if wanted(args.quiet) else None
    shards = args.shards if args.shards is not None else (1 if files else None)
    stats = run_many(pipelines, shards=shards, executor=args.executor, scheduler=args.scheduler,
                     workers=args.workers, progress=show.update if show else None)
    if show:
        show.done()
    what = f"{len(pipelines)} file(s)" + (f" ({skipped} done before, skipped)" if skipped else "") if files else \
        f"{len(stats.shard_rows())} shard(s)"
    print(f"{_produced(stats) or '0 events'} out of {what} in {stats.wall_s:.2f} s")
    for line in stats.rerun:
        print(f"tectum run: ran twice (a worker died): {line}", file=sys.stderr)
    if args.stats:
        print(stats.report())
    if args.stats_json:
        import json

        with open(args.stats_json, "w") as f:
            json.dump(stats.as_dict(), f, indent=1)
    return 0


def _produced(stats: Any) -> str:
    """What the chains gave their sinks, summed over the recordings."""
    from tectum._stats import amounts

    counts: dict[str, int] = {"events": 0}
    for job in stats.jobs:
        for nid, st in (job.stats.nodes.items() if job.stats is not None else ()):
            if nid.startswith("parts."):  # the join's sources: each output node once
                counts["events"] += st.events_out
                for kind, n in st.samples_out.items():
                    counts[str(kind)] = counts.get(str(kind), 0) + n
    return amounts(counts)


def _pipelines(args: argparse.Namespace,
               build: Callable[[argparse.Namespace], Pipeline]) -> tuple[list[Pipeline], int, bool]:
    """The pipelines to run, the files skipped as done, and whether the
    source was a pattern."""
    from tectum.scale import expand

    if not is_glob(args.source):
        return [build(args)], 0, False
    pattern, query = _split(args.source)
    files = expand(pattern)
    if not files:
        raise PipelineError(f"no file matches {pattern!r}")
    if not args.sink:
        raise PipelineError("a file pattern needs --sink with {stem} (or {name}) for each file's output")
    if len(files) > 1 and not any("{" in s for s in args.sink):
        raise PipelineError("each file needs its own output: put {stem} (or {name}, {parent}) in --sink")
    out, skipped = [], 0
    for path in files:
        keys = {"stem": os.path.splitext(os.path.basename(path))[0], "name": os.path.basename(path),
                "parent": os.path.basename(os.path.dirname(os.path.abspath(path)))}
        try:
            sinks = [s.format(**keys) for s in args.sink]
        except (KeyError, IndexError, ValueError) as e:
            raise PipelineError(f"--sink: bad placeholder {e} (known: {{stem}}, {{name}}, {{parent}})") from None
        files_out = [s.split("?", 1)[0] for s in sinks]
        if all(os.path.exists(f) for f in files_out):
            skipped += 1
            continue
        for f in files_out:
            if os.path.dirname(f):
                os.makedirs(os.path.dirname(f), exist_ok=True)
        one = argparse.Namespace(**{**vars(args), "source": path + (f"?{query}" if query else ""), "sink": sinks})
        out.append(build(one))
    return out, skipped, True


class _Progress:
    """One line on stderr: recordings done, shards done, events read, rate."""

    def __init__(self, jobs: int) -> None:
        self.jobs = jobs
        self.began = time.monotonic()
        self._width = 0

    def update(self, stats: Any, jobs_done: int) -> None:
        rows = stats.shard_rows()
        total = sum(len(j.shards) for j in stats.jobs)
        events = sum(r["events_in"] - r["warmup_events"] for r in rows)
        rate = events / max(time.monotonic() - self.began, 1e-9) / 1e6
        text = f"files {jobs_done}/{self.jobs} · shards {len(rows)}/{total} · {events:,} events · {rate:.2f} Mev/s"
        sys.stderr.write("\r" + text + " " * max(0, self._width - len(text)))
        sys.stderr.flush()
        self._width = len(text)

    def done(self) -> None:
        if self._width:
            sys.stderr.write("\r" + " " * self._width + "\r")
            sys.stderr.flush()
