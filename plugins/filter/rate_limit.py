"""``filter.rate_limit``: bound the event rate sent to a control loop."""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, Operator

from ._state import select

__all__ = ["RateLimit", "token_bucket_kernel"]


@njit(cache=True, nogil=True)
def token_bucket_kernel(t, state, rate_per_us, burst, keep):  # type: ignore[no-untyped-def]
    """Token bucket in event time. ``state`` = [tokens, last event time (µs),
    started (0/1)] float64, updated in place. The bucket refills at
    ``rate_per_us`` tokens per µs up to ``burst``; each event takes one
    token if there is one, else it is dropped. Writes ``keep``; returns the
    number kept."""
    tokens = state[0]
    last = state[1]
    started = state[2] != 0.0
    n = 0
    for i in range(t.shape[0]):
        ti = float(t[i])
        if started:
            tokens = min(burst, tokens + (ti - last) * rate_per_us)
        started = True
        last = ti
        if tokens >= 1.0:
            tokens -= 1.0
            keep[i] = True
            n += 1
        else:
            keep[i] = False
    state[0] = tokens
    state[1] = last
    state[2] = 1.0 if started else 0.0
    return n


class RateLimit(Operator):
    """Event-rate limiter for control loops: at most ``burst`` events plus
    ``rate_hz`` events per second of *event time* pass, whatever the input
    rate (a token bucket, so over any interval of T s at most
    ``burst + rate_hz * T`` events come out).

    Drop policy: first come, first served. Within a burst the earliest
    events pass and the rest are dropped until the bucket refills; no event
    is delayed or reordered, so the limiter adds no latency. The decision
    uses timestamps only (never the wall clock), so it is deterministic and
    batch invariant. :attr:`dropped` counts the events dropped so far.

    State: three floats (24 bytes).
    """

    name = "filter.rate_limit"

    def __init__(self, rate_hz: float = 1_000_000.0, burst: int = 10_000) -> None:
        if rate_hz <= 0 or burst < 1:
            raise ValueError("need rate_hz > 0 and burst >= 1")
        self.rate_hz, self.burst = float(rate_hz), int(burst)
        self.state = np.array([float(burst), 0.0, 0.0])
        self.dropped = 0

    def memory_us(self) -> None:
        """The bucket's level depends on every event since the stream began
        (a steady input keeps it from ever refilling)."""
        return None

    def process(self, packet: EventPacket) -> list[EventPacket]:
        keep = np.empty(len(packet), np.bool_)
        n = token_bucket_kernel(packet.t, self.state, self.rate_hz / 1e6, float(self.burst), keep)
        self.dropped += len(packet) - n
        return [select(packet, keep) if n < len(packet) else packet]
