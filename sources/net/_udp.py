"""The UDP receiver: one sender at a time, identified by its address and
session. The first datagram from which a fresh :class:`~._wire.Receiver`
accepts something (a HELLO, SAMPLES or END) makes its address and session
the sender; while it is live every other datagram is dropped and counted
(``dropped_other_sender``): a spoofed END or HELLO from elsewhere changes
nothing. A sender silent for ``timeout_s`` s has gone (its stream ends
there); one that sent END counts towards ``senders``. A spoofer that forges
both the sender's address and its session number is not told apart (UDP
has nothing to bind a secret to).
"""

from __future__ import annotations

import math
import struct

import trio

from ._session import Run, log
from ._wire import HEADER, Receiver

__all__ = ["serve_udp"]


async def serve_udp(run: Run, sock: trio.socket.SocketType) -> None:
    """Receive datagrams (until cancelled)."""
    u = _Udp(run)
    try:
        while True:
            await u.step(sock)
    finally:
        if u.recv is not None:  # cancelled with a sender live: what it held back goes out
            with trio.CancelScope(shield=True):
                await u.gone(False)


class _Udp:
    """The UDP receiver's state: the live sender (address, session), its receiver."""

    def __init__(self, run: Run) -> None:
        self.run = run
        self.owner: tuple[object, int] | None = None
        self.recv: Receiver | None = None
        self.heard = 0.0
        self.ended: set[tuple[object, int]] = set()
        self.sid = 0

    async def step(self, sock: trio.socket.SocketType) -> None:
        run = self.run
        wait = self.heard + run.policy.timeout_s if self.recv is not None else math.inf
        data: bytes | None = None
        with trio.move_on_at(wait):
            data, addr = await sock.recvfrom(65536)
        if data is None:  # the sender has gone silent
            run.counters["dropped_timeout"] += 1
            await self.gone(False)
            return
        key = (addr, struct.unpack_from("<I", data, 4)[0] if len(data) >= HEADER else -1)
        if self.recv is None:
            if key in self.ended:
                run.counters["late"] += 1
                return
            recv = run.receiver()
            pkts = recv.feed(data)
            if not recv.accepted and not recv.ended:
                run.retire(recv)
                return
            self.owner, self.recv, self.sid = key, recv, self.sid + 1
            run.arrived()
            run.merger.join(self.sid)
            log.info("udp: sender %s session %08x", addr, key[1])
        elif key != self.owner:
            run.counters["dropped_other_sender"] += 1
            return
        else:
            pkts = self.recv.feed(data)
        self.heard = trio.current_time()
        if not await run.emit(self.sid, pkts):
            run.counters["dropped_schema_mismatch"] += 1
            self.ended.add(key)  # refused for good
            await self.gone(False)
        elif self.recv.ended:
            await self.gone(True)

    async def gone(self, finished: bool) -> None:
        """The sender has finished (END), gone silent or been refused."""
        assert self.recv is not None and self.owner is not None
        await self.run.emit(self.sid, self.recv.flush())
        await self.run.leave(self.sid)
        self.run.departed(finished)
        self.run.retire(self.recv)
        if finished:
            self.ended.add(self.owner)  # its repeated ENDs are late, not a new sender
        self.owner = self.recv = None
