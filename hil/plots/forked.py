"""Drawing jobs shared among forked processes.

Agg's drawing is pure CPU in one thread (text layout, ticks, rasterising, PNG compression: ~0.12 s a figure
here), and a run's figures do not depend on one another. After the data is read and matplotlib imported, a
fork inherits both at no cost, so each process draws its share and only the results (the figures' paths)
come back, pickled through a pipe. ``hil run`` waits for its figures after the summary, with the run's own
core idle: two processes halve that wait on two cores.

POSIX only (``os.fork``). With one process, where there is no fork, or while another thread of this process
runs, every job runs here: a forked child holds only the forking thread, and a lock another thread held at
the fork (the logging module's, an import's) would stay held in it for ever.
"""

from __future__ import annotations

import os
import pickle
import threading
from collections.abc import Callable, Sequence
from typing import TypeVar

from protocol.errors import HilError

T = TypeVar("T")


def draw_shared(jobs: Sequence[Callable[[], T]], processes: int) -> list[T]:
    """Each job's result, in the jobs' order, the jobs run ``processes`` ways: job ``i`` in process
    ``i % processes``, process 0 being this one. A job's exception is raised here as it was raised (by the
    first process, in process order, that had one; one that cannot be pickled as a :class:`HilError`
    naming it); a child that dies without answering is a :class:`HilError` with its exit status."""
    processes = max(1, min(processes, len(jobs)))
    if processes == 1 or not hasattr(os, "fork") or threading.active_count() > 1:
        return [job() for job in jobs]
    children = [_fork_share(jobs, k, processes) for k in range(1, processes)]
    results: dict[int, T] = {}
    mine: BaseException | None = None
    try:
        for i in range(0, len(jobs), processes):
            results[i] = jobs[i]()
    except BaseException as exc:  # the children are reaped before it is raised
        mine = exc
    answers = [_reap(pid, fd) for pid, fd in children]
    if mine is not None:
        raise mine
    for answer in answers:
        if isinstance(answer, BaseException):
            raise answer
        results.update(answer)
    return [results[i] for i in range(len(jobs))]


def _fork_share(jobs: Sequence[Callable[[], object]], k: int, processes: int) -> tuple[int, int]:
    """A child running jobs ``k, k + processes, ...`` and writing ``{index: result}`` (or the exception)
    to a pipe: (its pid, the pipe's read end)."""
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid:
        os.close(write_fd)
        return pid, read_fd
    status = 0
    try:  # the child: never returns into the parent's code, never runs its exit handlers
        os.close(read_fd)
        answer: object
        try:
            answer = {i: jobs[i]() for i in range(k, len(jobs), processes)}
        except BaseException as exc:
            answer = exc
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
