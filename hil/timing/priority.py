"""The operating system's scheduling of a real-time run: a fixed real-time priority (Linux ``SCHED_FIFO``)
for the run's process, asked for by the operator (``hil run --rt-priority N``), and what the run had.

Why. On a machine with other work on it (a second process busy on one of two cores, a browser, a
campaign), the kernel's fair scheduler shares a core between the control thread and that work: a control
activation that wakes while the other process has the core waits for its time slice, ~1–3 ms at p99 at
200 Hz (``python -m bench runtime``, its busy-core rows). A thread under ``SCHED_FIFO`` runs as soon as it
is runnable, before every normal thread: the same run's lateness stays at its quiet figure. It is every
thread of the process, not the control thread alone: the threads running already (a ground station's
server) are switched, and those the run starts (the board link's reader, the phone's receiver, the CSV
writer) and a board it spawns (``spawn://firmware-sim``) inherit it — the interpreter's lock is never
held by a thread that the busy process, or the browser watching the run, keeps off the core (a priority
inversion the control thread would wait out: with the page attached, p99 2.4 ms at the normal policy).

What it costs. A real-time thread that never slept would starve the rest of its core; the run's threads
sleep to their deadlines and block on their I/O, and Linux's real-time throttling (by default 0.95 s of
each second, ``/proc/sys/kernel/sched_rt_runtime_us``) keeps the rest of the machine alive whatever
happens. It needs the privilege to use it: root, ``CAP_SYS_NICE``, or an ``RLIMIT_RTPRIO`` of at least
the priority (``ulimit -r``; ``/etc/security/limits.conf``: ``@realtime - rtprio 50``). Without it the
run stops at once with a :class:`~protocol.errors.ConfigError` saying so, rather than running with the
timing the operator asked it not to have. The same can be had from outside (``chrt -f 20 hil run ...``):
:func:`current` reports either way, in the run's summary.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Any

from protocol.errors import ConfigError

WHERE = "run --rt-priority"
"""The option a refusal names."""

_POLICY_NAMES = {
    getattr(os, name): name
    for name in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH", "SCHED_IDLE")
    if hasattr(os, name)
}


@dataclass(frozen=True)
class Scheduling:
    """The calling thread's scheduling: ``policy`` by its name (``SCHED_OTHER``: the normal fair share,
    ``SCHED_FIFO``: real time) and its real-time ``priority`` (1–99; 0 for the normal policies)."""

    policy: str
    priority: int

    def describe(self) -> dict[str, Any]:
        """For the run's summary (``scheduling``)."""
        return asdict(self)


def current() -> Scheduling:
    """The calling thread's policy and priority (``unknown`` where the OS does not say: not Linux)."""
    if not hasattr(os, "sched_getscheduler"):
        return Scheduling("unknown", 0)
    policy = os.sched_getscheduler(0)
    return Scheduling(_POLICY_NAMES.get(policy, str(policy)), os.sched_getparam(0).sched_priority)


@contextlib.contextmanager
def realtime(priority: int | None) -> Iterator[Scheduling]:
    """Every thread of this process — those running now (a ground station's server, started before the
    run) and those they start inside the block (which inherit it), and the processes they start — under
    ``SCHED_FIFO`` at ``priority`` until the block ends, then each back to what it had; ``None``: left as
    it is. Yields the calling thread's scheduling in force. ConfigError, naming what is missing, when the
    priority is out of range, the OS has no real-time policy, or the process may not use it."""
    if priority is None:
        yield current()
        return
    if not hasattr(os, "sched_setscheduler"):
        raise ConfigError("a real-time priority needs Linux's SCHED_FIFO, which this OS does not have", WHERE)
    low, high = os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO)
    if not low <= priority <= high:
        raise ConfigError(f"must be a SCHED_FIFO priority from {low} to {high}, got {priority!r}", WHERE)
    before = _policies()
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError as exc:
        raise ConfigError(
            f"SCHED_FIFO priority {priority} is not permitted here ({exc.strerror}): run as root, give the "
            f"interpreter CAP_SYS_NICE, or raise the real-time priority limit (ulimit -r: now "
            f"{_rtprio_limit()}) to at least {priority}",
            WHERE,
        ) from exc
    try:
        for tid in before:
            with contextlib.suppress(ProcessLookupError):  # a thread that ended meanwhile
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        yield current()
    finally:
        for tid, (policy, param) in before.items():
            with contextlib.suppress(ProcessLookupError):
                os.sched_setscheduler(tid, policy, param)


def _policies() -> dict[int, tuple[int, os.sched_param]]:
    """Each running thread of this process (its kernel thread id; 0: the calling one) and its policy and
    parameters. Threads the ``threading`` module does not know (a C library's own) are left alone."""
    calling = threading.get_native_id()
    out = {0: (os.sched_getscheduler(0), os.sched_getparam(0))}
    for thread in threading.enumerate():
        tid = thread.native_id
        if tid is None or tid == calling:
            continue
        with contextlib.suppress(ProcessLookupError):
            out[tid] = (os.sched_getscheduler(tid), os.sched_getparam(tid))
    return out


def _rtprio_limit() -> str:
    """The process's soft ``RLIMIT_RTPRIO``, for the refusal's message."""
    import resource

    soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
    return "unlimited" if soft == resource.RLIM_INFINITY else str(soft)
