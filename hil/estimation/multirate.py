"""Multi-rate merge: per-sensor sample streams in, filter steps out (the paper's hold-last-sample scheme).

The filter steps at the *driving* sensor's samples (by default the fastest stream; the gyroscope when
live) and holds the latest sample of every other sensor, recording its age. Each step carries, per
sensor, the held value (or 'not usable'), its age in seconds and whether it is new since the previous
step. The same rules run in two shapes with identical results: :func:`merge` over whole streams
(vectorised, for replaying a 720k-sample log) and :class:`Merger`, fed one sample at a time (live).

Policies (each tested):

- **Non-finite samples** (a NaN/inf value or timestamp): dropped, counted as ``nan``. The sensor's held
  sample then ages and goes stale, so the filter is told, never handed the NaN.
- **Duplicated timestamps** (a sample with the same time as that sensor's newest accepted one): the first
  wins; later ones are dropped, counted as ``duplicate``. (A zero-length filter step is meaningless.)
- **Out-of-order timestamps** (older than that sensor's newest accepted one): dropped, counted as
  ``out_of_order``. Decisions depend only on each sensor's own arrival order, so they are the same in
  both shapes. (Android timestamps are monotonic per sensor; a step back is a logging or transport
  fault, and re-sorting would silently move data across steps already taken live.)
- **Jitter**: steps are at the driving sensor's actual timestamps; ``h`` varies from step to step.
- **Ties across sensors**: a step at time ``t`` holds every sample with timestamp ``≤ t``, same-time
  samples of other sensors included.
- **Gaps**: a step longer than ``gap_after_s`` is flagged ``GAP`` and counted (the estimator sub-steps it).
- **Stale sensors**: a held sample older than ``stale_after_s`` (or none yet) is not usable: its value is
  withheld and the step flagged ``<KIND>_STALE`` (counted per sensor). A sensor that stops, or that
  sends only NaN, goes stale this way.
- **Failover**: while the driving sensor is stale, the next sensor in ``failover_order`` whose own samples
  are fresh drives the steps (flagged ``FAILOVER``), so a stopped gyroscope does not stop the filter;
  when the driver resumes, it drives again.
- **Live latency**: :class:`Merger` emits the step for a driver sample at ``t`` once it has seen a sample
  stamped ``≥ t + latency_s`` (with ``latency_s = 0``: at once — the driver's sample completes its step;
  a failover step waits for a sample stamped after ``t``), or on :meth:`Merger.flush`. Samples arriving
  later than that but still newer than their sensor's held one are used from the next step on (a late
  sample is never dropped for being late, only for going backwards). With everything arriving in time
  order (same-time samples before the driver's), live equals batch exactly.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from hil.estimation.estimator import flag
from hil.estimation.sensors import (
    KINDS,
    MergedStep,
    MergedSteps,
    SensorKind,
    SensorSample,
    SensorStream,
    StepFlag,
)
from hil.estimation.slots import FAILOVER, GAP
from protocol.compiled import fast_constructor
from protocol.errors import ConfigError

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]
_NAN3 = (math.nan, math.nan, math.nan)


@dataclass(frozen=True)
class MergePolicy:
    """How streams are merged (see the module docstring for each rule).

    ``driver``: the sensor whose samples set the steps; None = the fastest stream (batch; ties go to the
    gyroscope, then the accelerometer) or the gyroscope (live). ``stale_after_s``: age (s) beyond which a
    held sample is not usable. ``gap_after_s``: step length (s) above which a step is flagged a gap.
    ``failover_order``: who drives while the driver is stale; None = the other sensors, fastest first
    (batch) or accelerometer then magnetometer (live). ``latency_s``: live only, see :class:`Merger`.
    """

    driver: SensorKind | None = None
    stale_after_s: float = 0.25
    gap_after_s: float = 0.1
    failover: bool = True
    failover_order: tuple[SensorKind, ...] | None = None
    latency_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("stale_after_s", "gap_after_s", "latency_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                where = f"MergePolicy.{name}"
                raise ConfigError(f"must be a finite number of seconds >= 0, got {value!r}", where)
        if self.failover_order is not None and (
            len(set(self.failover_order)) != len(self.failover_order) or self.driver in self.failover_order
        ):
            raise ConfigError(
                f"must list distinct sensors other than the driver, got {self.failover_order!r}",
                "MergePolicy.failover_order",
            )


_LABELS = tuple(k.label for k in KINDS)  # indexed by SensorKind (``label`` is a property: computed per call)
_STALE = tuple(int(StepFlag.stale(k)) for k in KINDS)
_new_step = fast_constructor(MergedStep)
"""``MergedStep(t, h, gyr, acc, mag, age, fresh, flags)`` by setting its slots, not through the frozen
dataclass's ``__init__`` (``object.__setattr__`` per field): one per estimator step."""


