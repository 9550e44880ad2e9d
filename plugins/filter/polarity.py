"""``filter.polarity``: keep the events of one polarity."""

from __future__ import annotations

from typing import Literal

from tectum import EventPacket, Operator

from ._state import select

__all__ = ["Polarity"]


class Polarity(Operator):
    """Keep only ON (``keep="on"``, p = +1) or OFF (``keep="off"``, p = -1)
    events. Stateless: no memory beyond the output."""

    name = "filter.polarity"

    def __init__(self, keep: Literal["on", "off"] = "on") -> None:
        if keep not in ("on", "off"):
            raise ValueError("keep must be 'on' or 'off'")
        self.keep = keep

    def memory_us(self) -> int:
        """Each event on its own: no memory (time sharding needs no warm-up)."""
        return 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        return [select(packet, packet.p > 0 if self.keep == "on" else packet.p < 0)]
