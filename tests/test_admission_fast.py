"""The phone's admission check (:meth:`hil.estimation.admission.PhoneGuard.admit`) with its shortcut for a
plainly valid reading (issue 29, host speed) against the admit it replaced, kept here as its oracle
(:class:`ReferenceGuard`: ``_reason`` asked of every reading): the same verdicts, reasons and counts for
any stream — NaN, ±inf, ±0, 1e160, values at and past the limits, limits that are infinite, NaN, zero or
negative, clocks that jump."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.admission import (
    JUMP_S,
    MIN_INTERVAL_S,
    REANCHOR_READINGS,
    REANCHOR_SPAN_S,
    PhoneGuard,
    ReadingLimits,
    Verdict,
)
from hil.estimation.sensors import KINDS, SensorSample


class ReferenceGuard(PhoneGuard):
    """:class:`PhoneGuard` with the admit it had before the shortcut (verbatim, with the first reading's
    unconfirmed anchor and the check of a clock ahead of the host's since added to both)."""

    def admit(self, sample: SensorSample, now: float | None = None) -> Verdict:
        t = sample.t_s
        reason = self._reason(sample)
        if reason is not None:
            return self._drop(reason)
        newest = self.newest
        ahead = newest + JUMP_S + (0.0 if now is None else max(now - self._newest_at, 0.0))
        if newest > -math.inf and (t < newest - JUMP_S or t > ahead or self._ahead_of_host(t, now)):
            side = -1 if t < newest else 1
            if self._run_side != side or not self._run_last <= t <= self._run_last + JUMP_S:
                self._run_side, self._run_count, self._run_first = side, 0, t  # (re)start the run
            self._run_count += 1
            self._run_last = t
            if self._run_count >= REANCHOR_READINGS and t - self._run_first >= REANCHOR_SPAN_S:
                return self._reanchor(sample, Verdict.RESTART if side < 0 else Verdict.JUMP, now)
            return self._drop("past" if side < 0 else "future")
        self._run_side = 0
        last = self._last.get(sample.kind)
        if last is not None:
            if t == last:
                return self._drop("duplicate")
            if t < last:  # added since: the merger's out_of_order, dropped and counted here
                return self._drop("out_of_order")
            if last < t < last + MIN_INTERVAL_S:
                return self._drop("burst")
        if newest == -math.inf:  # the stream's first reading anchors its clock, unconfirmed
            self._anchor(t)
        self._accept(sample, now)
        return Verdict.ACCEPT


ABSURD = [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e160, -1e160, 5e-324, 40.0, -40.0, 172.6, 5000.0]
VALUES = st.one_of(st.floats(-6000.0, 6000.0), st.sampled_from(ABSURD))
TIMES = st.one_of(
    st.integers(0, 300).map(lambda k: k * 0.005),
    st.floats(-5.0, 20.0),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e160, -0.0]),
)
SAMPLES = st.builds(SensorSample, TIMES, st.sampled_from(KINDS), st.tuples(VALUES, VALUES, VALUES))
LIMIT = st.sampled_from([40.0, 172.6, 5000.0, math.inf, math.nan, 0.0, -1.0, 1e-300])
LIMITS = st.one_of(st.just(ReadingLimits()), st.builds(ReadingLimits, LIMIT, LIMIT, LIMIT))


@settings(max_examples=300, deadline=None)
@given(LIMITS, st.lists(st.tuples(SAMPLES, st.one_of(st.none(), st.floats(0.0, 30.0))), max_size=50))
def test_admission_is_the_reference_reading_for_reading(limits, stream):
    fast, oracle = PhoneGuard(limits), ReferenceGuard(limits)
    for sample, now in stream:
        assert fast.admit(sample, now) == oracle.admit(sample, now)
        assert fast.last_reason == oracle.last_reason
        assert fast.newest == oracle.newest or (math.isnan(fast.newest) and math.isnan(oracle.newest))
    assert fast.as_dict() == oracle.as_dict()


def test_new_limits_take_effect_and_an_infinite_limit_lets_no_infinity_through():
    guard = PhoneGuard()
    gyr = KINDS[0]
    assert guard.admit(SensorSample(0.0, gyr, (50.0, 0.0, 0.0))) is Verdict.DROP
    assert guard.last_reason == "out_of_range"
    guard.limits = ReadingLimits(gyr=math.inf)
    assert guard.admit(SensorSample(0.01, gyr, (1e300, 0.0, 0.0))) is Verdict.ACCEPT
    assert guard.admit(SensorSample(0.02, gyr, (math.inf, 0.0, 0.0))) is Verdict.DROP
    assert guard.last_reason == "non_finite"
