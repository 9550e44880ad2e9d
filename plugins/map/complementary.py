"""``map.complementary``: log intensity from events fused with APS frames
by a per-pixel complementary filter (Scheerlinck, Barnes, Mahony,
"Continuous-time intensity estimation using event cameras", ACCV 2018).

Each pixel obeys ``dL/dt = E(t) - α (L - L_F)``: the events ``E`` (``+c_on``
/ ``-c_off`` each) are integrated as by ``map.high_pass``, and the estimate
relaxes towards the log of the latest frame ``L_F = log(I / full_scale +
frame_offset)`` at the crossover frequency ``α`` (rad/s). Frames carry the
static content (the DC the high-pass filter loses), events the fast changes
between frames (which the frames miss, and their blur). ``L_F`` is held
from one frame's timestamp to the next; at a new frame every pixel is
decayed to its time and the base moves under it, so the estimate stays
continuous. The first frame is taken as the base outright (what the events
added before it stays on top): the zero the filter starts from is no
measurement. Without frames (a source that has none) it is the high-pass
filter.

The ``frames`` port is filled by kind from the source when it has frames
(an ECD folder with ``images.txt``, ``simulate:...?davis=true``, AEDAT 4).
Frames are (H, W) or (H, W, C) (channels averaged) of the events' sensor
size, uint8 (full scale 255), uint16 (65535) or float (linear, 1 = full
scale). Maps, windows and costs as ``map.high_pass`` (plus one pass over the
image per frame); the map has no ``confidence`` here (the frames inform
every pixel). Memory: 16 bytes per pixel (state and base).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from tectum import FramePacket, Kind, Packet, Port

from ._integrate import log_frame, switch_base
from .high_pass import _FRAME, HighPass

__all__ = ["Complementary"]


class Complementary(HighPass):
    """Log-intensity maps fusing events with APS frames (complementary filter, Scheerlinck et al. 2018).

    Parameters
    ----------
    alpha:
        Crossover frequency, rad/s: below it the frames are trusted, above
        it the events. Default 30 (4.8 Hz): the frames are trusted over a
        few frame times of a DAVIS at 20-50 fps (measured best on simulated
        DAVIS scenes at 30 fps, and on ``ecd/slider_depth`` with frames
        held out).
    c_on:
        Contrast of an ON event, log-intensity units (> 0).
    c_off:
        Contrast of an OFF event (> 0; the event subtracts it).
    frame_offset:
        Added to the frame's intensity (1 = full scale) before the log, so
        that black pixels have a finite log: about a grey level of an 8-bit
        frame by default (the noise floor of the dark pixels).
    window_us:
        Time windows of this many µs (default 10 000 when ``count`` is not given).
    count:
        Or a map every ``count`` events.
    partial:
        Emit the unfinished last window at end of stream when it holds events.
    at_us:
        Or maps at these instants (µs, increasing) instead of windows.
    """

    name = "map.complementary"
    inputs = {
        "events": Port(Kind.EVENTS, doc="the events to integrate"),
        "frames": Port(Kind.FRAMES, required=False, doc="APS frames the estimate relaxes to (the low frequencies)"),
    }

    #: For the conformance check: short windows over the 40 ms stream.
    conformance_params = {"window_us": 4000, "alpha": 20.0}
    with_confidence = False

    def __init__(self, alpha: float = 30.0, c_on: float = 0.2, c_off: float = 0.2,
                 frame_offset: float = 1.0 / 255, window_us: int | None = None, count: int | None = None,
                 partial: bool = True, at_us: tuple[int, ...] = ()) -> None:
        super().__init__(alpha=alpha, c_on=c_on, c_off=c_off, window_us=window_us, count=count, partial=partial,
                         at_us=at_us)
        if not (frame_offset > 0 and math.isfinite(frame_offset)):
            raise ValueError(f"frame_offset must be finite and > 0, got {frame_offset}")
        self.frame_offset = float(frame_offset)
        self.counts["frames"] = 0

    @staticmethod
    def conformance_stream() -> dict[str, Packet]:
        """Bars moving over a 48x36 sensor with noise, with a frame every 5 ms."""
        ev = HighPass.conformance_stream()["events"]
        t = np.arange(1000, 40_000, 5000, dtype=np.int64)
        rng = np.random.default_rng(0)
        images = rng.integers(0, 256, (len(t), 36, 48)).astype(np.uint8)
        return {"events": ev, "frames": FramePacket(t, images=images, t_start=ev.t_start, t_end=ev.t_end)}

    def warmup(self) -> None:
        super().warmup()
        D = np.zeros((2, 2), np.float32)
        switch_base(D, np.zeros((2, 2), np.int64), D, D, 1, 1e-6)

    def _frame_cuts(self, ports: Mapping[str, Packet], t: np.ndarray) -> list[tuple[int, int, int, int]]:
        fr = ports.get("frames")
        if fr is None or not len(fr):
            return []
        idx = np.searchsorted(t, fr.t, side="left")
        return [(int(idx[k]), int(fr.t[k]), _FRAME, k) for k in range(len(fr))]

    def _apply_frame(self, ports: Mapping[str, Packet], k: int) -> None:
        fr = ports["frames"]
        assert isinstance(fr, FramePacket)
        new = log_frame(fr.images[k], self.frame_offset)
        h, w = new.shape
        try:
            self._ensure_state((w, h))
        except ValueError:
            raise ValueError(f"{self.name}: a frame of {w}x{h} px at t = {int(fr.t[k])} µs does not match the "
                             f"events' sensor {self.D.shape[1]}x{self.D.shape[0]}") from None  # type: ignore[union-attr]
        old = self.base if self.base.shape[0] else new  # the first frame becomes the base outright
        switch_base(self.D, self.t_last, old, new, int(fr.t[k]), self._a)
        self.base = new
        self.counts["frames"] += 1
