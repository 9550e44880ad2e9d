"""An offloaded operator runs in a thread of its own (named after its node),
every call of a run in that one thread, which ends with the run: when the
run ends, fails, or is cancelled while a call is under way (the call runs
to its end first)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import tectum
from tectum import EventPacket, Operator, Pipeline
from tectum.testing import ListSink, ListSource


def _events(n: int, dt_us: int = 1) -> EventPacket:
    t = np.arange(n, dtype=np.int64) * dt_us
    z = np.zeros(n, np.uint16)
    return EventPacket(t, z, z, np.ones(n, np.int8), sensor=(4, 4), t_start=0, t_end=int(t[-1]) + 1)


class Where(Operator):
    """Notes the thread of each call; ``fail_at``: raise at that call; ``sleep_s`` a call."""

    name = "filter.where_test"

    def __init__(self, fail_at: int = -1, sleep_s: float = 0.0) -> None:
        self.threads: list[threading.Thread] = []
        self.fail_at, self.sleep_s = fail_at, sleep_s
        self.returned = 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        self.threads.append(threading.current_thread())
        if len(self.threads) == self.fail_at:
            raise ValueError("boom")
        time.sleep(self.sleep_s)
        self.returned += 1
        return [packet]

    def finish(self) -> list[EventPacket]:
        self.threads.append(threading.current_thread())
        return []


def _ended(threads: list[threading.Thread]) -> bool:
    for t in set(threads):
        t.join(2.0)  # the thread ends right after the run hands it its end
    return not any(t.is_alive() for t in threads)


def test_each_offloaded_operator_runs_in_a_thread_of_its_own_that_ends_with_the_run() -> None:
    a, b = Where(), Where()
    p = Pipeline(max_events=10)
    src = p.source(ListSource([_events(100)]), id="src")
    p.sink(ListSink(), p.op(a, src, id="a", offload=True))
    p.sink(ListSink(), p.op(b, src, id="b", offload=True))
    tectum.run(p)
    assert len(a.threads) == 11 and len(b.threads) == 11  # 10 packets and finish()
    assert {t.name for t in a.threads} == {"tectum-offload-a"} and {t.name for t in b.threads} == {"tectum-offload-b"}
    assert len({t.ident for t in a.threads}) == 1 and a.threads[0] is not b.threads[0]
    assert threading.main_thread() not in a.threads
    assert _ended(a.threads + b.threads)


def test_an_error_in_the_thread_is_the_node_s_and_the_thread_ends() -> None:
    op = Where(fail_at=3)
    p = Pipeline(max_events=10)
    p.sink(ListSink(), p.op(op, p.source(ListSource([_events(100)]), id="src"), id="w", offload=True))
    with pytest.raises(tectum.NodeError, match="boom") as e:
        tectum.run(p)
    assert e.value.node == "w"
    assert _ended(op.threads)


class FailsOnceStarted(Operator):
    """Fails (inline, beside an offloaded :class:`Where`) once that one has begun a call."""

    name = "filter.fails_test"

    def __init__(self, other: Where) -> None:
        self.other = other

    def process(self, packet: EventPacket) -> list[EventPacket]:
        if self.other.threads:
            raise RuntimeError("inline failure")
        return [packet]


def test_a_run_cancelled_during_a_call_waits_for_it_and_the_thread_ends() -> None:
    slow = Where(sleep_s=0.05)
    p = Pipeline(pace=1.0, max_latency_us=1000)  # a window a ms: the source yields between them
    src = p.source(ListSource([_events(40, 1000)]), id="src")
    p.sink(ListSink(), p.op(slow, src, id="slow", offload=True))
    p.sink(ListSink(), p.op(FailsOnceStarted(slow), src, id="bad"))
    with pytest.raises(tectum.NodeError, match="inline failure"):
        tectum.run(p)
    assert slow.returned == len(slow.threads) >= 1  # each call it began ran to its end
    assert _ended(slow.threads)