@dataclass
class MergeStats:
    """Counters of one merge: per sensor (keyed by ``SensorKind.label``) accepted samples and drops by
    reason, per sensor the steps on which it was stale, and the steps, gaps and failover steps; and the
    roles the merge used (``driver``, ``failover_order``), which a live :class:`Merger` can be given to
    reproduce a batch merge."""

    accepted: dict[str, int] = field(default_factory=lambda: dict.fromkeys(_LABELS, 0))
    nan: dict[str, int] = field(default_factory=lambda: dict.fromkeys(_LABELS, 0))
    duplicate: dict[str, int] = field(default_factory=lambda: dict.fromkeys(_LABELS, 0))
    out_of_order: dict[str, int] = field(default_factory=lambda: dict.fromkeys(_LABELS, 0))
    stale_steps: dict[str, int] = field(default_factory=lambda: dict.fromkeys(_LABELS, 0))
    steps: int = 0
    gaps: int = 0
    failover_steps: int = 0
    driver: SensorKind | None = None
    failover_order: tuple[SensorKind, ...] = ()

    @property
    def dropped(self) -> int:
        return sum(sum(d.values()) for d in (self.nan, self.duplicate, self.out_of_order))

    def absorb(self, other: MergeStats) -> None:
        """Add ``other``'s counts to these (a live host starts a new :class:`Merger` whenever the phone's
        stream is not to be integrated across: the run's counts are the sum over its mergers)."""
        for name in ("accepted", *_REASONS, "stale_steps"):
            mine: dict[str, int] = getattr(self, name)
            for label, n in getattr(other, name).items():
                mine[label] = mine.get(label, 0) + n
        self.steps += other.steps
        self.gaps += other.gaps
        self.failover_steps += other.failover_steps

    def as_dict(self) -> dict[str, object]:
        """For ``summary.json``: per sensor what was accepted and what dropped, by reason; the steps, gaps
        and failover steps, and per sensor the steps on which it was stale."""
        return {
            "accepted": dict(self.accepted),
            "dropped": {reason: dict(getattr(self, reason)) for reason in _REASONS},
            "dropped_total": self.dropped,
            "steps": self.steps,
            "gaps": self.gaps,
            "failover_steps": self.failover_steps,
            "stale_steps": dict(self.stale_steps),
        }

    def count_step(self, flags: int) -> None:
        """Count one step with these :class:`StepFlag` bits."""
        self.steps += 1
        if flags:  # the usual step has none
            self.gaps += bool(flags & StepFlag.GAP)
            self.failover_steps += bool(flags & StepFlag.FAILOVER)
            for kind in KINDS:
                self.stale_steps[kind.label] += bool(flags & StepFlag.stale(kind))

    def count_steps(self, flags: NDArray[np.int64]) -> None:
        """Count many steps at once (the batch path); same result as :meth:`count_step` on each."""
        self.steps += int(flags.shape[0])
        self.gaps += int(np.count_nonzero(flags & GAP))
        self.failover_steps += int(np.count_nonzero(flags & FAILOVER))
        for kind in KINDS:
            self.stale_steps[kind.label] += int(np.count_nonzero(flags & int(StepFlag.stale(kind))))


_REASONS = ("nan", "duplicate", "out_of_order")


