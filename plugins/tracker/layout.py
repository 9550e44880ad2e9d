"""LED marker layouts: the ``layout=`` file of ``tracker.led_markers``.

A layout is a small text file, one LED per line: its id (a positive
integer, the track id the operator gives it), its position ``x y z`` in
metres in the marker body's frame, and its blink frequency in Hz; blank
lines and ``#`` comments are ignored; values are separated by spaces, tabs
or commas::

    # id  x (m)   y (m)   z (m)   frequency (Hz)
    1     0.00    0.00    0.00    700
    2     0.10    0.00    0.00    950
    3     0.10    0.08    0.00    1200
    4     0.00    0.08    0.02    1500

The 6-DoF pose needs at least 4 LEDs (``cv2.solvePnP``), and an LED is
known by its frequency alone, so two LEDs must not share one: a layout with
fewer than 4 LEDs, repeated ids or frequencies, a non-finite value or a
frequency <= 0 is rejected when it is read (:class:`tectum.FormatError`
naming the file and line, or the reason). Whether frequencies are far
enough apart for the operator's tolerance is checked by the operator
(:func:`check_bands`), before the run.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tectum import FormatError

__all__ = ["MarkerLayout", "read_layout", "parse_layout", "check_bands"]


@dataclass(frozen=True)
class MarkerLayout:
    """LEDs of a marker body: ``ids`` (n,) int64, ``points`` (n, 3) m in the
    body frame, ``freqs`` (n,) Hz; ``source`` names where it came from."""

    ids: np.ndarray
    points: np.ndarray
    freqs: np.ndarray
    source: str = ""

    def __len__(self) -> int:
        return len(self.ids)


def parse_layout(text: str, source: str = "layout", min_markers: int = 4) -> MarkerLayout:
    """A layout from its text (see the module); ``source`` names it in errors."""
    ids: list[int] = []
    rows: list[list[float]] = []
    lines: list[int] = []
    for no, line in enumerate(text.splitlines(), 1):
        body = line.split("#", 1)[0].replace(",", " ").split()
        if not body:
            continue
        where = f"{source}, line {no}"
        if len(body) != 5:
            raise FormatError(f"{where}: expected 'id x y z frequency_hz', got {len(body)} values")
        try:
            ident = int(body[0])
            vals = [float(v) for v in body[1:]]
        except ValueError:
            raise FormatError(f"{where}: not numbers: {line.strip()!r}") from None
        if ident < 1:
            raise FormatError(f"{where}: id {ident} must be a positive integer")
        if not all(math.isfinite(v) for v in vals):
            raise FormatError(f"{where}: non-finite value in {line.strip()!r}")
        if vals[3] <= 0:
            raise FormatError(f"{where}: frequency {vals[3]:g} Hz must be > 0")
        if ident in ids:
            raise FormatError(f"{where}: id {ident} repeats line {lines[ids.index(ident)]}")
        for j, r in enumerate(rows):
            if r[3] == vals[3]:
                raise FormatError(f"{where}: frequency {vals[3]:g} Hz repeats line {lines[j]} (an LED is known by "
                                  "its frequency: each needs its own)")
        ids.append(ident)
        rows.append(vals)
        lines.append(no)
    if len(ids) < min_markers:
        raise FormatError(f"{source}: {len(ids)} LEDs; the pose needs at least {min_markers} (solvePnP)")
    arr = np.array(rows, np.float64)
    return MarkerLayout(np.array(ids, np.int64), arr[:, :3].copy(), arr[:, 3].copy(), source)


def read_layout(path: str, min_markers: int = 4) -> MarkerLayout:
    """A layout file (see the module)."""
    if not os.path.isfile(path):
        raise FormatError(f"{path}: no such layout file")
    with open(path, encoding="utf-8", errors="replace") as f:
        return parse_layout(f.read(), path, min_markers)


def check_bands(freqs: Sequence[float] | np.ndarray, tol: float, reject_hz: Sequence[float],
                source: str = "layout") -> None:
    """Each LED's frequency band ``f / (1 + tol) .. f (1 + tol)`` must not
    overlap another's nor hold a rejected (mains flicker) frequency:
    ValueError with the two frequencies otherwise."""
    f = sorted(float(v) for v in freqs)
    for a, b in zip(f, f[1:]):
        if a * (1 + tol) >= b / (1 + tol):
            raise ValueError(f"{source}: LED frequencies {a:g} and {b:g} Hz are within the tolerance "
                             f"({tol:g}) of each other: they cannot be told apart")
    for a in f:
        for m in reject_hz:
            if a / (1 + tol) <= m <= a * (1 + tol):
                raise ValueError(f"{source}: LED frequency {a:g} Hz is within the tolerance ({tol:g}) of "
                                 f"{m:g} Hz, a rejected (mains flicker) band")
