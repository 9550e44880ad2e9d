"""Every built-in operator passes the batch-invariance conformance check.

Operators are found in the registry (so a newly registered built-in is
checked without touching this file) and built with their defaults. An
operator that needs another input than events gives its own stream through
a class attribute ``conformance_stream`` (a callable returning a packet),
and one that has required parameters gives ``conformance_params`` (a dict);
windowed operators are checked the same way, since they emit when the
watermark passes a window's end. Operators with named ports give one packet
per port; each port is split on its own and the ports interleaved.
"""

from __future__ import annotations

import pytest

import tectum
from tectum import Kind
from tectum.testing import assert_batch_invariant

from helpers import bars

BUILTIN = sorted(
    name for name, e in tectum.get_registry().operators.items()
    if e.cls.__module__.startswith("tectum.")
)


def test_there_are_builtin_operators():
    assert "filter.refractory" in BUILTIN


@pytest.mark.parametrize("name", BUILTIN)
def test_batch_invariance(name):
    cls = tectum.get_registry().operator(name)
    make_stream = getattr(cls, "conformance_stream", None)
    if make_stream is not None:
        stream = make_stream()  # one packet, or one per port for operators with named ports
    elif cls.inputs is not None:
        pytest.fail(f"{name} has ports {sorted(cls.inputs)}: give it a conformance_stream (one packet per port)")
    elif Kind.EVENTS in cls.consumes:
        stream = bars(duration_us=40_000, sensor="48x36", noise_hz=20.0, speed=300.0)
    else:
        pytest.fail(f"{name} consumes {cls.consumes}: give it a conformance_stream")
    params = dict(getattr(cls, "conformance_params", {}))
    assert_batch_invariant(lambda: cls(**params), stream, max_examples=8)
