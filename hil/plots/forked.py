"""Drawing jobs shared among forked processes.

Agg's drawing is pure CPU in one thread (text layout, ticks, rasterising, PNG compression: ~0.07–0.12 s a
figure here), and a run's figures do not depend on one another. After the data is read and matplotlib
imported, a fork inherits both at no cost, so each process draws a share and only the results (the
figures' paths) come back, pickled through a pipe. ``hil run`` waits for its figures after the summary,
with the run's own core idle: two processes halve that wait on two cores.

The shares are not fixed: each process takes the next job not taken yet (a counter the processes share,
behind a lock), so a process whose figures draw fast takes more of them, and the wait ends with the
slowest figure, not the slowest fixed share (a log-scaled figure with its minor ticks costs twice a plain
one: with every other job to each of two processes, one drew ~0.45 s of figures while the other drew ~0.32).

POSIX only (``os.fork``). With one process, where there is no fork, or while another thread of this process
runs, every job runs here: a forked child holds only the forking thread, and a lock another thread held at
the fork (the logging module's, an import's) would stay held in it for ever.
"""

from __future__ import annotations

import mmap
import multiprocessing
import os
import pickle
import threading
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from protocol.errors import HilError

T = TypeVar("T")


class _Counter:
    """The next job's index, shared by forked processes: :meth:`take` hands out 0, 1, 2, ... once each."""

    def __init__(self) -> None:
        self._next = mmap.mmap(-1, 8)  # anonymous and shared: a forked child writes the same page
        self._lock = multiprocessing.get_context("fork").Lock()

    def take(self) -> int:
        with self._lock:
            index = int.from_bytes(self._next[:8], "little")
            self._next[:8] = (index + 1).to_bytes(8, "little")
        return index


def draw_shared(jobs: Sequence[Callable[[], T]], processes: int) -> list[T]:
    """Each job's result, in the jobs' order, the jobs run ``processes`` ways: this process and
    ``processes - 1`` forked ones, each taking the next job not taken yet until none is left. A job's
    exception is raised here as it was raised — the first job's in the jobs' order that raised (a process
    takes no job after one of its own raised; one that cannot be pickled is a :class:`HilError` naming
    it); a child that dies without answering is a :class:`HilError` with its exit status."""
    processes = max(1, min(processes, len(jobs)))
    if processes == 1 or not hasattr(os, "fork") or threading.active_count() > 1:
        return [job() for job in jobs]
    counter = _Counter()
    children = [_fork_share(jobs, counter) for _ in range(1, processes)]
    mine = _take_jobs(jobs, counter)  # the children are reaped before anything is raised
    answers = [_reap(pid, fd) for pid, fd in children]
    results: dict[int, Any] = dict(mine)
    for answer in answers:
        if isinstance(answer, BaseException):
            raise answer
        assert isinstance(answer, dict)  # what _fork_share writes when it is not an error
        results.update(answer)
    for i in sorted(results):
        if isinstance(results[i], _Raised):
            raise results[i].error
    return [results[i] for i in range(len(jobs))]


class _Raised:
    """A job's exception among the results (a job may return an exception as its result)."""

    def __init__(self, error: BaseException) -> None:
        self.error = error

    def __reduce__(self) -> tuple[Any, ...]:
        return (_Raised, (self.error,))


def _take_jobs(jobs: Sequence[Callable[[], object]], counter: _Counter) -> dict[int, object]:
    """Jobs taken from ``counter`` and run until none is left or one raises: ``{index: result}``, a raised
    exception as a :class:`_Raised`."""
    done: dict[int, object] = {}
    while (i := counter.take()) < len(jobs):
        try:
            done[i] = jobs[i]()
        except BaseException as exc:
            done[i] = _Raised(exc)
            break
    return done


def _fork_share(jobs: Sequence[Callable[[], object]], counter: _Counter) -> tuple[int, int]:
    """A child taking jobs from ``counter`` (:func:`_take_jobs`) and writing ``{index: result}`` to a pipe:
    (its pid, the pipe's read end)."""
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid:
        os.close(write_fd)
        return pid, read_fd
    status = 0
    try:  # the child: never returns into the parent's code, never runs its exit handlers
        os.close(read_fd)
        answer = _take_jobs(jobs, counter)
        try:
            payload = pickle.dumps(answer)
            pickle.loads(payload)  # an exception whose __init__ its args do not fit fails here, not there
        except Exception:
            payload = pickle.dumps(HilError(f"a forked drawing job failed: {answer!r}"))
        with os.fdopen(write_fd, "wb") as pipe:
            pipe.write(payload)
    except BaseException:
        status = 2
    finally:
        os._exit(status)


def _reap(pid: int, read_fd: int) -> object:
    """What the child ``pid`` wrote (read to its end), once it has exited."""
    with os.fdopen(read_fd, "rb") as pipe:
        payload = pipe.read()
    _, status = os.waitpid(pid, 0)
    if not payload:
        return HilError(f"a forked drawing process ended without an answer ({_describe(status)})")
    return pickle.loads(payload)


def _describe(status: int) -> str:
    code = os.waitstatus_to_exitcode(status)  # a signal's number, negated
    return f"signal {-code}" if code < 0 else f"exit status {code}"
