"""Periodic tasks on one injected clock, scheduled against absolute deadlines.

The same scheduler runs the host's loops in real time (``WallClock``: it sleeps to each deadline) and in
lockstep (``LockstepClock``: ``sleep_until`` jumps the clock, so a run goes as fast as the CPU allows).
Deadlines are ``origin + k · period`` with an integer ``k`` — never ``t += period`` in floating point, never
``sleep(period)`` — so period errors do not accumulate at any rate.

Tasks due at the same instant run in the order they were given (e.g. world, sensors, estimator, control):
in lockstep the run is therefore deterministic. "The same instant" is the same nanosecond: deadlines of
commensurate periods that meet (5 × 1 ms and 1 × 5 ms) differ in their last bits of floating point, and
must not run in the order of their rounding errors. A task that is found late by more than its period has
overrun: the missed activations are *skipped* (counted in ``overruns``), never replayed in a burst, since a
stale control step is worse than a missed one; a deadline at the very nanosecond an activation ended is not
missed, it runs (a lockstep step that waited to the next control instant once lost that instant too, or
not, as the rounding of its float fell, and counted one overrun too many). Nor does :meth:`Scheduler.run`
run an activation it finds past its limit by more than the task's period (its process paused across the
run's end, seconds late): the run's time is up, and a control step then would act on a run that has ended
(it once re-armed a board that failed safe during the pause, as the host let go of it). An activation that
is merely late runs as before, and in lockstep (the clock at each deadline) every one due by the limit runs.

Statistics per task: lateness (how long after its deadline a task started, s) in a bounded ring, with
p50 / p99 over the newest samples, the max over the whole run, and the number of runs and overruns — the
jitter figures ``bench/`` reports. Every time the clock gives must be finite, as must ``until``
(:class:`~protocol.errors.ConfigError` otherwise).
"""

from __future__ import annotations

import heapq
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from hil.timing.clock import Clock
from protocol.errors import ConfigError

_RING = 65_536  # lateness samples kept per task (the newest)
_EPS = 1e-9  # s: a deadline this close to ``until`` still runs (k · period rounds either way)
_RESOLUTION_S = 1e-9  # s: the scheduler's instant (tasks due in the same nanosecond are due together)


