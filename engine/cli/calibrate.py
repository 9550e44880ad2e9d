"""``tectum calibrate``: intrinsics (and stereo extrinsics) from a recording of a calibration pattern."""

from __future__ import annotations

import argparse
import sys

HELP = "calibrate a camera from a blinking dot/LED grid (or checkerboard frames); writes OpenCV YAML, calib.txt or ROS"

PATTERNS = ("dots", "leds", "checker-screen", "checkerboard")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("events", help="the recording (any format tectum reads)")
    p.add_argument("right", nargs="?", help="a second camera's recording of the same board at the same time: "
                   "stereo extrinsics, written so filter.undistort:side=left|right rectifies")
    p.add_argument("--pattern", choices=PATTERNS, default="dots",
                   help="dots / leds: a blinking circle grid; checker-screen: a screen blinking a checkerboard; "
                   "checkerboard: a printed board in APS frames, or in map.high_pass images of a moving board")
    p.add_argument("--grid", required=True, metavar="COLSxROWS",
                   help="dots per row x rows (circle grids), or inner corners (checkerboards)")
    p.add_argument("--spacing", type=float, required=True, metavar="METRES",
                   help="distance between neighbouring dots of a row (asymmetric grids: half of it, as OpenCV), "
                   "or the checkerboard's square size")
    p.add_argument("--frequency", type=float, default=0.0, metavar="HZ",
                   help="blink frequency (default: found from the events)")
    p.add_argument("--asymmetric", action="store_true", help="an asymmetric circle grid (OpenCV's)")
    p.add_argument("--model", choices=("radtan", "fisheye"), default="radtan",
                   help="lens model: radtan (k1 k2 p1 p2) or fisheye (equidistant k1..k4)")
    p.add_argument("--k3", action="store_true", help="also fit k3 (radtan)")
    p.add_argument("--min-views", type=int, default=5, help="views of the whole board needed (default 5)")
    p.add_argument("--reconstruct-us", type=int, default=0, metavar="US",
                   help="checkerboard: map.high_pass images of the events every US µs instead of APS frames")
    p.add_argument("--out", required=True, help="calibration file to write (.yaml OpenCV, .txt ECD calib.txt)")
    p.add_argument("--format", choices=("opencv", "ecd", "ros"), default=None,
                   help="file layout (default by --out's extension)")


def main(args: argparse.Namespace) -> int:
    from tectum.calibration import calibrate, calibrate_frames, calibrate_stereo, write_calibration, write_stereo

    model = "equidistant" if args.model == "fisheye" else "radtan"
    kw = dict(frequency_hz=args.frequency, asymmetric=args.asymmetric, model=model, k3=args.k3,
              min_views=args.min_views, pattern="checker" if args.pattern == "checker-screen" else "dots")
    if args.right:
        if args.pattern == "checkerboard":
            raise ValueError("stereo calibration takes blinking patterns (dots, leds, checker-screen)")
        if args.format not in (None, "opencv"):
            raise ValueError("a stereo calibration is written as OpenCV YAML (M1 D1 M2 D2 R T R1 R2 P1 P2)")
        st = calibrate_stereo(args.events, args.right, args.grid, args.spacing, **kw)
        print("left:\n" + st.left.summary() + "\nright:\n" + st.right.summary())
        s = st.stereo
        print(f"stereo: {s.pairs} view pairs, RMS {s.rms:.4f} px, baseline {float((s.T ** 2).sum() ** 0.5):.4f} m")
        write_stereo(args.out, s.left, s.right, s.R, s.T, s.R1, s.R2, s.P1, s.P2, rms=s.rms)
    else:
        if args.pattern == "checkerboard":
            cal = calibrate_frames(args.events, args.grid, args.spacing, reconstruct_us=args.reconstruct_us,
                                   model=model, k3=args.k3, min_views=args.min_views)
        else:
            cal = calibrate(args.events, args.grid, args.spacing, **kw)
        print(cal.summary())
        write_calibration(args.out, cal.camera, rms=cal.rms, fmt=args.format,
                          per_view=[v.rms for v in cal.views if v.points is not None])
    print(f"wrote {args.out}", file=sys.stderr)
    return 0
