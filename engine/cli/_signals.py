"""Interrupts of the command line: SIGTERM is handled like SIGINT (Ctrl-C),
an interrupted command leaves no temporary files and exits with 128 + the
signal's number (130 for SIGINT, 143 for SIGTERM), after one line on stderr.

Python raises :class:`KeyboardInterrupt` wherever the main thread happens
to be; inside a library's weak-reference callback or ``__del__`` (h5py has
both) it is printed as "Exception ignored" and lost, and the command went
on to write a complete file and exit 0. So the commands that write files
take the signal as a request instead, acted on at a safe point:

* ``tectum run``, ``simulate`` and ``demo``: :func:`run_until_signal`
  receives the signals in a trio task (listening before any sink opens) and
  cancels the pipeline, whose sinks then abort (their temporary
  files and folders are removed: the output is absent, never truncated);
* ``tectum convert``: inside :func:`deferred` a signal sets a flag that the
  packet loop checks (a second signal raises at once, for a stuck source).

Everywhere else SIGTERM calls the current SIGINT handler (Python's, or
trio's during a run, which delivers it safely into the run).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

__all__ = ["received", "exit_status", "term_like_int", "deferred", "run_until_signal"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_received: list[int] = []  # signals received by this command, in order


def received() -> int | None:
    """The first interrupting signal this command received, if any."""
    return _received[0] if _received else None


def exit_status() -> int:
    """128 + the interrupting signal's number (130 when it was Ctrl-C)."""
    return 128 + (received() or signal.SIGINT)


def _name(signum: int) -> str:
    return signal.Signals(signum).name


def _forward(signum: int, frame: FrameType | None) -> None:
    _received.append(signum)
    handler = signal.getsignal(signal.SIGINT)
    if callable(handler) and handler is not _forward:
        handler(signal.SIGINT, frame)
    else:
        raise KeyboardInterrupt


@contextmanager
def term_like_int() -> Iterator[None]:
    """SIGTERM behaves as SIGINT while inside (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGTERM, _forward)
    _received.clear()
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


@contextmanager
def deferred() -> Iterator[Callable[[], None]]:
    """While inside, SIGINT and SIGTERM only ask to stop: yields ``check()``,
    which raises :class:`KeyboardInterrupt` once one came. A second signal
    raises at once. Main thread only (elsewhere ``check`` never raises)."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    count = len(_received)

    def handler(signum: int, frame: FrameType | None) -> None:
        _received.append(signum)
        if len(_received) > count + 1:
            raise KeyboardInterrupt

    def check() -> None:
        if len(_received) > count:
            raise KeyboardInterrupt

    old = {s: signal.signal(s, handler) for s in _SIGNALS}
    try:
        yield check
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def run_until_signal(plan: Any) -> Any:
    """``tectum.run(plan)``, cancelled by SIGINT or SIGTERM (then its sinks
    abort and :class:`KeyboardInterrupt` is raised here). A source that
    takes SIGINT itself (a network receiver ending its stream with what it
    received) also gets SIGTERM as SIGINT. Returns the run's stats."""
    import trio

    from tectum._scheduler import _unwrap, arun

    stats: list[Any] = []

    async def watch(cancel: trio.CancelScope, task_status: Any = trio.TASK_STATUS_IGNORED) -> None:
        with trio.open_signal_receiver(*_SIGNALS) as signals:
            ours = signal.getsignal(signal.SIGINT)
            task_status.started()
            async for signum in signals:
                _received.append(signum)
                if signum == signal.SIGTERM and signal.getsignal(signal.SIGINT) is not ours:
                    signal.raise_signal(signal.SIGINT)  # a source listens for SIGINT: it decides
                    continue
                cancel.cancel()
                return

    async def main() -> None:
        async with trio.open_nursery() as nursery:
            if threading.current_thread() is threading.main_thread():
                await nursery.start(watch, nursery.cancel_scope)  # listening before any sink opens
            stats.append(await arun(plan))
            nursery.cancel_scope.cancel()

    try:
        trio.run(main)
    except BaseExceptionGroup as group:  # the run's error, as tectum.run raises it (not in a group)
        rest = group.split(KeyboardInterrupt)[1]
        if rest is None:  # a signal in the instant before the receiver was up
            raise KeyboardInterrupt(_name(received() or signal.SIGINT)) from None
        err = _unwrap(rest)  # the failing node's error, as tectum.run raises it
        if err is rest:
            raise
        err.__suppress_context__ = True
        raise err from err.__cause__
    if not stats:
        raise KeyboardInterrupt(_name(received() or signal.SIGINT))
    return stats[0]
