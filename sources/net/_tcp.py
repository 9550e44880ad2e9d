"""The TCP receiver: every connection served on its own task, with its own
:class:`~._wire.Receiver` (so its sensor, columns, sequence numbers and time
are its own), a deadline per message and admission as a sender.

A connection becomes a *sender* when its first message (after AUTH, when a
secret is set) is valid: a HELLO, a SAMPLES or an END. Anything else first,
a message late by ``timeout_s``, or a length above ``max_message`` closes it
(counted by reason in ``dropped_<reason>``). One sender at a time unless
``merge``: later ones wait unread (TCP holds their data back) and are logged;
when the sender leaves without END its place is kept ``reconnect_s`` s for
its session to come back. Connections above ``max_connections`` are closed
at once (``dropped_busy``).
"""

from __future__ import annotations

import struct
from collections import deque

import trio

from ._auth import challenge, check
from ._session import Run, log
from ._wire import HEADER

__all__ = ["serve_tcp"]


class _Reader:
    """Length-prefixed messages from a stream, each within a deadline."""

    def __init__(self, stream: trio.SocketStream, timeout_s: float) -> None:
        self.stream, self.timeout_s = stream, timeout_s
        self.buf = bytearray()

    async def next(self, limit: int) -> bytes | str:
        """The next message, or why there is none: ``closed``, ``timeout``
        (not whole within ``timeout_s`` s), ``length`` (above ``limit`` or
        under 4 bytes)."""
        with trio.move_on_after(self.timeout_s):
            while True:
                if len(self.buf) >= 4:
                    n = int.from_bytes(self.buf[:4], "little")
                    if not 4 <= n <= limit:
                        return "length"
                    if len(self.buf) >= 4 + n:
                        msg = bytes(self.buf[4:4 + n])
                        del self.buf[:4 + n]
                        return msg
                try:
                    chunk = await self.stream.receive_some(1 << 20)
                except (trio.BrokenResourceError, OSError):
                    chunk = b""
                if not chunk:
                    return "closed"
                self.buf += chunk
        return "timeout"


class _Slot:
    """One sender at a time: the others queue (``merge=False``)."""

    def __init__(self, run: Run) -> None:
        self.run = run
        self.owner: int | None = None
        self.kept_for: int | None = None  # a session whose sender may come back
        self.queue: deque[tuple[int, trio.Event]] = deque()

    async def take(self, cid: int, session: int, peer: str) -> None:
        if self.owner is None and (self.kept_for is None or self.kept_for == session):
            self.owner, self.kept_for = cid, None
            return
        log.warning("tcp: sender %s waits: one sender per run (merge=true to merge senders)", peer)
        self.run.counters["queued"] += 1
        turn = trio.Event()
        self.queue.append((cid, turn))
        try:
            await turn.wait()
        except BaseException:
            self.queue = deque(q for q in self.queue if q[0] != cid)
            if self.owner == cid:
                self.owner = None
                self.next()
            raise

    def release(self, cid: int, session: int, finished: bool, nursery: trio.Nursery) -> None:
        if self.owner != cid:
            return
        self.owner = None
        if finished or not self.run.policy.reconnect_s:
            self.next()
            return
        self.kept_for = session
        nursery.start_soon(self._expire, session)

    async def _expire(self, session: int) -> None:
        await trio.sleep(self.run.policy.reconnect_s)
        if self.kept_for == session:
            self.kept_for = None
            if self.owner is None:
                self.next()

    def next(self) -> None:
        if self.queue and self.owner is None:
            cid, turn = self.queue.popleft()
            self.owner = cid
            turn.set()


async def serve_tcp(run: Run, listener: trio.SocketListener) -> None:
    """Accept and serve connections (until cancelled)."""
    slot = _Slot(run)
    open_now = 0
    ids = iter(range(1 << 62))

    async def serve(stream: trio.SocketStream, nursery: trio.Nursery) -> None:
        nonlocal open_now
        cid = next(ids)
        try:
            async with stream:
                await _connection(run, slot, stream, cid, nursery)
        finally:
            open_now -= 1

    async with trio.open_nursery() as nursery:
        while True:
            stream = await listener.accept()
            run.counters["connections"] += 1
            if open_now >= run.policy.max_connections:
                run.counters["dropped_busy"] += 1
                run.counters["dropped_connections"] += 1
                await stream.aclose()
                continue
            open_now += 1
            nursery.start_soon(serve, stream, nursery)


def _peer(stream: trio.SocketStream) -> str:
    try:
        host, port = stream.socket.getpeername()[:2]
        return f"{host}:{port}"
    except OSError:
        return "?"


async def _connection(run: Run, slot: _Slot, stream: trio.SocketStream, cid: int, nursery: trio.Nursery) -> None:
    pol = run.policy
    peer = _peer(stream)
    reader = _Reader(stream, pol.timeout_s)
    if pol.secret:
        nonce, msg = challenge()
        with trio.move_on_after(pol.timeout_s):
            try:
                await stream.send_all(len(msg).to_bytes(4, "little") + msg)
            except (trio.BrokenResourceError, OSError):
                pass
        got = await reader.next(HEADER + 64)
        if isinstance(got, str) or not check(pol.secret, nonce, got):
            _drop(run, "auth" if not isinstance(got, str) else got, peer)
            return
    first = await reader.next(pol.max_message)
    if isinstance(first, str):
        _drop(run, first, peer)
        return
    recv = run.receiver()
    pkts = recv.feed(first)
    if not recv.accepted and not recv.ended:
        run.retire(recv)
        _drop(run, "first_message", peer)
        return
    session = struct.unpack_from("<I", first, 4)[0]
    run.arrived()
    finished = admitted = False
    try:
        if not pol.merge:
            await slot.take(cid, session, peer)
        run.merger.join(cid)
        admitted = True
        log.info("tcp: sender %s connected", peer)
        ok = await run.emit(cid, pkts)
        while ok and not recv.ended:
            got = await reader.next(pol.max_message)
            if isinstance(got, str):
                _drop(run, got, peer)
                break
            ok = await run.emit(cid, recv.feed(got))
        if not ok:
            _drop(run, "schema_mismatch", peer)
        finished = recv.ended
    finally:
        if admitted:
            with trio.CancelScope(shield=True):
                await run.emit(cid, recv.flush())  # what it held back at its last timestamp
                await run.leave(cid)
        slot.release(cid, session, finished, nursery)
        run.departed(finished)
        run.retire(recv)


def _drop(run: Run, why: str, peer: str) -> None:
    run.counters[f"dropped_{why}"] += 1
    run.counters["dropped_connections"] += 1
    log.info("tcp: connection from %s dropped (%s)", peer, why)
