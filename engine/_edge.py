"""Bounded edges between tasks, with a policy for when they are full."""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any, Literal

import trio

__all__ = ["Edge"]


class Edge:
    """A bounded FIFO between two trio tasks.

    ``capacity`` is how many items it holds. When full, ``policy`` decides:
    ``block`` makes the sender wait (lossless back-pressure, for files),
    ``keep_latest`` drops the oldest item, ``drop`` drops the new one (both
    for live control, where fresh data beats complete data). Every drop is
    counted in :attr:`drops`. Choose ``capacity`` as the burst you accept to
    queue: for a control loop that wants the newest result, 1 with
    ``keep_latest``.
    """

    def __init__(self, capacity: int, policy: Literal["block", "keep_latest", "drop"] = "block") -> None:
        if capacity < 1:
            raise ValueError("capacity must be >= 1")
        self.capacity = capacity
        self.policy = policy
        self.drops = 0
        self._q: deque[Any] = deque()
        self._closed = False
        self._readers = trio.lowlevel.ParkingLot()
        self._writers = trio.lowlevel.ParkingLot()

    def __len__(self) -> int:
        return len(self._q)

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called (queued items may remain)."""
        return self._closed

    def has_room(self, n: int) -> bool:
        """True when ``n`` items can be sent without waiting."""
        return self.policy != "block" or len(self._q) + n <= self.capacity

    async def send(self, item: Any) -> None:
        """Put an item; may wait (``block``) or drop (other policies)."""
        await self.send_all((item,))

    async def send_all(self, items: Sequence[Any]) -> None:
        """Put several items, in order, each under the policy. No checkpoint
        while there is room: senders yield on their own schedule (see the
        scheduler), so items are handed over in bursts."""
        q, cap = self._q, self.capacity
        for item in items:
            if self._closed:
                raise trio.ClosedResourceError("edge is closed")
            if len(q) >= cap:
                if self.policy == "block":
                    while len(q) >= cap:
                        if self._readers:
                            self._readers.unpark()
                        await self._writers.park()
                        if self._closed:
                            raise trio.ClosedResourceError("edge is closed")
                elif self.policy == "keep_latest":
                    q.popleft()
                    self.drops += 1
                else:
                    self.drops += 1
                    continue
            q.append(item)
        if self._readers:
            self._readers.unpark()

    def put_all(self, items: Sequence[Any]) -> None:
        """Put several items whatever the capacity (a feedback loop's own
        task must never wait on its own edge; see :meth:`wait_room`)."""
        if self._closed:
            raise trio.ClosedResourceError("edge is closed")
        self._q.extend(items)
        if self._readers:
            self._readers.unpark()

    async def wait_room(self) -> None:
        """Wait until the edge holds fewer than ``capacity`` items (or is closed)."""
        while len(self._q) >= self.capacity and not self._closed:
            if self._readers:
                self._readers.unpark()
            await self._writers.park()

    async def receive_all(self) -> list[Any]:
        """Everything queued (waits for at least one item); raises
        :class:`trio.EndOfChannel` once closed and empty."""
        while not self._q:
            if self._closed:
                raise trio.EndOfChannel
            await self._readers.park()
        items = list(self._q)
        self._q.clear()
        if self._writers:
            self._writers.unpark_all()
        return items

    def close(self) -> None:
        """No more items: the receiver drains what is queued, then ends."""
        self._closed = True
        self._readers.unpark_all()
        self._writers.unpark_all()

    async def receive(self) -> Any:
        """The next item; raises :class:`trio.EndOfChannel` once closed and empty."""
        while not self._q:
            if self._closed:
                raise trio.EndOfChannel
            await self._readers.park()
        item = self._q.popleft()
        if self._writers:
            self._writers.unpark()
        return item

    def __aiter__(self) -> Edge:
        return self

    async def __anext__(self) -> Any:
        try:
            return await self.receive()
        except trio.EndOfChannel:
            raise StopAsyncIteration from None