def _log_drops(stats: MergeStats, before: dict[str, dict[str, int]]) -> None:
    """Log (once per sensor and reason) that samples were dropped; the counts are in ``stats``."""
    for reason in _REASONS:
        counts: dict[str, int] = getattr(stats, reason)
        for label, n in counts.items():
            if n and not before[reason][label]:
                logger.warning("merge: dropping %s samples of %s (counted in MergeStats)", reason, label)


def _snapshot(stats: MergeStats) -> dict[str, dict[str, int]]:
    return {reason: dict(getattr(stats, reason)) for reason in _REASONS}


def resolve_roles(
    policy: MergePolicy, periods: Mapping[SensorKind, float] | None = None
) -> tuple[SensorKind, tuple[SensorKind, ...]]:
    """The driving sensor and the failover order: from the policy, else by ``periods`` (s, fastest
    first; ties in :data:`KINDS` order), else the live defaults (gyroscope; accelerometer, magnetometer)."""
    if periods is not None:
        ranked = sorted(KINDS, key=lambda k: (periods.get(k, math.inf), int(k)))
    else:
        ranked = [SensorKind.GYR, SensorKind.ACC, SensorKind.MAG]
    driver = policy.driver if policy.driver is not None else ranked[0]
    order = policy.failover_order
    if order is None:
        order = tuple(k for k in ranked if k != driver)
    return driver, (order if policy.failover else ())


# --------------------------------------------------------------------------- batch
def _accept(t: Array, xyz: Array) -> tuple[NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]:
    """Per-row (accepted, duplicate, out-of-order) in arrival order; the rest of the rows are non-finite."""
    finite = np.isfinite(t) & np.all(np.isfinite(xyz), axis=1)
    newest = np.maximum.accumulate(np.where(finite, t, -np.inf)) if t.size else t
    before = np.concatenate([[-np.inf], newest[:-1]]) if t.size else t
    return finite & (t > before), finite & (t == before), finite & (t < before)


def _latest_index(times: Array, at: Array) -> NDArray[np.int64]:
    """Index of the latest of ``times`` (sorted) that is ``<= at``, or -1."""
    return np.searchsorted(times, at, side="right").astype(np.int64) - 1


def _stale_at(times: Array, at: Array, limit: float) -> NDArray[np.bool_]:
    idx = _latest_index(times, at)
    last = times[np.maximum(idx, 0)] if times.size else np.zeros_like(at)
    return (idx < 0) | (at - last > limit)


