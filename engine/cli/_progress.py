"""Progress of long commands on a terminal: one line on stderr, rewritten in
place a few times a second, giving the stream time covered, the events, the
rate and, where the total is known, the share done and the time left.

Shown only when stderr is a terminal and ``-q`` was not given: piped or
redirected output stays clean. The line is cleared when the work ends, so the
command's own summary follows on a clean line.
"""

from __future__ import annotations

import sys
import time
from typing import IO, Any

from tectum import EventPacket, Kind, Packet, Sink

__all__ = ["Progress", "ProgressSink", "wanted", "attach"]

_EVERY_S = 0.2  # seconds between redraws


def wanted(quiet: bool, stream: IO[str] | None = None) -> bool:
    """Show progress: not ``-q``, and the stream (stderr) is a terminal."""
    stream = stream or sys.stderr
    return not quiet and hasattr(stream, "isatty") and stream.isatty()


def _duration(s: float) -> str:
    s = max(0.0, s)
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{s // 60:.0f} min {s % 60:02.0f} s"
    return f"{s // 3600:.0f} h {s % 3600 // 60:02.0f} min"


def _rate(per_s: float) -> str:
    if per_s >= 1e6:
        return f"{per_s / 1e6:.2f} Mev/s"
    return f"{per_s / 1e3:.1f} kev/s" if per_s >= 1e3 else f"{per_s:.0f} ev/s"


class Progress:
    """Counts packets as they pass and redraws the line at most every
    0.2 s. ``total_us``: the stream time the work covers, when known
    (simulated duration, a requested time range), for percent and ETA."""

    def __init__(self, total_us: int | None = None, stream: IO[str] | None = None) -> None:
        self.total_us = total_us
        self.stream = stream or sys.stderr
        self.events = 0
        self.t0: int | None = None
        self.t_now = 0
        self.started = self._drawn = 0.0  # wall clock from the first packet (start-up is not work)
        self._width = 0

    def update(self, packet: Packet) -> None:
        if self.t0 is None:
            self.t0 = packet.t_start
            self.started = self._drawn = time.monotonic()
        self.t_now = max(self.t_now, packet.t_end)
        if isinstance(packet, EventPacket):
            self.events += len(packet)
        now = time.monotonic()
        if now - self._drawn >= _EVERY_S:
            self._drawn = now
            self._draw(self.line(now - self.started))

    def line(self, wall_s: float) -> str:
        """The progress line after ``wall_s`` seconds of work."""
        covered = (self.t_now - self.t0) if self.t0 is not None else 0
        parts = [f"{covered / 1e6:.3f} s"]
        if self.total_us:
            parts[0] += f" of {self.total_us / 1e6:.3f} s ({min(covered / self.total_us, 1.0):.0%})"
        parts.append(f"{self.events:,} events")
        parts.append(_rate(self.events / max(wall_s, 1e-9)))
        if self.total_us and covered > 0:
            parts.append(f"ETA {_duration(wall_s * (self.total_us - covered) / covered)}")
        return " · ".join(parts)

    def _draw(self, text: str) -> None:
        pad = max(0, self._width - len(text))
        self._width = len(text)
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()

    def done(self) -> None:
        """Clear the line (the command prints its own summary). Work done
        before the first redraw still shows its line once, so what a
        terminal shows does not depend on how fast the machine is."""
        if not self._width and self.t0 is not None:
            self._draw(self.line(time.monotonic() - self.started))
        if self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
            self._width = 0


class ProgressSink(Sink):
    """A sink that feeds a :class:`Progress` from a source's stream (a
    pipeline's ``run``): takes every kind, writes nothing."""

    name = "progress"
    consumes = (Kind.ANY,)

    def __init__(self, progress: Progress) -> None:
        self.progress = progress

    def write(self, packet: Packet) -> None:
        self.progress.update(packet)

    def close(self) -> None:
        self.progress.done()

    def abort(self) -> None:
        self.progress.done()


def attach(pipeline: Any, quiet: bool, total_us: int | None = None) -> None:
    """Add a progress sink behind the pipeline's first source, when
    :func:`wanted`."""
    if not wanted(quiet):
        return
    sources = [n.id for n in pipeline.nodes if n.role == "source"]
    if sources:
        pipeline.sink(ProgressSink(Progress(total_us)), sources[0], id="progress")
