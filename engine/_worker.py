"""A thread of its own for one offloaded operator: the scheduler's hand-over
of each batch of packets to it, and of the results back to trio, with as
little Python in between as can be."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, TypeVar

import outcome
import trio

__all__ = ["NodeThread"]

T = TypeVar("T")


def _no_abort(_raise_cancel: Any) -> trio.lowlevel.Abort:
    return trio.lowlevel.Abort.FAILED  # a call under way runs to its end (as trio.to_thread's default)


class NodeThread:
    """One worker thread that runs an offloaded node's calls, one at a time,
    while the calling trio task waits (:meth:`call`).

    ``trio.to_thread.run_sync`` does the same through trio's thread cache
    and a capacity limiter; per call the worker thread then holds the GIL
    for its dispatch (a context copy, the limiter, the cache's loop: tens of
    µs, measured by the offload helper), and it holds the GIL exactly when it
    wakes up from the operator's GIL-free work, which is when the trio thread
    may be about to release a paced window. Here the worker wakes from a
    lock, calls, and queues its result with one ``run_sync_soon``.

    A call under way is not abandoned when the task is cancelled: the
    cancellation takes effect once the call returns. The thread ends at
    :meth:`close` (a daemon: it never holds up the interpreter's exit).
    Unlike trio's workers it runs without trio's thread-local token, so an
    operator cannot ``trio.from_thread.run`` from it (none does)."""

    def __init__(self, name: str) -> None:
        self._go = threading.Lock()
        self._go.acquire()  # released once per job (a binary semaphore)
        self._job: tuple[Callable[..., Any], Any, Any, trio.lowlevel.TrioToken] | None = None
        self._closed = False
        self.thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self.thread.start()

    async def call(self, fn: Callable[[Any], T], arg: Any) -> T:
        """``fn(arg)`` in the thread; its result, or its exception raised here."""
        await trio.lowlevel.checkpoint_if_cancelled()
        if self._closed:
            raise RuntimeError("NodeThread is closed")
        self._job = (fn, arg, trio.lowlevel.current_task(), trio.lowlevel.current_trio_token())
        self._go.release()
        result: T = await trio.lowlevel.wait_task_rescheduled(_no_abort)
        return result

    def close(self) -> None:
        """End the thread (after the call under way, if any)."""
        if not self._closed:
            self._closed = True
            self._job = None  # (no call is under way: its task waits in call(), not here)
            self._go.release()

    def _loop(self) -> None:
        go, reschedule = self._go, trio.lowlevel.reschedule
        while True:
            go.acquire()  # lets go of the GIL while it waits
            job = self._job
            if job is None:
                return
            fn, arg, task, token = job
            result = outcome.capture(fn, arg)
            token.run_sync_soon(reschedule, task, result)
