"""``tectum bench filters``' pipeline-gap rows: the pipeline is held to the
faster of the two engine-free figures, never to the slower one alone."""

from __future__ import annotations

import numpy as np

from tectum import EventPacket
from tectum.evaluation.suites import filters


def test_pipeline_held_to_the_faster_engine_free_figure() -> None:
    rng = np.random.default_rng(3)
    n = 6000
    ev = EventPacket(np.sort(rng.integers(0, 40_000, n)).astype(np.int64), rng.integers(0, 64, n).astype(np.uint16),
                     rng.integers(0, 48, n).astype(np.uint16), rng.integers(0, 2, n).astype(np.int8) * 2 - 1,
                     sensor=(64, 48))
    rows, targets = filters.pipeline_gap(ev, quick=True)
    speed = {(r["operation"], r["path"]): r["cpu_mev_s"] for r in rows}
    names = {op for op, _ in speed}
    assert names == set(filters._tectum_ops())
    for t in targets:
        op, rest = t["name"].split(": pipeline ")
        ref = rest.split(" / ")[1].split(" vs ")[0]
        assert ref in ("one array", "no engine")
        assert (op, "no engine") in speed
        free = [speed[(op, "no engine")]] + ([] if op in filters.WINDOWED else [speed[(op, "one array")]])
        assert speed[(op, ref)] == max(free)
    assert len(targets) == 2 * len(names)
