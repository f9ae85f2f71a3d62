"""A plugin's calls run on a thread of its own and waited for a bounded time: a call that never returns
(a step blocked on an ``Event``, a socket read with no timeout) ends what called it with a
:class:`~hil.plugins.PluginTimeout` instead of hanging it. The run's layers install it
(:meth:`hil.estimation.checked.CheckedEstimator.run_calls_with`, :mod:`hil.link.sources.checked`); the
estimation package itself starts no thread and reads no clock."""

from __future__ import annotations

import itertools
import queue
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any, TypeVar

from hil.plugins import PluginTimeout

T = TypeVar("T")

WAIT_SLICE_S = 0.05
"""s: how long a :class:`PluginWorker`'s caller waits at a time for its call, so that Ctrl-C, SIGTERM and a
campaign's :class:`~protocol.errors.RunHung` (an exception set into the waiting thread, which is only
raised between bytecodes) land within a slice, not at the end of the whole bound."""

ABANDONED: list[str] = []
"""Every :class:`PluginWorker` thread that never returned from a call (``"estimator 'mine': step at t =
3.2 s"``), in this process: left running as daemons (Python cannot stop a thread blocked in C), counted
here so that a process running many runs (a campaign's worker) can say how many it carries."""


class _Job:
    """One call handed to a :class:`PluginWorker`'s thread, and what it returned or raised."""

    __slots__ = ("call", "done", "result", "error")

    def __init__(self, call: Callable[[], Any]) -> None:
        self.call = call
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None


def _serve(jobs: queue.SimpleQueue[_Job | None]) -> None:
    """A :class:`PluginWorker`'s thread: each job run in turn, until a None (its worker was collected)."""
    while (job := jobs.get()) is not None:
        try:
            job.result = job.call()
        except BaseException as exc:  # handed to the caller's thread, raised there as the plugin's
            job.error = exc
        finally:
            job.done.set()
        del job


class PluginWorker:
    """A plugin's calls, each run on one thread of its own (a daemon, started on the first call) and waited
    for a bounded time: a call that does not return within ``bound_s`` raises :class:`PluginTimeout`
    naming ``plugin``, ``what`` and the bound — a step that blocked forever (an ``Event().wait()``, a
    socket read without a timeout) hung ``hil run`` until it was killed, its board never disarmed by the
    host. A thread blocked in C cannot be stopped: it is left behind, a daemon (it does not keep the
    process alive), named after the call and counted in :data:`ABANDONED`; every later call raises at
    once (the plugin is still inside the call that never returned). The plugin's own exception (a
    SystemExit too) is raised as it is in the caller's thread, for :func:`call_plugin` to word. Costs a
    handover between two threads a call (~20-50 µs): for plugins only, never the host's own hot path."""

    _numbers = itertools.count(1)

    def __init__(self, plugin: str) -> None:
        self.plugin = plugin
        self.stuck: str | None = None
        """The call that never returned (its ``what``), or None."""
        self._jobs: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        weakref.finalize(self, self._jobs.put, None)  # its thread ends with it (it holds only the queue)

    def call(self, what: str, call: Callable[[], T], bound_s: float) -> T:
        """``call()`` on the worker's thread, waited for at most ``bound_s`` (s, wall time)."""
        if self.stuck is not None:
            raise PluginTimeout(self.plugin, f"{what}: not called, its {self.stuck} never returned")
        if self._thread is None:
            self._thread = threading.Thread(
                target=_serve, args=(self._jobs,), name=f"plugin-{next(self._numbers)}", daemon=True
            )
            self._thread.start()
        job = _Job(call)
        self._jobs.put(job)
        deadline = time.monotonic() + bound_s
        while not job.done.wait(min(WAIT_SLICE_S, max(deadline - time.monotonic(), 0.0))):
            if time.monotonic() >= deadline:
                self.stuck = what
                self._thread.name = f"{self.plugin}: stuck in {what}"
                ABANDONED.append(f"{self.plugin}: {what}")
                raise PluginTimeout(
                    self.plugin,
                    f"{what} did not return within {bound_s:.3g} s (its thread left running as a "
                    f"daemon: {len(ABANDONED)} so in this process)",
                )
        if job.error is not None:
            error, job.error = job.error, None
            raise error
        return job.result  # type: ignore[no-any-return]