def merge(
    streams: Mapping[SensorKind, SensorStream], policy: MergePolicy | None = None
) -> tuple[MergedSteps, MergeStats]:
    """Merge whole per-sensor streams into filter steps (rows kept in each stream's recorded order).

    A missing or empty stream is a sensor that never speaks: stale on every step. Returns the steps and
    the counters.
    """
    policy = policy or MergePolicy()
    stats = MergeStats()
    clean: dict[SensorKind, tuple[Array, Array]] = {}
    for kind in KINDS:
        stream = streams.get(kind)
        t = stream.t if stream is not None else np.zeros(0)
        xyz = stream.xyz if stream is not None else np.zeros((0, 3))
        keep, dup, back = _accept(t, xyz)
        label = kind.label
        stats.accepted[label] = int(keep.sum())
        stats.duplicate[label] = int(dup.sum())
        stats.out_of_order[label] = int(back.sum())
        stats.nan[label] = int(t.shape[0] - keep.sum() - dup.sum() - back.sum())
        clean[kind] = (t[keep], xyz[keep])
    _log_drops(stats, _snapshot(MergeStats()))
    periods = {k: SensorStream(k, t, x).median_period() for k, (t, x) in clean.items() if t.size}
    driver, order = resolve_roles(policy, periods)
    stats.driver, stats.failover_order = driver, order
    limit = policy.stale_after_s

    # candidate step times: every driver sample, plus failover samples while the driver is stale
    times = [clean[driver][0]]
    rank = [np.zeros(clean[driver][0].shape[0], dtype=np.int64)]
    for j, kind in enumerate(order):
        s = clean[kind][0]
        ok = _stale_at(clean[driver][0], s, limit)
        for better in order[:j]:
            ok &= _stale_at(clean[better][0], s, limit)
        times.append(s[ok])
        rank.append(np.full(int(ok.sum()), j + 1, dtype=np.int64))
    all_t = np.concatenate(times)
    all_rank = np.concatenate(rank)
    sort = np.lexsort((all_rank, all_t))
    all_t, all_rank = all_t[sort], all_rank[sort]
    first = np.ones(all_t.shape[0], bool)
    first[1:] = all_t[1:] > all_t[:-1]
    step_t, step_rank = all_t[first], all_rank[first]
    n = step_t.shape[0]

    flags = np.zeros(n, dtype=np.int64)
    flags[step_rank > 0] |= FAILOVER
    h = np.diff(step_t, prepend=step_t[:1]) if n else np.zeros(0)
    flags[h > policy.gap_after_s] |= GAP
    values: dict[SensorKind, Array] = {}
    age = np.empty((n, 3))
    fresh = np.empty((n, 3), bool)
    for kind in KINDS:
        kt, kx = clean[kind]
        idx = _latest_index(kt, step_t)
        has = idx >= 0
        held_t = kt[np.maximum(idx, 0)] if kt.size else np.zeros(n)
        held_x = kx[np.maximum(idx, 0)] if kt.size else np.zeros((n, 3))
        age[:, kind] = np.where(has, step_t - held_t, np.inf)
        valid = has & (age[:, kind] <= limit)
        values[kind] = np.where(valid[:, None], held_x, np.nan)
        fresh[:, kind] = has & (idx > np.concatenate([[-1], idx[:-1]]))
        flags[~valid] |= int(StepFlag.stale(kind))
    stats.count_steps(flags)
    steps = MergedSteps(
        step_t, values[SensorKind.GYR], values[SensorKind.ACC], values[SensorKind.MAG], age, fresh, flags
    )
    return steps, stats


def first_full_step(steps: MergedSteps) -> int:
    """Index of the first step at which every sensor has delivered a sample (0 if none ever does): where
    a replay starts, since sensors of a recording start a few samples apart."""
    spoken = np.all(np.isfinite(steps.age), axis=1)
    return int(np.argmax(spoken)) if spoken.any() else 0


