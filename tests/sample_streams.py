"""Hypothesis strategies for sample streams of every kind, for the file
round-trip tests (``from sample_streams import sample_packet``)."""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tectum import Kind, SamplePacket, packet_class

#: The built-in kinds whose fields are all scalars and vectors (a CSV holds them).
FLAT_KINDS = (Kind.IMU, Kind.POSES, Kind.TRIGGERS, Kind.ANGULAR_VELOCITY, Kind.TRACKS, Kind.CLUSTERS, Kind.POINTS)


def _values(dtype: np.dtype, shape: tuple[int, ...], finite: bool) -> Any:
    if dtype.kind in "ib":
        return hnp.arrays(dtype, shape)  # the whole int64 range; flags
    elements = st.floats(width=dtype.itemsize * 8, allow_nan=not finite, allow_infinity=not finite)
    return hnp.arrays(dtype, shape, elements=elements)


@st.composite
def sample_packet(draw: Any, kind: Kind, max_rows: int = 40, extras: bool = False,
                  keep: tuple[str, ...] | None = None, t_max: int = 1 << 62) -> SamplePacket:
    """A packet of ``kind``: times from anywhere in ``[-t_max, t_max]`` µs
    (runs of equal times included), every required field, each optional
    one or not, floats anywhere (NaN, inf, subnormals) except in poses,
    whose rows are poses (finite, unit quaternion). ``extras`` adds
    undeclared fields (an int16 vector, a float32 scalar); ``keep`` limits
    the fields to those named."""
    cls = packet_class(kind)
    assert issubclass(cls, SamplePacket)
    n = draw(st.integers(0, max_rows))
    base = draw(st.integers(-t_max, t_max - (1 << 46)))
    steps = draw(hnp.arrays(np.int64, n, elements=st.integers(0, 3) | st.integers(0, 1 << 40)))
    t = base + np.cumsum(steps)
    poses = kind == Kind.POSES
    data: dict[str, np.ndarray] = {}
    for name, spec in cls.fields.items():
        if (keep is not None and name not in keep) or (spec.optional and not draw(st.booleans())):
            continue
        shape = (n, *(w for w in spec.shape or ()))  # flat kinds: no open sizes
        data[name] = draw(_values(np.dtype(spec.dtype), shape, finite=poses))
    if poses:
        q = draw(hnp.arrays(np.float64, (n, 4), elements=st.floats(-1, 1)))
        q[np.linalg.norm(q, axis=1) < 0.1] = (0, 0, 0, 1)
        data["orientation"] = q / np.linalg.norm(q, axis=1)[:, None]
    if extras:
        data["code"] = draw(hnp.arrays(np.int16, (n, 2)))
        data["score"] = draw(_values(np.dtype(np.float32), (n,), finite=False))
    end = int(t[-1]) + 1 if n else base + 1
    return cls(t, t_start=base, t_end=end, **data)


def splits(pkt: SamplePacket, cuts: list[int]) -> list[SamplePacket]:
    """The packet as consecutive pieces, cut at the given sample counts (a
    timestamp is never split; empty pieces included)."""
    out = []
    lo = pkt.t_start
    for c in sorted(set(cuts)):
        if not 0 < c < len(pkt) or pkt.t[c] == pkt.t[c - 1]:
            continue
        hi = int(pkt.t[c])
        out.append(pkt.slice_time(lo, hi))
        lo = hi
    out.append(pkt.slice_time(lo, pkt.t_end))
    return out  # type: ignore[return-value]