@dataclass
class TaskStats:
    """What one task's schedule looked like. Lateness in seconds."""

    runs: int = 0
    overruns: int = 0
    max_lateness_s: float = math.nan  # over every run, not only the ring's newest: NaN before the first
    _lateness: np.ndarray = field(default_factory=lambda: np.zeros(_RING), repr=False)

    def record(self, lateness_s: float) -> None:
        self._lateness[self.runs % _RING] = lateness_s
        self.runs += 1
        # kept apart from the ring: a real-time run longer than the ring (65 536 world steps: 66 s at
        # 1 kHz) once reported a max that had forgotten its worst stall
        if not lateness_s <= self.max_lateness_s:
            self.max_lateness_s = lateness_s

    @property
    def lateness(self) -> np.ndarray:
        """The recorded lateness samples (s), at most the newest 65 536, unordered."""
        return self._lateness[: min(self.runs, _RING)]

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile of lateness (s); NaN before the first run."""
        samples = self.lateness
        return float(np.percentile(samples, q)) if samples.size else math.nan

    def summary(self) -> dict[str, float]:
        """Runs, overruns and lateness p50 / p99 (the newest samples) / max (the whole run) in
        microseconds (JSON-friendly)."""
        return {
            "runs": self.runs,
            "overruns": self.overruns,
            "lateness_p50_us": self.percentile(50) * 1e6,
            "lateness_p99_us": self.percentile(99) * 1e6,
            "lateness_max_us": self.max_lateness_s * 1e6,
        }


@dataclass
class PeriodicTask:
    """``callback(t)`` every ``period_s`` seconds, first at ``origin + offset_s``; ``t`` is the deadline
    (the scheduled time, s), which is what a lockstep step must use to be deterministic."""

    name: str
    period_s: float
    callback: Callable[[float], None]
    offset_s: float = 0.0
    stats: TaskStats = field(default_factory=TaskStats)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.period_s) and self.period_s > 0.0):
            raise ConfigError(
                f"period must be a positive number of seconds, not {self.period_s!r}", f"task {self.name!r}"
            )
        if self.period_s < _RESOLUTION_S:  # its deadlines would share nanoseconds: a run of 1 s, 10^12 steps
            raise ConfigError(
                f"period must be at least the scheduler's resolution of 1 ns, not {self.period_s!r} s",
                f"task {self.name!r}",
            )
        if not (math.isfinite(self.offset_s) and self.offset_s >= 0.0):
            raise ConfigError(f"offset must be ≥ 0 s, not {self.offset_s!r}", f"task {self.name!r}")


class Scheduler:
    """Runs ``tasks`` on ``clock`` until a time or until told to stop.

    ``origin`` (default: the clock's time at construction) anchors every task's deadlines.
    """

    def __init__(self, clock: Clock, tasks: Sequence[PeriodicTask], origin: float | None = None) -> None:
        if not tasks:
            raise ConfigError("a scheduler needs at least one task", "Scheduler")
        names = [t.name for t in tasks]
        if len(set(names)) != len(names):
            raise ConfigError(f"task names must be unique: {names}", "Scheduler")
        self.clock = clock
        self.tasks = list(tasks)
        self.origin = clock.now() if origin is None else float(origin)
        self._k = [0] * len(self.tasks)
        self._stop = False

    def deadline(self, index: int) -> float:
        """The next deadline (s) of task ``index``."""
        return self._deadline_at(index, self._k[index])

    def _deadline_at(self, index: int, k: int) -> float:
        """Task ``index``'s ``k``-th deadline (s)."""
        task = self.tasks[index]
        return self.origin + task.offset_s + k * task.period_s

    def stop(self) -> None:
        """Ask :meth:`run` to return after the task that is running now (safe from a callback)."""
        self._stop = True

    def run(self, until: float | None = None) -> None:
        """Run tasks in deadline order until the next deadline would be after ``until`` (s, clock time;
        None: until :meth:`stop`), or until an activation is found past ``until`` by more than its task's
        period (the clock stood still for it: a process paused across the limit)."""
        if until is not None and math.isnan(until):  # every deadline "not after" NaN: it never ended
            raise ConfigError("a run's limit must be a time in seconds or None, not nan", "Scheduler.run")
        self._stop = False
        clock = self.clock
        tasks = self.tasks
        heap = [(self._key(i), i) for i in range(len(tasks))]  # (deadline in ns, given order)
        heapq.heapify(heap)
        limit = math.inf if until is None else until + _EPS
        while not self._stop:
            index = heap[0][1]
            due = self.deadline(index)
            if due > limit:
                assert until is not None
                clock.sleep_until(until)
                return
            clock.sleep_until(due)
            task = tasks[index]
            started = _now(clock)
            if started > limit and started - due > task.period_s:
                return  # found past the limit (a host paused across it): its time is up, nothing more runs
            task.stats.record(started - due if started > due else 0.0)
            task.callback(due)
            self._advance(index, _now(clock))
            heapq.heapreplace(heap, (self._key(index), index))

    def _key(self, index: int) -> int:
        """Task ``index``'s next deadline in whole nanoseconds: the order of tasks due together."""
        return _ns(self.deadline(index))

    def _advance(self, index: int, now: float) -> None:
        """Next activation: one period on, or — if ``now`` is already past that — the first deadline at or
        after ``now`` (the same nanosecond is the same instant: on time, not missed), the skipped ones
        counted as overruns."""
        task = self.tasks[index]
        k = self._k[index] + 1
        now_ns = _ns(now)
        if _ns(self._deadline_at(index, k)) < now_ns:
            first = k
            # the count of periods gives k to within one either way (float division); the whole
            # nanoseconds, as the heap orders them, settle it
            k = max(first, math.ceil((now - self.origin - task.offset_s) / task.period_s))
            while k > first and _ns(self._deadline_at(index, k - 1)) >= now_ns:
                k -= 1
            while _ns(self._deadline_at(index, k)) < now_ns:
                k += 1
            task.stats.overruns += k - first
        self._k[index] = k

    def summary(self) -> dict[str, dict[str, float]]:
        """Every task's :meth:`TaskStats.summary`, by name."""
        return {t.name: t.stats.summary() for t in self.tasks}


def _ns(t: float) -> int:
    """``t`` (s) in whole nanoseconds: the scheduler's instant. A deadline too far to count in them (a
    period or offset of 1e300 s: ``round(inf)`` raised ``OverflowError``) is the last instant there is."""
    return round(min(t * 1e9, sys.float_info.max))


def _now(clock: Clock) -> float:
    """``clock.now()``, refused unless finite: a clock that said NaN ran every task on with a lateness of
    0 and no overrun ever counted (each comparison with it false)."""
    now = clock.now()
    if not math.isfinite(now):
        raise ConfigError(f"the clock gave {now!r} s, not a finite time", "Scheduler.run")
    return now
