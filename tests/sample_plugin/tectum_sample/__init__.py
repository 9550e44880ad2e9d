"""A third-party plugin: ``filter.every_nth`` keeps every n-th event."""

from __future__ import annotations

import numpy as np

from tectum import EventPacket, Operator, hookimpl


class EveryNth(Operator):
    """Keep every ``n``-th event of the stream (counting across packets)."""

    name = "filter.every_nth"

    def __init__(self, n: int = 2) -> None:
        if n < 1:
            raise ValueError("n must be >= 1")
        self.n = n
        self.seen = 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        idx = self.seen + np.arange(len(packet))
        self.seen += len(packet)
        return [packet.select(idx % self.n == 0)]


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_operator(EveryNth)
