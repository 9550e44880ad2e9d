"""``tectum demo``: the main job on a built-in scene, with a picture and a report."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

HELP = "denoise a simulated scene (with ground truth) and write a before/after picture and a report to --out"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="tectum-demo", help="output folder (default tectum-demo)")
    p.add_argument("--duration-us", type=int, default=300_000, help="length of the scene in µs")
    p.add_argument("--scene", default="shapes", help="built-in scene of `tectum simulate --list`")


#: BGR colours of the picture: background, ON and OFF events, events the simulator labels as noise.
BACKGROUND, ON, OFF, NOISE = (30, 30, 30), (250, 200, 90), (60, 60, 230), (60, 230, 240)
WINDOW_US = 30_000  # the picture shows the last 30 ms
SCALE = 2  # sensor pixels are drawn 2x2 screen pixels


def render(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, sensor: tuple[int, int],
           noise: np.ndarray | None = None) -> np.ndarray:
    """Polarity picture (BGR uint8): ON light blue, OFF red, on dark grey;
    events with a true ``noise`` label in yellow."""
    w, h = sensor
    img = np.full((h, w, 3), BACKGROUND, np.uint8)
    on, off = p > 0, p < 0
    img[y[off], x[off]] = OFF
    img[y[on], x[on]] = ON
    if noise is not None:
        img[y[noise], x[noise]] = NOISE
    return img


def _text(img: np.ndarray, text: str, org: tuple[int, int], size: float = 0.5, colour: Any = (235, 235, 235)) -> None:
    import cv2

    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, size, colour, 1, cv2.LINE_AA)


def figure(before: np.ndarray, after: np.ndarray, title: str, captions: tuple[str, str], footer: str) -> np.ndarray:
    """The two pictures side by side, enlarged, with a title, a caption
    over each, a legend of the colours and a scale bar (BGR uint8)."""
    import cv2

    panels = [cv2.resize(im, None, fx=SCALE, fy=SCALE, interpolation=cv2.INTER_NEAREST) for im in (before, after)]
    ph, pw = panels[0].shape[:2]
    gap, top, cap, bottom = 12, 34, 26, 58
    out = np.full((top + cap + ph + bottom, 2 * pw + 3 * gap, 3), 15, np.uint8)
    _text(out, title, (gap, 22), 0.55)
    for k, (panel, caption) in enumerate(zip(panels, captions)):
        x0 = gap + k * (pw + gap)
        _text(out, caption, (x0, top + 18))
        out[top + cap:top + cap + ph, x0:x0 + pw] = panel
    y = top + cap + ph + 22
    x = gap
    legend = ((ON, "ON event (brighter)"), (OFF, "OFF event (darker)"), (NOISE, "noise (simulator's label)"))
    for colour, label in legend:
        cv2.rectangle(out, (x, y - 10), (x + 10, y), colour, -1)
        _text(out, label, (x + 16, y))
        x += 30 + 9 * len(label)
    bar = 50  # sensor pixels
    cv2.line(out, (x + 10, y - 5), (x + 10 + bar * SCALE, y - 5), (235, 235, 235), 2)
    _text(out, f"{bar} px", (x + 18 + bar * SCALE, y))
    _text(out, footer, (gap, y + 24), 0.45, (190, 190, 190))
    return out


def main(args: argparse.Namespace) -> int:
    import cv2

    import tectum
    from tectum.testing import ListSink

    from ._progress import attach
    from ._signals import run_until_signal

    reg = tectum.get_registry()
    op = "filter.background_activity" if "filter.background_activity" in reg.operators else "filter.refractory"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    p = tectum.Pipeline()
    cam = p.source(f"simulate:{args.scene}", id="camera", duration_us=args.duration_us, preset="realistic")
    raw = ListSink()
    p.sink(raw, cam, id="raw")
    attach(p, args.quiet, total_us=args.duration_us)
    den = p.op(op, cam, id="denoise")
    kept = ListSink()
    p.sink(kept, den, id="kept")
    p.sink(str(out / "denoised.npz"), den, id="file")
    stats = run_until_signal(p.validate())
    a, b = raw.events(), kept.events()
    na, nb = a["noise"] != 0, b["noise"] != 0  # simulator truth: shot, hot-pixel and leak noise
    report = {
        "operator": op,
        "events_in": int(len(a)),
        "events_out": int(len(b)),
        "signal_kept": float((~nb).sum() / max((~na).sum(), 1)),
        "noise_passed": float(nb.sum() / max(na.sum(), 1)),
        "wall_s": stats.wall_s,
        "throughput_mev_s": len(a) / max(stats.nodes["denoise"].busy_ns, 1) * 1e3,
    }
    last, lastb = a.t >= a.t_end - WINDOW_US, b.t >= b.t_end - WINDOW_US
    w, h = a.sensor
    title = (f"tectum demo: {op} on the simulated '{args.scene}' scene ({w}x{h} px, realistic sensor noise), "
             f"the last {WINDOW_US // 1000} ms")
    captions = (f"before: {int(last.sum()):,} events, {int(na[last].sum()):,} of them noise",
                f"after {op}: {int(lastb.sum()):,} events, {int(nb[lastb].sum()):,} noise")
    footer = (f"whole run ({args.duration_us / 1e3:.0f} ms): {report['events_in']:,} events in, "
              f"{report['events_out']:,} out; signal kept {report['signal_kept']:.1%}, "
              f"noise passed {report['noise_passed']:.1%}")
    pic = figure(render(a.t[last], a.x[last], a.y[last], a.p[last], a.sensor, na[last]),
                 render(b.t[lastb], b.x[lastb], b.y[lastb], b.p[lastb], b.sensor, nb[lastb]), title, captions, footer)
    cv2.imwrite(str(out / "before_after.png"), pic)
    (out / "report.json").write_text(json.dumps(report, indent=1))
    text = (
        f"# tectum demo\n\nScene: simulated `{args.scene}` on a {a.sensor[0]}x{a.sensor[1]} sensor, "
        f"{args.duration_us / 1e3:.0f} ms, realistic sensor noise (labelled by the simulator: "
        f"{int(na.sum())} of {len(a)} events are noise).\n\nOperator `{op}`: {report['events_in']} events in, "
        f"{report['events_out']} out; signal kept {report['signal_kept']:.1%}, noise passed "
        f"{report['noise_passed']:.1%}; {report['throughput_mev_s']:.1f} Mev/s inside the operator.\n\n"
        f"![before (left) and after (right), the last {WINDOW_US // 1000} ms; noise in yellow]"
        f"(before_after.png)\n\n```\n{stats.report()}\n```\n"
    )
    (out / "report.md").write_text(text)
    print(text)
    print(f"wrote {out / 'report.md'}, {out / 'before_after.png'}, {out / 'denoised.npz'}")
    return 0
