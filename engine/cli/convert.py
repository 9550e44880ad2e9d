"""``tectum convert IN OUT``: stream events from any readable format to any
writable one (formats from content / extension).

Ctrl-C or SIGTERM stops it between packets: the output is not written (its
temporary file is removed) and the exit status is 130 or 143. A signal that
comes while the finished file is being committed lets the commit complete
(the file is whole and reopens) and still exits with that status."""

from __future__ import annotations

import argparse
import sys

HELP = "convert an event file to another format, streaming (e.g. in.raw out.aedat4)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", help="event file to read (format detected from its content); IN?k=v passes source options")
    p.add_argument("output", help="file to write (format from its extension: .txt .csv .aedat4 .raw "
                                  ".evt3.raw .dat .h5 .npy .npz); OUT?k=v passes sink options")
    p.add_argument("--sensor", default=None, help="WIDTHxHEIGHT for inputs that do not say")
    p.add_argument("--skip-bad", action="store_true", help="drop undecodable parts instead of failing")
    p.add_argument("--start-us", type=int, default=None, help="first time to keep (absolute µs)")
    p.add_argument("--end-us", type=int, default=None, help="end of the time range (absolute µs)")


def main(args: argparse.Namespace) -> int:
    from tectum import accepts
    from tectum._stats import amounts
    from tectum.sources.files._common import FROM_EXTENT

    from ._args import open_source, split_query
    from ._progress import Progress, wanted
    from ._signals import deferred
    from ._unwritten import unwritten_lines

    with deferred() as check:  # a signal stops the work between packets, never inside h5py
        src, sink = open_source(args.input, args.output, sensor=args.sensor, skip_bad=args.skip_bad or None,
                                t_start_us=args.start_us, t_end_us=args.end_us)
        out = split_query(args.output)[0]
        written: dict[str, int] = {}  # kind -> events or samples
        refused: dict[str, int] = {}  # kinds the sink does not take -> events or samples
        known = args.start_us is not None and args.end_us is not None
        progress = Progress(args.end_us - args.start_us if known else None) if wanted(args.quiet) else None
        try:
            sink.open()
            for pkt in src.packets():
                check()
                if progress is not None:
                    progress.update(pkt)
                counts = written if accepts(sink.consumes, pkt.kind) else refused
                if counts is written:
                    sink.write(pkt)
                counts[str(pkt.kind)] = counts.get(str(pkt.kind), 0) + len(pkt)
            check()
        except BaseException:
            sink.abort()  # the temporary file goes: no output
            raise
        finally:
            if progress is not None:
                progress.done()
        sink.close()
    check()
    for kind, n in getattr(sink, "not_written", {}).items():  # taken, then left out by the sink
        written[kind] -= n
        refused[kind] = refused.get(kind, 0) + n
    for line in unwritten_lines(out, type(sink), refused):
        print(line, file=sys.stderr)
    size = getattr(sink, "sensor", None)
    if getattr(src, "sensor_from", None) == FROM_EXTENT and size and getattr(sink, "stores_sensor", False):
        print(f"{out}: sensor {size[0]}x{size[1]} written, from {FROM_EXTENT}: the input does not say "
              f"(--sensor WIDTHxHEIGHT gives the camera's)", file=sys.stderr)
    skipped = getattr(src, "skipped_events", 0)
    extra = f", skipped {skipped}" if skipped else ""
    print(f"{amounts(written) or '0 events'} -> {out}{extra}")
    return 0
