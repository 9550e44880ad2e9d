"""A sink that only counts (for runs whose output is the stats)."""

from __future__ import annotations

from tectum import Kind, Packet, Sink


class NullSink(Sink):
    """Counts what reaches it and discards it (``null:``)."""

    name = "null"
    consumes = (Kind.ANY,)
    schemes = ("null",)

    def __init__(self, url: str = "null:") -> None:
        self.packets = 0
        self.events = 0

    def write(self, packet: Packet) -> None:
        self.packets += 1
        self.events += len(packet.t)  # its rows (the array's len: no Python-level __len__ call per packet)
