"""The live merger (:class:`hil.estimation.multirate.Merger`, on lists indexed by sensor and unrolled over
the three sensors: issue 29, host speed) against the dict-and-set form it replaced, kept here as its
oracle (:class:`ReferenceMerger`, verbatim but for its name): the same steps, flags, ages and counts for
any stream — duplicates, ties, out-of-order, late and non-finite samples, absurd values, every driver and
failover order, with and without a latency window."""

from __future__ import annotations

import logging
import math
from collections import deque

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.estimator import flag
from hil.estimation.multirate import (
    _LABELS,
    _STALE,
    FAILOVER,
    GAP,
    MergePolicy,
    Merger,
    MergeStats,
    resolve_roles,
)
from hil.estimation.sensors import KINDS, MergedStep, SensorKind, SensorSample

logger = logging.getLogger(__name__)


class ReferenceMerger:
    """The same merge, one sample at a time: ``push(sample)`` returns the steps that sample completes.

    Holds at most ``latency_s`` worth of samples. ``driver`` and ``failover_order`` come from the policy
    or the live defaults (:func:`resolve_roles`); pass the batch's resolved roles to reproduce a batch
    merge exactly.
    """

    def __init__(self, policy: MergePolicy | None = None) -> None:
        self.policy = policy or MergePolicy()
        self.driver, self.failover_order = resolve_roles(self.policy)
        self.stats = MergeStats(driver=self.driver, failover_order=self.failover_order)
        self._newest: dict[SensorKind, float] = dict.fromkeys(KINDS, -math.inf)  # newest accepted time
        self._pending: dict[SensorKind, deque[SensorSample]] = {k: deque() for k in KINDS}
        self._held: dict[SensorKind, SensorSample | None] = dict.fromkeys(KINDS)
        self._changed: dict[SensorKind, bool] = dict.fromkeys(KINDS, False)
        self._watermark = -math.inf
        self._last_step = -math.inf

    def push(self, sample: SensorSample) -> list[MergedStep]:
        """Take one sample (any sensor, arrival order); returns the steps now complete, oldest first."""
        kind = sample.kind
        t = sample.t_s
        x, y, z = sample.xyz
        reason = None
        if not (math.isfinite(t) and math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            reason = "nan"
        elif t == self._newest[kind]:
            reason = "duplicate"
        elif t < self._newest[kind]:
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
        pending = self._pending
        driver_q = pending[self.driver]
        while True:
            at = math.inf  # the oldest head (accepted samples are finite): a loop, not min() of a list
            for q in pending.values():
                if q and q[0].t_s < at:
                    at = q[0].t_s
            if at == math.inf:
                return out
            if at > horizon or (at == horizon and not (driver_q and driver_q[0].t_s == at)):
                return out  # wait: more samples stamped `at` may come (unless the driver's completes it)
            arrived = set()
            for kind, q in pending.items():
                while q and q[0].t_s == at:
                    self._held[kind] = q.popleft()
                    self._changed[kind] = True
                    arrived.add(kind)
            if at <= self._last_step:
                continue  # a late sample: held for the next step, no step of its own
            rank = self._rank(at, arrived)
            if rank is not None:
                out.append(self._step(at, rank))

    def _stale(self, kind: SensorKind, at: float) -> bool:
        held = self._held[kind]
        return held is None or at - held.t_s > self.policy.stale_after_s

    def _rank(self, at: float, arrived: set[SensorKind]) -> int | None:
        """0 if the driver steps at ``at``, j+1 if failover sensor j does, None if nobody does."""
        if self.driver in arrived:
            return 0
        if self._stale(self.driver, at):
            for j, kind in enumerate(self.failover_order):
                if kind in arrived:
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
        values: list[tuple[float, float, float] | None] = []
        ages: list[float] = []
        fresh: list[bool] = []
        for kind in KINDS:
            held = self._held[kind]
            age = math.inf if held is None else at - held.t_s
            ok = held is not None and age <= stale_after
            values.append(held.xyz if ok and held is not None else None)
            ages.append(age)
            fresh.append(self._changed[kind])
            self._changed[kind] = False
            if not ok:
                bits |= _STALE[kind]
        self._last_step = at
        self.stats.count_step(bits)
        age3, fresh3 = (ages[0], ages[1], ages[2]), (fresh[0], fresh[1], fresh[2])
        return MergedStep(at, h, values[0], values[1], values[2], age3, fresh3, flag(bits))


TIMES = st.one_of(
    st.integers(0, 400).map(lambda k: k * 0.0025),  # on a grid: ties between sensors, duplicates
    st.floats(0.0, 1.0),
    st.sampled_from([math.nan, math.inf, -math.inf, -0.0, 0.0, 1e160]),
)
VALUES = st.one_of(st.floats(-1e3, 1e3), st.sampled_from([math.nan, math.inf, -0.0, 0.0, 1e160, -1e160]))
SAMPLES = st.builds(SensorSample, TIMES, st.sampled_from(KINDS), st.tuples(VALUES, VALUES, VALUES))
POLICIES = st.builds(
    MergePolicy,
    driver=st.sampled_from([None, *KINDS]),
    stale_after_s=st.sampled_from([0.25, 0.01]),
    gap_after_s=st.sampled_from([0.1, 0.004]),
    failover=st.booleans(),
    latency_s=st.sampled_from([0.0, 0.003, 0.05]),
)


def _stats(stats: MergeStats) -> dict[str, object]:
    return dict(vars(stats))


@settings(max_examples=300, deadline=None)
@given(POLICIES, st.lists(SAMPLES, max_size=60), st.booleans())
def test_the_live_merger_is_the_reference_step_for_step(policy, samples, in_time_order):
    if in_time_order:
        samples = sorted(
            samples, key=lambda s: (not math.isfinite(s.t_s), s.t_s if math.isfinite(s.t_s) else 0)
        )
    fast, oracle = Merger(policy), ReferenceMerger(policy)
    for sample in samples:
        assert fast.push(sample) == oracle.push(sample)
        assert _stats(fast.stats) == _stats(oracle.stats)
    assert fast.flush() == oracle.flush()
    assert _stats(fast.stats) == _stats(oracle.stats)


def test_a_live_stream_steps_as_the_reference_does():
    """A phone's stream (gyroscope and accelerometer at 200 Hz, magnetometer at 50 Hz, a pause that
    makes the gyroscope stale and the accelerometer take over): the same steps, and some of each kind."""
    stream = []
    for k in range(400):
        t = k * 0.005
        if not 100 <= k < 200:  # the gyroscope pauses: the accelerometer drives (failover)
            stream.append(SensorSample(t, SensorKind.GYR, (0.01, 0.02, 0.03)))
        stream.append(SensorSample(t + 0.002, SensorKind.ACC, (0.1, 0.2, 9.8)))
        if k % 4 == 0:
            stream.append(SensorSample(t + 0.003, SensorKind.MAG, (20.0, 5.0, -40.0)))
    fast, oracle = Merger(), ReferenceMerger()
    steps = [step for sample in stream for step in fast.push(sample)]
    assert steps == [step for sample in stream for step in oracle.push(sample)]
    assert len(steps) > 300 and fast.stats.failover_steps > 0 and fast.stats.stale_steps["gyr"] > 0
