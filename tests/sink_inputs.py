"""What to feed a sink in the tests that cover every registered sink: the
kind it takes (events when it takes them) and a stream of that kind.

``from sink_inputs import sink_kind, write_input`` (``tests`` is on the path).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tectum import Kind, Packet, accepts, packet_class
from tectum.sinks.files._common import write_all
from tectum.sinks.npz import NpzSink

#: The moving bars an event sink gets (small, with noise).
BARS = "pattern:?duration_us=20000&sensor=32x24&noise_hz=2"


def sink_kind(cls: type) -> Kind:
    """Events when the sink takes them, else the first kind it names."""
    if accepts(cls.consumes, Kind.EVENTS):
        return Kind.EVENTS
    return next(k for k in cls.consumes if k != Kind.ANY)


def samples(kind: Kind, n: int = 25) -> Packet:
    """``n`` samples of ``kind``, 1 ms apart from 5 ms: every required field
    as plain numbers (poses: one unit quaternion)."""
    cls = packet_class(kind)
    t = np.arange(n, dtype=np.int64) * 1000 + 5000
    data = {}
    for name, spec in cls.fields.items():
        if not spec.optional:
            shape = (n, *(spec.shape or ()))
            data[name] = (np.arange(np.prod(shape)).reshape(shape) % 97 / 8).astype(spec.dtype)
    if kind == Kind.POSES:
        data["orientation"] = np.tile([0.0, 0.0, 0.6, 0.8], (n, 1))
    return cls(t, t_start=int(t[0]), t_end=int(t[-1]) + 1, **data)


def write_input(path: Path, kind: Kind) -> str:
    """Write a stream of ``kind`` to ``path`` (.npz) and return the source
    argument that reads it (``BARS`` itself for events)."""
    if kind == Kind.EVENTS:
        return BARS
    write_all(NpzSink(str(path)), [samples(kind)])
    return str(path)
