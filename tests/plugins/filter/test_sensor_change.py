"""Filters with per-pixel state refuse events of another sensor than their first packet's."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import tectum
from tectum import EventPacket, Operator
from tectum.plugins.filter import HotPixel, Refractory, SpatioTemporalCorrelation, Undistort
from tectum.sinks.null import NullSink
from tectum.testing import ListSource

OPERATORS: dict[str, Callable[[], Operator]] = {
    "refractory": lambda: Refractory(period_us=100),
    "stcf": lambda: SpatioTemporalCorrelation(dt_us=1000, k=1),
    "hot_pixel": lambda: HotPixel(learn_us=500),
    "undistort": lambda: Undistort(**Undistort.conformance_params),
}


def _events(sensor: tuple[int, int], t0: int, n: int = 400) -> EventPacket:
    rng = np.random.default_rng(t0)
    t = t0 + np.sort(rng.integers(0, 1000, n))
    return EventPacket.from_arrays(t, rng.integers(0, sensor[0], n), rng.integers(0, sensor[1], n),
                                   rng.choice([-1, 1], n), sensor=sensor, t_start=t0, t_end=t0 + 1000).validate()


@pytest.mark.parametrize("name", list(OPERATORS))
def test_events_of_another_sensor_are_refused_not_indexed_past_the_state(name: str) -> None:
    """Each kernel indexes the state made at the first packet by ``x, y``
    without bounds checks: a packet of another sensor is a ValueError naming
    both sizes (a smaller one here: without the check it would pass
    unnoticed; a larger one would write past the state). The same size
    given as another tuple passes."""
    op = OPERATORS[name]()
    op.process(_events((48, 36), 0))
    op.process(_events(tuple([48, 36]), 1000))  # type: ignore[arg-type]  # equal, not the same object
    with pytest.raises(ValueError, match="24x18 sensor after its state was made for 48x36"):
        op.process(_events((24, 18), 2000))


def test_through_a_pipeline_the_node_is_named() -> None:
    p = tectum.Pipeline()
    p.sink(NullSink(), p.op(Refractory(), p.source(ListSource([_events((48, 36), 0), _events((24, 18), 1000)])),
                            id="rf"))
    with pytest.raises(tectum.NodeError, match="'rf'.*24x18 sensor"):
        tectum.run(p)
