"""A third-party plugin: ``filter.every_nth`` keeps every n-th event, and the
``sample`` suite of ``tectum bench`` measures its speed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

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


def bench_every_nth(out: Path, quick: bool) -> dict[str, Any]:
    """Mev/s of ``filter.every_nth`` (n = 2) on one packet of random events,
    with a target of 1 Mev/s."""
    from tectum.evaluation.harness import target, targets_table, throughput

    n = 100_000 if quick else 1_000_000
    rng = np.random.default_rng(0)
    pkt = EventPacket.from_arrays(np.arange(n), rng.integers(0, 64, n), rng.integers(0, 48, n),
                                  rng.integers(0, 2, n), sensor=(64, 48))
    r = throughput(lambda: EveryNth(2).process(pkt), n, repeat=3)
    targets = [target("every_nth, n = 2", r["mev_s"], 1.0, "Mev/s")]
    print(targets_table(targets))
    return {"throughput": r, "targets": targets}


@hookimpl
def tectum_register_operators(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_operator(EveryNth)


@hookimpl
def tectum_register_bench_suites(registry) -> None:  # type: ignore[no-untyped-def]
    registry.add_bench_suite("sample", bench_every_nth, "speed of filter.every_nth (the sample plugin)")
