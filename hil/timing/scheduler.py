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
stale control step is worse than a missed one. Nor does :meth:`Scheduler.run` run an activation it finds
past its limit by more than the task's period (its process paused across the run's end, seconds late): the
run's time is up, and a control step then would act on a run that has ended (it once re-armed a board that
failed safe during the pause, as the host let go of it). An activation that is merely late runs as before,
and in lockstep (the clock at each deadline) every one due by the limit runs.

Statistics per task: lateness (how long after its deadline a task started, s) in a bounded ring, with
p50 / p99 / max, and the number of runs and overruns — the jitter figures ``bench/`` reports.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from hil.timing.clock import Clock
from protocol.errors import ConfigError

_RING = 65_536  # lateness samples kept per task (the newest)
_EPS = 1e-9  # s: a deadline this close to ``until`` still runs (k · period rounds either way)


@dataclass
class TaskStats:
    """What one task's schedule looked like. Lateness in seconds."""

    runs: int = 0
    overruns: int = 0
    _lateness: np.ndarray = field(default_factory=lambda: np.zeros(_RING), repr=False)

    def record(self, lateness_s: float) -> None:
        self._lateness[self.runs % _RING] = lateness_s
        self.runs += 1

    @property
    def lateness(self) -> np.ndarray:
        """The recorded lateness samples (s), at most the newest 65 536, unordered."""
        return self._lateness[: min(self.runs, _RING)]

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile of lateness (s); NaN before the first run."""
        samples = self.lateness
        return float(np.percentile(samples, q)) if samples.size else math.nan

    def summary(self) -> dict[str, float]:
        """Runs, overruns and lateness p50 / p99 / max in microseconds (JSON-friendly)."""
        samples = self.lateness
        return {
            "runs": self.runs,
            "overruns": self.overruns,
            "lateness_p50_us": self.percentile(50) * 1e6,
            "lateness_p99_us": self.percentile(99) * 1e6,
            "lateness_max_us": float(samples.max()) * 1e6 if samples.size else math.nan,
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
        task = self.tasks[index]
        return self.origin + task.offset_s + self._k[index] * task.period_s

    def stop(self) -> None:
        """Ask :meth:`run` to return after the task that is running now (safe from a callback)."""
        self._stop = True

    def run(self, until: float | None = None) -> None:
        """Run tasks in deadline order until the next deadline would be after ``until`` (s, clock time;
        None: until :meth:`stop`), or until an activation is found past ``until`` by more than its task's
        period (the clock stood still for it: a process paused across the limit)."""
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
            started = clock.now()
            if started > limit and started - due > task.period_s:
                return  # found past the limit (a host paused across it): its time is up, nothing more runs
            task.stats.record(started - due if started > due else 0.0)
            task.callback(due)
            self._advance(index, clock.now())
            heapq.heapreplace(heap, (self._key(index), index))

    def _key(self, index: int) -> int:
        """Task ``index``'s next deadline in whole nanoseconds: the order of tasks due together."""
        return round(self.deadline(index) * 1e9)

    def _advance(self, index: int, now: float) -> None:
        """Next activation: one period on, or — if ``now`` is already past that — the first deadline after
        ``now``, the skipped ones counted as overruns."""
        task = self.tasks[index]
        self._k[index] += 1
        late_by = now - self.deadline(index)
        if late_by > 0.0:
            skipped = int(late_by // task.period_s) + 1
            self._k[index] += skipped
            task.stats.overruns += skipped

    def summary(self) -> dict[str, dict[str, float]]:
        """Every task's :meth:`TaskStats.summary`, by name."""
        return {t.name: t.stats.summary() for t in self.tasks}
