"""``tectum bench calibrate``, part ``failure``: where ``tectum.calibrate``
stops meeting its targets, one knob at a time from the ``accuracy`` part's
setting (15 views, 45° tilt, 250 Hz, no noise):

* noise: 10, 30, 100 Hz/px of shot noise;
* views: 3, 5, 8 still views;
* tilt: boards tilted up to 5°, 15°, 60° (low tilt leaves focal length and
  distance confounded);
* blink frequency against timestamp jitter: 250, 1000, 2000 Hz with 0, 50,
  200 µs of Gaussian jitter (a transition must land within 25 % of half a
  period: at 2 kHz that is ±62 µs).

Each row says whether the run met all four targets (``ok``) or why it
failed. ``--quick`` runs one setting per knob less.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tectum.evaluation.harness import table

from ._calibrate_accuracy import run_case

COLS = ["knob", "value", "used", "focal_%", "pp_px", "k1_err", "rms_px", "ok", "error"]


def _ok(row: dict[str, Any]) -> str:
    if "error" in row:
        return "no"
    met = row["focal_%"] <= 0.3 and row["pp_px"] <= 0.5 and row["k1_err"] <= 0.01 and row["rms_px"] <= 0.2
    return "yes" if met else "no"


def run(out: Path, quick: bool) -> dict[str, Any]:
    cases: list[tuple[str, str, dict[str, Any]]] = []
    cases += [("noise Hz/px", str(n), {"noise_hz": n}) for n in ((10.0, 100.0) if quick else (10.0, 30.0, 100.0))]
    cases += [("views", str(v), {"views": v}) for v in ((3, 8) if quick else (3, 5, 8))]
    cases += [("tilt deg", str(t), {"tilt_deg": t}) for t in ((5.0, 60.0) if quick else (5.0, 15.0, 60.0))]
    freqs = (250.0, 2000.0) if quick else (250.0, 1000.0, 2000.0)
    jitters = (0.0, 200.0) if quick else (0.0, 50.0, 200.0)
    cases += [("blink Hz / jitter µs", f"{f:g} / {j:g}", {"blink_hz": f, "jitter_us": j, "views": 8})
              for f in freqs for j in jitters]
    rows = []
    for knob, value, kw in cases:
        row, _ = run_case(knob, 3, **kw)
        row.update(knob=knob, value=value)
        row["ok"] = _ok(row)
        rows.append(row)
        print(table([row], COLS).splitlines()[-1], flush=True)
    print("\n" + table(rows, COLS))
    return {"rows": rows, "targets": []}
