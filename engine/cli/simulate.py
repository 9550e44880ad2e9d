"""``tectum simulate``: simulate a scene to an event file, with ground truth beside it."""

from __future__ import annotations

import argparse
import re
import sys

HELP = "simulate a scene (built-in name, TOML, video or image folder) to an event file, ground truth beside it"

_UNITS = {"us": 1, "µs": 1, "ms": 1_000, "s": 1_000_000, "": 1_000_000}


def parse_duration(text: str) -> int:
    """``"2s"``, ``"150ms"``, ``"5000us"`` or ``"1.5"`` (seconds) -> µs."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(us|µs|ms|s|)\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"bad duration {text!r}: use e.g. 2s, 150ms, 5000us")
    return int(round(float(m.group(1)) * _UNITS[m.group(2)]))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", nargs="?", help="a built-in scene name (see --list), a scene .toml file, a video "
                   "file, an image folder or an images.txt list")
    p.add_argument("--list", action="store_true", help="list the built-in scenes and exit")
    p.add_argument("--duration", type=parse_duration,
                   help="simulated time, e.g. 2s, 150ms (default: the scene's or 1s)")
    p.add_argument("--out", help="event file; the writer is chosen by extension (.npz keeps per-event truth "
                   "columns); ground truth goes to OUT.truth.npz")
    p.add_argument("--seed", type=int, default=0, help="random seed (noise, threshold spread)")
    p.add_argument("--preset", default="ideal", help="sensor model: ideal, realistic, noisy")
    p.add_argument("--sensor", help="sensor size WxH (default: the scene's, built-ins 346x260)")
    p.add_argument("--truth-fps", type=float, default=10.0, help="rate of dense truth maps (intensity, depth, flow)")
    p.add_argument("--window-us", type=int, default=10_000, help="µs per packet")
    p.add_argument("--fps", type=float, default=0.0, help="frame rate of a video / image folder (default: the "
                   "container's; an images.txt gives its own timestamps)")
    p.add_argument("--map", metavar="FILE", help="also write the scene's photometric map (log intensity, depth, K, "
                   "pose at --map-time) to FILE.npz, as tracker.pose_6dof's map= reads it")
    p.add_argument("--map-time", type=parse_duration, default=0, metavar="T",
                   help="the time the map is seen at, e.g. 0s, 50ms (default 0)")
    p.add_argument("--set", action="append", default=[], metavar="K=V",
                   help="override a sensor-model parameter (e.g. shot_noise_hz=2), repeatable")


def main(args: argparse.Namespace) -> int:
    from tectum.sources.simulate import describe_scenes

    if args.list:
        for name, desc in describe_scenes().items():
            print(f"{name:18s} {desc}")
        return 0
    if not args.scene:
        print("tectum simulate: give a SCENE (see --list)", file=sys.stderr)
        return 2
    from tectum import Pipeline, get_registry
    from tectum.sinks.null import NullSink
    from tectum.sources.simulate import SimulateSource

    from ._progress import attach
    from ._signals import run_until_signal

    model = {}
    for kv in args.set:
        if "=" not in kv:
            print(f"tectum simulate: bad --set {kv!r}: expected K=V", file=sys.stderr)
            return 2
        k, v = kv.split("=", 1)
        model[k.strip()] = float(v)
    if args.map:
        from tectum.sources.simulate.photomap import write_scene_map

        try:
            write_scene_map(args.map, args.scene, args.map_time, sensor=args.sensor, seed=args.seed,
                            preset=args.preset, **model)
        except (ValueError, OSError) as e:
            print(f"tectum simulate: --map {args.map}: {e}", file=sys.stderr)
            return 2
    keep_cols = args.out is None or args.out.lower().endswith(".npz")
    src = SimulateSource(f"simulate:{args.scene}", duration_us=args.duration, seed=args.seed, preset=args.preset,
                         sensor=args.sensor, window_us=args.window_us, truth_columns=keep_cols,
                         truth_fps=args.truth_fps, model=model, fps=args.fps)
    p = Pipeline()
    node = p.source(src, id="simulate")
    attach(p, args.quiet, total_us=int(src.sim.T))
    if args.out:
        get_registry().sink_for(args.out)  # fails early, naming the known extensions
        p.sink(args.out, node, id="out")
    else:
        p.sink(NullSink(), node, id="count")
    stats = run_until_signal(p.validate())
    s = stats.nodes.get("simulate")
    n = s.events_out if s is not None else 0
    sim = src.sim
    print(f"{n} events, {sim.steps} steps, {sim.T / 1e6:.3f} s simulated in {stats.wall_s:.2f} s "
          f"({n / max(stats.wall_s, 1e-9) / 1e6:.2f} Mev/s)")
    if args.out:
        truth_path = args.out + ".truth.npz"
        src.truth.save(truth_path)
        print(f"events -> {args.out}\ntruth  -> {truth_path}")
    if args.map:
        print(f"map    -> {args.map}")
    return 0