# --------------------------------------------------------------------------- live
class Merger:
    """The same merge, one sample at a time: ``push(sample)`` returns the steps that sample completes.

    Holds at most ``latency_s`` worth of samples. ``driver`` and ``failover_order`` come from the policy
    or the live defaults (:func:`resolve_roles`); pass the batch's resolved roles to reproduce a batch
    merge exactly.
    """

    def __init__(self, policy: MergePolicy | None = None) -> None:
        self.policy = policy or MergePolicy()
        self.driver, self.failover_order = resolve_roles(self.policy)
        self.stats = MergeStats(driver=self.driver, failover_order=self.failover_order)
        # Per sensor, in lists indexed by SensorKind (0, 1, 2: KINDS order), not dicts: every sample reads
        # and writes several of them (a list index is the cheapest lookup Python has).
        self._newest: list[float] = [-math.inf] * len(KINDS)  # newest accepted time
        self._pending: tuple[deque[SensorSample], ...] = tuple(deque() for _ in KINDS)
        self._held: list[SensorSample | None] = [None] * len(KINDS)
        self._changed: list[bool] = [False] * len(KINDS)
        self._watermark = -math.inf
        self._last_step = -math.inf
        # the failover order as (kind, its bit in an ``arrived`` mask), for _rank
        self._failover = tuple((kind, 1 << kind) for kind in self.failover_order)

    def push(self, sample: SensorSample) -> list[MergedStep]:
        """Take one sample (any sensor, arrival order); returns the steps now complete, oldest first."""
        kind = sample.kind
        t = sample.t_s
        x, y, z = sample.xyz
        newest = self._newest[kind]
        reason = None
        if not (math.isfinite(t) and math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            reason = "nan"
        elif t == newest:
            reason = "duplicate"
        elif t < newest:
            reason = "out_of_order"
        if reason is not None:
            label = _LABELS[kind]
            counts: dict[str, int] = getattr(self.stats, reason)
            if not counts[label]:
                logger.warning("merge: dropping %s samples of %s (counted in MergeStats)", reason, label)
            counts[label] += 1
            return []
        self.stats.accepted[_LABELS[kind]] += 1
        self._newest[kind] = t
        self._pending[kind].append(sample)
        if t > self._watermark:
            self._watermark = t
        return self._emit(self._watermark - self.policy.latency_s)

    def flush(self) -> list[MergedStep]:
        """End of input: emit every step still waiting for the latency window."""
        return self._emit(math.inf)

    def _emit(self, horizon: float) -> list[MergedStep]:
        out: list[MergedStep] = []
        q0, q1, q2 = self._pending
        driver_q = self._pending[self.driver]
        held, changed = self._held, self._changed
        while True:
            at = math.inf  # the oldest head (accepted samples are finite): unrolled, not min() of a list
            if q0 and q0[0].t_s < at:
                at = q0[0].t_s
            if q1 and q1[0].t_s < at:
                at = q1[0].t_s
            if q2 and q2[0].t_s < at:
                at = q2[0].t_s
            if at == math.inf:
                return out
            if at > horizon or (at == horizon and not (driver_q and driver_q[0].t_s == at)):
                return out  # wait: more samples stamped `at` may come (unless the driver's completes it)
            arrived = 0  # a bit per sensor (1 << kind)
            for kind, q in enumerate((q0, q1, q2)):
                while q and q[0].t_s == at:
                    held[kind] = q.popleft()
                    changed[kind] = True
                    arrived |= 1 << kind
            if at <= self._last_step:
                continue  # a late sample: held for the next step, no step of its own
            rank = self._rank(at, arrived)
            if rank is not None:
                out.append(self._step(at, rank))

    def _stale(self, kind: SensorKind, at: float) -> bool:
        held = self._held[kind]
        return held is None or at - held.t_s > self.policy.stale_after_s

    def _rank(self, at: float, arrived: int) -> int | None:
        """0 if the driver steps at ``at``, j+1 if failover sensor j does, None if nobody does; ``arrived``
        has bit ``1 << kind`` set for each sensor with a sample stamped ``at``."""
        if arrived >> self.driver & 1:
            return 0
        if self._stale(self.driver, at):
            for j, (kind, bit) in enumerate(self._failover):
                if arrived & bit:
                    return j + 1
                if not self._stale(kind, at):
                    return None
        return None

    def _step(self, at: float, rank: int) -> MergedStep:
        h = at - self._last_step if self._last_step > -math.inf else 0.0
        # StepFlag bits as an int, one memoised StepFlag at the end: IntFlag arithmetic costs ~1 µs a use
        bits = FAILOVER if rank else 0
        if h > self.policy.gap_after_s:
            bits |= GAP
        stale_after = self.policy.stale_after_s
        held, changed = self._held, self._changed
        g, a, m = held
        # unrolled over the three sensors (KINDS order): a sensor's value is None when nothing is held or
        # what is held is older than stale_after; its age is inf when nothing is held
        age_g = math.inf if g is None else at - g.t_s
        age_a = math.inf if a is None else at - a.t_s
        age_m = math.inf if m is None else at - m.t_s
        gyr = g.xyz if g is not None and age_g <= stale_after else None
        acc = a.xyz if a is not None and age_a <= stale_after else None
        mag = m.xyz if m is not None and age_m <= stale_after else None
        if gyr is None:
            bits |= _STALE[0]
        if acc is None:
            bits |= _STALE[1]
        if mag is None:
            bits |= _STALE[2]
        fresh3 = (changed[0], changed[1], changed[2])
        changed[0] = changed[1] = changed[2] = False
        self._last_step = at
        self.stats.count_step(bits)
        return _new_step(at, h, gyr, acc, mag, (age_g, age_a, age_m), fresh3, flag(bits))
