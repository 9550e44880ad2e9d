"""Long commands show their progress on a terminal (stream time covered,
events, rate, share and time left where the total is known), say nothing
extra when stderr is not a terminal, and ``-q`` silences them. Run in a
subprocess whose stderr is a pseudo-terminal, as a user's shell gives it."""

from __future__ import annotations

import os
import pty
import re
import subprocess
import sys
from pathlib import Path

from tectum.cli._progress import Progress

TECTUM = [sys.executable, "-m", "tectum"]
SIMULATE = ["simulate", "shapes", "--duration", "3s", "--sensor", "64x48"]


def _on_a_terminal(argv: list[str]) -> tuple[str, str]:
    """(stderr as the terminal shows it, stdout) of tectum ``argv``."""
    master, slave = pty.openpty()
    p = subprocess.Popen([*TECTUM, *argv], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=slave)
    os.close(slave)
    seen = b""
    while True:
        try:
            data = os.read(master, 4096)
        except OSError:  # EIO: the child has closed the terminal
            break
        if not data:
            break
        seen += data
    out, _ = p.communicate(timeout=120)
    assert p.returncode == 0, seen
    os.close(master)
    return seen.decode(), out.decode()


def test_simulate_shows_progress_with_eta_on_a_terminal() -> None:
    err, out = _on_a_terminal(SIMULATE)
    lines = [ln for ln in err.split("\r") if ln.strip()]
    assert lines, err
    assert all(re.fullmatch(r"\d+\.\d{3} s of 3\.000 s \(\d+%\) · [\d,]+ events · [\d.]+ (M|k|)ev/s · ETA .+", ln.rstrip())
               for ln in lines), lines
    assert err.endswith("\r") and not err.split("\r")[-2].strip()  # the line is cleared at the end
    assert "3.000 s simulated" in out


def test_convert_shows_progress_and_quiet_silences_it(tmp_path: Path) -> None:
    src = tmp_path / "big.npz"
    subprocess.run([*TECTUM, "run", "pattern:?duration_us=20000000&sensor=64x48&noise_hz=20", "--sink", str(src)],
                   check=True, capture_output=True)
    err, _ = _on_a_terminal(["convert", str(src), str(tmp_path / "out.raw")])
    assert re.search(r"\d+\.\d{3} s · [\d,]+ events · [\d.]+ (M|k|)ev/s", err), err
    err, out = _on_a_terminal(["convert", "-q", str(src), str(tmp_path / "out2.raw")])
    assert err == "" and "events ->" in out


def test_nothing_extra_when_not_a_terminal() -> None:
    r = subprocess.run([*TECTUM, *SIMULATE], capture_output=True, text=True, check=True)
    assert r.stderr == ""


def test_eta_from_the_rate_so_far() -> None:
    import tectum

    pr = Progress(total_us=4_000_000)
    pr.update(tectum.EventPacket.from_arrays([0, 999_999], [0, 1], [0, 0], [1, -1], sensor=(2, 2)))
    assert pr.line(2.0) == "1.000 s of 4.000 s (25%) · 2 events · 1 ev/s · ETA 6 s"
