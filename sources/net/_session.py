"""What the TCP and UDP receivers share: the run's parameters, its counters,
the merge of its senders' streams and the condition that ends it."""

from __future__ import annotations

import logging
import math
import signal
import threading
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass

import trio

from tectum import Packet

from ._merge import Merger
from ._wire import Receiver

__all__ = ["Policy", "Run", "log"]

log = logging.getLogger("tectum.net")


@dataclass(frozen=True)
class Policy:
    """A network source's parameters (see :class:`~tectum.sources.net.source.NetSource`)."""

    idle_s: float = 0.0
    senders: int = 1
    merge: bool = False
    timeout_s: float = 10.0
    reconnect_s: float = 2.0
    max_message: int = 1 << 23
    max_connections: int = 8
    secret: bytes = b""

    def receiver(self) -> Receiver:
        """A fresh receiver: one per connection (UDP: per sender)."""
        return Receiver(max_events=self.max_message // 9 + 1, max_message=self.max_message)


class Run:
    """One run of a network source: merges the admitted senders' packets
    into the output channel (in order, under a lock), counts, and sets
    :attr:`done` when the user's condition is met (``senders`` ENDs, ``idle_s``
    without a sender, SIGINT)."""

    def __init__(self, policy: Policy, out: trio.MemorySendChannel[Packet]) -> None:
        self.policy = policy
        self.merger = Merger()
        self.counters: Counter[str] = Counter()
        self.receivers: list[Receiver] = []  # live ones; the counts of the others are folded
        self._folded: Counter[str] = Counter()
        self.done = trio.Event()
        self.interrupted = False
        self.out = out
        self._lock = trio.Lock()
        self._present = 0  # senders connected (admitted or queued)
        self._empty_since = trio.current_time()
        self._changed = trio.Event()

    # -- output ---------------------------------------------------------------
    async def emit(self, sid: int, pkts: Iterable[Packet]) -> bool:
        """Add sender ``sid``'s packets and send what the merge releases;
        False when events of another sensor or columns than the stream's
        came (nothing of them added)."""
        m, ok = self.merger, True
        async with self._lock:
            for p in pkts:
                q = m.through(sid, p)
                ok = ok and not m.refused
                if q is not None:
                    await self._send([q])
            await self._send(m.release())
        return ok

    async def _send(self, pkts: list[Packet]) -> None:
        try:
            for q in pkts:
                await self.out.send(q)
        except (trio.BrokenResourceError, trio.ClosedResourceError):
            self.done.set()  # the pipeline has stopped reading: nothing more to do

    async def leave(self, sid: int) -> None:
        """Sender ``sid`` has gone: it no longer holds the others back."""
        self.merger.leave(sid)
        await self.emit(sid, ())

    async def flush(self) -> None:
        async with self._lock:
            await self._send(self.merger.flush())

    # -- senders and the end condition ------------------------------------------
    def arrived(self) -> None:
        self._present += 1
        self.counters["senders"] += 1
        self._change()

    def departed(self, finished: bool) -> None:
        self._present -= 1
        if self._present == 0:
            self._empty_since = trio.current_time()
        if finished:
            self.counters["finished"] += 1
            if self.policy.senders and self.counters["finished"] >= self.policy.senders:
                self.done.set()
        self._change()

    def _change(self) -> None:
        self._changed.set()
        self._changed = trio.Event()

    async def watch_idle(self) -> None:
        """Set :attr:`done` once no sender has been connected for ``idle_s`` s."""
        if not self.policy.idle_s:
            return
        while True:
            changed = self._changed
            deadline = self._empty_since + self.policy.idle_s if not self._present else math.inf
            with trio.move_on_at(deadline):
                await changed.wait()
                continue
            log.info("no sender for %.3g s: the run ends", self.policy.idle_s)
            self.done.set()
            return

    async def watch_interrupt(self) -> None:
        """Ctrl-C ends the run like its condition would (what was received
        goes out, sinks close normally) and marks it interrupted; only in the
        main thread (elsewhere the signal is not ours)."""
        if threading.current_thread() is not threading.main_thread():
            return
        with trio.open_signal_receiver(signal.SIGINT) as signals:
            async for _ in signals:
                log.warning("interrupted: ending the stream with what was received")
                self.interrupted = True
                self.done.set()
                return

    def receiver(self) -> Receiver:
        """A fresh receiver (one per connection, or UDP sender), counted."""
        r = self.policy.receiver()
        self.receivers.append(r)
        return r

    def retire(self, r: Receiver) -> None:
        """``r`` is done: keep its counts, not it (memory stays bounded)."""
        self.receivers.remove(r)
        _add_counts(self._folded, r)

    def counts(self) -> dict[str, int]:
        """Every receiver's counters summed, and the run's own."""
        out: Counter[str] = Counter(self._folded)
        for r in self.receivers:
            _add_counts(out, r)
        out.update(self.counters)
        out["behind"] = self.merger.behind
        out["forced"] = self.merger.forced
        out["interrupted"] = int(self.interrupted)
        return dict(out)


def _add_counts(out: Counter[str], r: Receiver) -> None:
    for k, v in r.counts().items():
        if isinstance(v, int):
            out[k] += v
    for k, v in r.rejected.items():
        out[f"rejected_{k}"] += v
