"""``tcp://HOST:PORT`` and ``udp://HOST:PORT`` sources: receive the event
(and IMU, frame, pose, trigger) streams tectum network sinks send (framing
in :mod:`._wire`).

The receiver listens until the user's condition is met: ``senders`` senders
have finished with END (default 1; 0: no count), no sender has been
connected for ``idle_s`` s (0: no limit), or Ctrl-C. Ctrl-C ends the stream
as the condition would: everything received goes out and the sinks close
normally (a file keeps it all), and the run reports ``interrupted`` (the CLI
then exits with 130). Connections that are not senders change nothing:
a connect and close, garbage, a half message, a peer too slow or silent.

Each connection (UDP: each sender) has its own sensor size, columns,
sequence numbers and time; what one peer sends cannot reject, delay or end
another's stream. Every message must arrive whole within ``timeout_s`` s of
the previous one (the first, of the connection), or the connection is
closed; memory is bounded by ``max_connections`` x ``max_message`` bytes
plus what the merge holds (:mod:`._merge`).

How senders make one stream: by default **one sender per run** (what a user
sending one recording expects): the first connection whose first message is
valid is the sender; later ones wait unread (their data stay in TCP's
buffers), with a log line, and are served in turn once the sender has
finished, when ``senders`` > 1 (the output never goes back in time: a later
sender's data before what was released are dropped, counted as ``behind``).
A sender that drops without END keeps its place ``reconnect_s`` s for its
session to come back (a tectum sink reconnects and resends). ``merge=true``
serves every sender at once and merges their streams by time with a
watermark (released up to the least time every live sender has passed;
they must share sensor size and columns). UDP is always one sender at a
time (:mod:`._udp`).

``secret`` (or the ``TECTUM_NET_SECRET`` environment variable, which keeps
it out of process listings) admits only TCP senders that prove they hold it
(HMAC over a fresh nonce, :mod:`._auth` says what that protects and what
not). Without it, any peer that speaks the protocol first is the sender.

Counters (``--stats``): ``accepted`` messages, ``events``, ``samples``,
``lost``, ``late``, ``rejected_<reason>`` (bad messages of a sender),
``connections``, ``senders``, ``finished``, ``queued``,
``dropped_connections`` with ``dropped_<reason>`` (``closed``, ``timeout``,
``length``, ``first_message``, ``auth``, ``busy``, ``schema_mismatch``,
``other_sender``), ``behind``, ``forced`` and ``interrupted``.
"""

from __future__ import annotations

import threading
from collections.abc import AsyncIterator

import trio

from tectum import Kind, Packet, Source

from ._addr import parse
from ._auth import secret_of
from ._session import Policy, Run
from ._tcp import serve_tcp
from ._udp import serve_udp

__all__ = ["NetSource"]


class NetSource(Source):
    """Events from the network (see the module docstring).

    Parameters (units): ``senders`` count of senders whose END ends the run
    (0: no count); ``idle_s`` seconds without a connected sender that end
    it (0: wait forever); ``merge`` serve senders at once, merged by time
    (TCP); ``timeout_s`` seconds within which each message must arrive;
    ``reconnect_s`` seconds a dropped sender's place is kept; ``secret`` the
    shared secret a TCP sender must prove (default: ``TECTUM_NET_SECRET``);
    ``max_message`` largest message in bytes; ``max_connections`` open at
    once. ``port`` 0 picks a free port (read :attr:`port` once :attr:`ready`).
    """

    name = "net"
    schemes = ("tcp", "udp")
    produces = (Kind.EVENTS, Kind.IMU, Kind.FRAMES, Kind.POSES, Kind.TRIGGERS)

    def __init__(self, url: str, idle_s: float = 0.0, senders: int = 1, merge: bool = False,
                 timeout_s: float = 10.0, reconnect_s: float = 2.0, secret: str = "", max_message: int = 1 << 23,
                 max_connections: int = 8, rcvbuf: int = 1 << 22) -> None:
        self.scheme, self.host, self.port = parse(url)
        if idle_s < 0 or reconnect_s < 0 or not timeout_s > 0 or senders < 0 or max_connections < 1:
            raise ValueError(f"{url!r}: need idle_s >= 0, reconnect_s >= 0, timeout_s > 0, senders >= 0, "
                             "max_connections >= 1")
        if not 1024 <= max_message <= 1 << 30:
            raise ValueError(f"{url!r}: max_message must lie within 1 KiB .. 1 GiB, not {max_message}")
        key = secret_of(secret)
        if key and self.scheme == "udp":
            raise ValueError(f"{url!r}: a secret needs tcp:// (UDP datagrams cannot be bound to a handshake)")
        self.policy = Policy(idle_s=idle_s, senders=senders, merge=merge, timeout_s=timeout_s,
                             reconnect_s=reconnect_s, max_message=max_message, max_connections=max_connections,
                             secret=key)
        self.rcvbuf = rcvbuf
        self.ready = threading.Event()
        self._run: Run | None = None
        self._error: BaseException | None = None

    @property
    def counts(self) -> dict[str, int]:  # type: ignore[override]  # read-only: derived from the run
        """Integer counters (the run's stats show them; see the module docstring)."""
        return self._run.counts() if self._run is not None else {}

    @property
    def interrupted(self) -> bool:
        """True when Ctrl-C ended the run."""
        return self._run is not None and self._run.interrupted

    async def apackets(self) -> AsyncIterator[Packet]:
        send, receive = trio.open_memory_channel[Packet](8)
        self._run = Run(self.policy, send)
        done = trio.Event()
        trio.lowlevel.spawn_system_task(self._serve, self._run, done)
        try:
            async with receive:
                async for pkt in receive:
                    yield pkt
        finally:
            self._run.done.set()
            with trio.CancelScope(shield=True):
                await done.wait()
        if self._error is not None:
            raise self._error

    async def _serve(self, run: Run, done: trio.Event) -> None:
        """Serve until the run's condition, then flush and close the output.
        A system task (the source's generator holds no nursery across its
        yields); its error is handed to the generator."""
        try:
            async with run.out:
                async with trio.open_nursery() as nursery:
                    nursery.start_soon(self._listen, run)
                    nursery.start_soon(run.watch_idle)
                    nursery.start_soon(run.watch_interrupt)
                    await run.done.wait()
                    nursery.cancel_scope.cancel()
                await run.flush()
        except Exception as e:
            self._error = e
        finally:
            self.ready.set()  # never leave a waiter hanging
            done.set()

    async def _listen(self, run: Run) -> None:
        if self.scheme == "udp":
            sock = trio.socket.socket(trio.socket.AF_INET, trio.socket.SOCK_DGRAM)
            with sock:
                sock.setsockopt(trio.socket.SOL_SOCKET, trio.socket.SO_RCVBUF, self.rcvbuf)
                await sock.bind((self.host, self.port))
                self.port = sock.getsockname()[1]
                self.ready.set()
                await serve_udp(run, sock)
            return
        listeners = await trio.open_tcp_listeners(self.port, host=self.host)
        try:
            self.port = listeners[0].socket.getsockname()[1]
            self.ready.set()
            await serve_tcp(run, listeners[0])
        finally:
            for item in listeners:
                await item.aclose()
