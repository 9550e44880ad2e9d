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

import struct

import trio

from ._session import Run, log
from ._wire import HEADER, Receiver

__all__ = ["serve_udp"]


async def serve_udp(run: Run, sock: trio.socket.SocketType) -> None:
    """Receive datagrams (until cancelled)."""
    pol = run.policy
    owner: tuple[object, int] | None = None
    recv: Receiver | None = None
    heard = 0.0
    ended: set[tuple[object, int]] = set()
    sid = 0
    while True:
        wait = heard + pol.timeout_s if owner is not None else trio.current_time() + 3600.0
        data: bytes | None = None
        with trio.move_on_at(wait):
            data, addr = await sock.recvfrom(65536)
        if data is None:  # the sender has gone silent
            run.counters["dropped_timeout"] += 1
            await run.leave(sid)
            run.departed(False)
            if recv is not None:
                run.retire(recv)
            owner = recv = None
            continue
        key = (addr, struct.unpack_from("<I", data, 4)[0] if len(data) >= HEADER else -1)
        if owner is None:
            if key in ended:
                run.counters["late"] += 1
                continue
            recv = run.receiver()
            pkts = recv.feed(data)
            if not recv.accepted and not recv.ended:
                run.retire(recv)
                continue
            owner, sid = key, sid + 1
            run.arrived()
            run.merger.join(sid)
            log.info("udp: sender %s session %08x", addr, key[1])
        elif key != owner:
            run.counters["dropped_other_sender"] += 1
            continue
        else:
            assert recv is not None
            pkts = recv.feed(data)
        heard = trio.current_time()
        fits = await run.emit(sid, pkts)
        if not fits:
            run.counters["dropped_schema_mismatch"] += 1
        if recv.ended or not fits:
            ended.add(owner)
            await run.leave(sid)
            run.departed(recv.ended)
            run.retire(recv)
            owner = recv = None
