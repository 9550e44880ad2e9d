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


def test_the_pipeline_rows_source_is_told_it_gives_events(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The timed pipeline's test-double source is told its kind, so that it
    does not read every piece's kind when made (each run: a cost of the
    double, which a file source does not pay, charged to the engine)."""
    import tectum.testing
    from tectum import Kind

    made: list[object] = []

    class Recording(tectum.testing.ListSource):
        def __init__(self, packets, produces=None) -> None:  # type: ignore[no-untyped-def]
            made.append(produces)
            super().__init__(packets, produces)

    monkeypatch.setattr(tectum.testing, "ListSource", Recording)
    rng = np.random.default_rng(4)
    n = 3000
    ev = EventPacket(np.sort(rng.integers(0, 30_000, n)).astype(np.int64), rng.integers(0, 64, n).astype(np.uint16),
                     rng.integers(0, 48, n).astype(np.uint16), rng.integers(0, 2, n).astype(np.int8) * 2 - 1,
                     sensor=(64, 48), t_start=0, t_end=30_000).validate()
    filters._pipeline(filters._tectum_ops()["refractory"], filters.chunks(ev, 1000))()
    assert made == [[Kind.EVENTS]]
