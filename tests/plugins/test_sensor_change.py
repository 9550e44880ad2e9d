"""Operators with per-pixel state refuse events of another sensor than their first packet's.

Their kernels index the state made at the first packet by ``x, y`` without
bounds checks, so the events of a larger sensor would write past it (before
this check, a 48x36 packet then a 96x72 one corrupted the heap or wrote out of
bounds in 20 built-in operators: found with ``NUMBA_BOUNDSCHECK=1``). Every
built-in one-input event operator is checked (found in the registry, so a new
one is too): it refuses with a ValueError naming both sizes, or it is one of
:data:`NO_PIXEL_STATE`, which keep no state sized by the sensor and take any.
"""

from __future__ import annotations

import numpy as np
import pytest

import tectum
from tectum import EventPacket
from tectum.plugins.filter import Refractory
from tectum.sinks.null import NullSink
from tectum.testing import ListSource

from helpers import builtin_operators, conformance_case

#: operators that keep nothing sized by the sensor (per-event maps, global
#: rates, images made afresh for each window from the packet's own sensor)
NO_PIXEL_STATE = frozenset({
    "filter.downsample", "filter.flip", "filter.polarity", "filter.rate_limit", "filter.roi", "filter.rotate",
    "filter.time_window", "tracker.angular_velocity", "tracker.clusters", "tracker.ego_motion",
    "tracker.led_markers",
})


def _events(sensor: tuple[int, int], t0: int, n: int = 300) -> EventPacket:
    rng = np.random.default_rng(t0)
    t = t0 + np.sort(rng.integers(0, 10_000, n))
    return EventPacket.from_arrays(t, rng.integers(0, sensor[0], n), rng.integers(0, sensor[1], n),
                                   rng.choice([-1, 1], n), sensor=sensor, t_start=t0, t_end=t0 + 10_000).validate()


def _event_operators() -> list[str]:
    return [n for n in builtin_operators() if isinstance(conformance_case(n)[1], EventPacket)]


@pytest.mark.parametrize("name", _event_operators())
def test_another_sensor_is_refused_by_every_operator_with_pixel_state(name: str) -> None:
    """The first packet is the operator's own conformance stream's first 10
    ms; the next has every event on a sensor twice as wide and high. The
    same size as another tuple (equal, not the same object) passes."""
    cls, stream, params = conformance_case(name)
    op = cls(**params)
    first = stream.slice_time(None, stream.t_start + 10_000)
    op.process(first)
    w, h = stream.sensor
    nxt = stream.slice_time(first.t_end, first.t_end + 10_000)
    op.process(EventPacket(nxt.t, nxt.x, nxt.y, nxt.p, sensor=(int(w), int(h)), t_start=nxt.t_start,
                           t_end=nxt.t_end, columns=dict(nxt.columns)))  # equal, not the same tuple
    big = _events((2 * w, 2 * h), nxt.t_end)
    bigger = big.with_columns(**{k: np.zeros(len(big), v.dtype) for k, v in stream.columns.items()})
    if name in NO_PIXEL_STATE:
        op.process(bigger)
        op.finish()
    else:
        with pytest.raises(ValueError, match=f"{name}: events of a {2 * w}x{2 * h} sensor after its state was made "
                                             f"for {w}x{h}"):
            op.process(bigger)


def test_no_pixel_state_names_are_operators() -> None:
    assert NO_PIXEL_STATE <= set(_event_operators())


def test_through_a_pipeline_the_node_is_named() -> None:
    p = tectum.Pipeline()
    p.sink(NullSink(), p.op(Refractory(), p.source(ListSource([_events((48, 36), 0), _events((24, 18), 10_000)])),
                            id="rf"))
    with pytest.raises(tectum.NodeError, match="'rf'.*24x18 sensor"):
        tectum.run(p)
