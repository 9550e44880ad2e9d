"""A public reference for angular velocity by contrast maximisation, run
side by side with ``tracker.angular_velocity``: the code of Gu, Learned-Miller,
Sheldon, Gallego & Bideau, "The Spatio-Temporal Poisson Point Process: A
Simple Model for the Alignment of Event Camera Data" (ICCV 2021),
https://github.com/pbideau/Event-ST-PPP, which estimates a camera's
angular velocity per batch of events with contrast maximisation
(``-m cmax``) or with their ST-PPP likelihood (``-m st-ppp``), in PyTorch
(Adam, 250 iterations per batch of 30,000 events: their defaults).

It is not on PyPI. To run it, clone it and point ``TECTUM_STPPP`` at the
clone; its own requirements (torch, pandas, scikit-learn, opencv,
matplotlib) must import in the interpreter that runs the benchmark. The
code runs as a separate process on an ECD-layout folder (``events.txt`` in
seconds, ``calib.txt``), exactly as its README says; nothing of it is
imported here or copied into tectum.

Its batches are consecutive, non-overlapping runs of ``ne`` events from
the first event, so tectum is run with ``window_events = step_events =
ne`` on the same events: the same windows. Its sign and axes are those of
tectum's (camera frame, x right, y down, z forward; measured on the
simulated scenes, where both agree with the truth).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tectum import EventPacket

__all__ = ["STPPP_REQUIREMENTS", "find_stppp", "run_stppp", "run_stppp_folder", "write_ecd_folder", "ReferenceRun"]

#: the modules the reference imports
STPPP_REQUIREMENTS = ("torch", "pandas", "sklearn", "cv2", "matplotlib")


def find_stppp() -> tuple[Path | None, str]:
    """The reference's checkout (``TECTUM_STPPP``) if it can run here, and
    why not otherwise."""
    root = os.environ.get("TECTUM_STPPP")
    if not root:
        return None, ("ST-PPP reference not run: set TECTUM_STPPP to a clone of "
                      "https://github.com/pbideau/Event-ST-PPP (not on PyPI)")
    path = Path(root)
    if not (path / "src" / "main.py").is_file():
        return None, f"ST-PPP reference not run: {path}/src/main.py does not exist"
    missing = [m for m in STPPP_REQUIREMENTS if importlib.util.find_spec(m) is None]
    if missing:
        return None, f"ST-PPP reference not run: its requirements {', '.join(missing)} do not import here"
    return path, ""


def write_ecd_folder(folder: Path, ev: EventPacket, f: float, cx: float, cy: float) -> None:
    """``events.txt`` (t in s, x, y, polarity 0/1) and ``calib.txt`` (fx fy
    cx cy and zero distortion) in the layout of the Event Camera Dataset."""
    folder.mkdir(parents=True, exist_ok=True)
    p01 = (np.asarray(ev.p) > 0).astype(np.int64)
    rows = np.column_stack([ev.t * 1e-6, ev.x, ev.y, p01])
    np.savetxt(folder / "events.txt", rows, fmt=["%.9f", "%d", "%d", "%d"], delimiter=" ")
    (folder / "calib.txt").write_text(f"{f} {f} {cx} {cy} 0 0 0 0 0\n")


@dataclass
class ReferenceRun:
    """One run of the reference on a folder: per batch the first and last
    event times (µs) and ω (rad/s, camera frame), and the seconds it spent
    per batch (its own ``Duration`` lines, wall clock)."""

    t0: np.ndarray
    t1: np.ndarray
    omega: np.ndarray
    seconds: np.ndarray


def run_stppp(root: Path, ev: EventPacket, f: float, cx: float, cy: float, *, method: str = "cmax",
              ne: int = 30_000, timeout_s: float = 1800.0) -> ReferenceRun:
    """Run the reference on ``ev`` written as an ECD folder with the pinhole
    intrinsics ``f, cx, cy`` (px) in a temporary directory (see
    :func:`run_stppp_folder`)."""
    with tempfile.TemporaryDirectory(prefix="tectum-stppp-") as tmp:
        write_ecd_folder(Path(tmp) / "seq", ev, f, cx, cy)
        return run_stppp_folder(root, Path(tmp) / "seq", method=method, ne=ne, timeout_s=timeout_s)


def run_stppp_folder(root: Path, folder: Path, *, method: str = "cmax", ne: int = 30_000,
                     timeout_s: float = 1800.0) -> ReferenceRun:
    """Run the reference (``method`` = ``cmax`` or ``st-ppp``) on an
    ECD-layout ``folder`` (240x180: the size it assumes), its output going
    to a temporary directory; raises ``RuntimeError`` with the last line of
    its stderr when it fails."""
    if method not in ("cmax", "st-ppp"):
        raise ValueError(f"method is cmax or st-ppp, not {method!r}")
    with tempfile.TemporaryDirectory(prefix="tectum-stppp-out-") as tmp:
        work = Path(tmp)
        cmd = [sys.executable, str(root / "src" / "main.py"), "-p", str(folder.parent), "-s", folder.name,
               "-m", method, "-t", "rot", "-n", str(ne), "-o", "out.txt"]
        env = {**os.environ, "MPLBACKEND": "Agg", "OMP_NUM_THREADS": "1"}  # one core, as tectum's figure
        c0 = time.perf_counter()
        run = subprocess.run(cmd, cwd=work, capture_output=True, text=True, timeout=timeout_s, env=env)
        if run.returncode != 0:
            last = (run.stderr.strip().splitlines() or ["(no output)"])[-1]
            raise RuntimeError(f"ST-PPP reference ({method}) failed: {last}")
        out = work / "output" / folder.name / "out.txt"
        table = np.loadtxt(out, ndmin=2) if out.exists() else np.empty((0, 7))
        secs = np.array([float(v) for v in re.findall(r"Duration:([0-9.eE+-]+)s", run.stdout)])
        if len(secs) != len(table):
            secs = np.full(len(table), (time.perf_counter() - c0) / max(len(table), 1))
    return ReferenceRun(t0=np.round(table[:, 1] * 1e6).astype(np.int64),
                        t1=np.round(table[:, 2] * 1e6).astype(np.int64), omega=table[:, 4:7].copy(), seconds=secs)
