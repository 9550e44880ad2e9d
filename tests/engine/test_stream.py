"""Stream operations: interleaving a source's streams in time."""

from __future__ import annotations

import numpy as np

from tectum import EventPacket, ImuPacket, interleave
from tectum.testing import assert_stream_contract


def _events(t0, t1):
    t = np.arange(t0, t1, 10, dtype=np.int64)
    z = np.zeros(len(t), np.uint16)
    return EventPacket(t, z, z, np.ones(len(t), np.int8), sensor=(4, 4), t_start=t0, t_end=t1)


def test_interleave_puts_each_stream_up_to_the_events_end_before_them():
    ev = [_events(0, 100), _events(100, 250), _events(250, 300)]
    t = np.arange(5, 400, 40, dtype=np.int64)
    imu = ImuPacket(t, accel=np.zeros((len(t), 3)), gyro=np.zeros((len(t), 3)), t_start=0, t_end=400)
    out = list(interleave(ev, [iter([imu])]))
    imu_out = [q for q in out if isinstance(q, ImuPacket)]
    assert_stream_contract(imu_out)
    assert np.array_equal(np.concatenate([q.t for q in imu_out]), t)
    assert imu_out[-1].t_end == 400
    seen = -1
    for q in out:  # when an events packet comes, the IMU has reached its end
        if isinstance(q, ImuPacket):
            seen = q.t_end
        else:
            assert seen >= q.t_end


def test_interleave_pulls_lazily():
    pulled = []

    def frames():
        for k in range(3):
            pulled.append(k)
            yield ImuPacket([k * 100], accel=[[0, 0, 0]], gyro=[[0, 0, 0]], t_start=k * 100, t_end=k * 100 + 100)

    it = interleave([_events(0, 50), _events(50, 120)], [frames()])
    next(it)  # the first IMU piece [0, 50)
    assert pulled == [0]
