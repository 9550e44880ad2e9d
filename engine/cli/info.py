"""``tectum info FILE``: what an event file holds."""

from __future__ import annotations

import argparse
import json

HELP = "describe an event file: format, sensor size, duration, events, rate, streams, t0 offset"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="an event file (format detected from its content); FILE?k=v passes source options")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--sensor", default=None, help="WIDTHxHEIGHT for files that do not say")


def main(args: argparse.Namespace) -> int:
    from tectum.errors import PipelineError

    from ._args import open_source

    src, _ = open_source(args.file, sensor=args.sensor)
    if not hasattr(src, "info"):
        raise PipelineError(f"{args.file!r} opens as a {src.name!r} source, which is no file to describe")
    info = src.info()
    if args.json:
        print(json.dumps(info, indent=1, default=str))
        return 0
    s = info.get("sensor")
    lines = [("file", info["path"]), ("format", info["format"]),
             ("sensor", f"{s[0]}x{s[1]}{_sensor_from(info.get('sensor_from'))}" if s else "unknown"),
             ("events", f"{info['events']:,}"),
             ("duration", f"{info['duration_us'] / 1e6:.6f} s"),
             ("first / last", f"{info['t_first_us']} / {info['t_last_us']} µs"),
             ("rate", f"{info['rate_mev_s']:.4f} Mev/s" if info["events"] else "no events"),
             ("streams", ", ".join(f"{k} {v:,}" for k, v in info["streams"].items()) or "none"),
             ("t0 offset", f"{info['t0_offset_us']} µs")]
    for key in ("time_unit", "columns"):  # text files: what was assumed, and why
        if isinstance(info.get(key), str):
            lines.append((key.replace("_", " "), info[key]))
    if info.get("indexed"):  # AEDAT 4.0: counted from the packet table, not decoded
        lines.append(("counts", "from the file's packet table, not decoded (FILE?use_index=false decodes "
                                "every packet and reports one that is corrupt)"))
    if info.get("skipped_events"):
        lines.append(("skipped", str(info["skipped_events"])))
    for k, v in lines:
        print(f"{k:>13}: {v}")
    return 0


def _sensor_from(how: str | None) -> str:
    """Where a sensor size the file does not say came from, for its line."""
    from tectum.sources.files._common import FROM_EXTENT, FROM_OPTION

    if not how:
        return ""
    if how == FROM_OPTION:
        return f" (from {how})"
    return f" (from {how}: the file does not say" + ("; --sensor gives the camera's)" if how == FROM_EXTENT else ")")
