"""The phone admission's per-reading clock tests spelt out in :meth:`PhoneGuard.admit` (issue 29: the
host's per-sample feed) against the admit that called ``_ahead_of_host`` and the builtin ``max``, kept
here verbatim as the oracle (:class:`CallingGuard`): the same verdict, reason and whole state after every
reading of any stream — host times absent, NaN, ±0, far, behind the stamps; stamps that jump, restart, run
fast or slow; absurd values."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.admission import (
    JUMP_S,
    MIN_INTERVAL_S,
    REANCHOR_READINGS,
    REANCHOR_SPAN_S,
    SLOW_WINDOW_S,
    PhoneGuard,
    Verdict,
)
from hil.estimation.sensors import KINDS, SensorKind, SensorSample


class CallingGuard(PhoneGuard):
    """:class:`PhoneGuard` with the admit it had before the clock tests were spelt out (verbatim)."""

    def admit(self, sample: SensorSample, now: float | None = None) -> Verdict:
        t = sample.t_s
        xyz = sample.xyz
        limits = self.limits
        if limits is not self._limits_of:
            import sys

            self._limits_of = limits
            self._bounds = tuple(min(limits.limit(kind), sys.float_info.max) for kind in KINDS)
        bound = self._bounds[sample.kind]
        if not (
            len(xyz) == 3
            and t - t == 0.0
            and abs(xyz[0]) <= bound
            and abs(xyz[1]) <= bound
            and abs(xyz[2]) <= bound
        ):
            reason = self._reason(sample)
            if reason is not None:
                return self._drop(reason)
        newest = self.newest
        ahead = newest + JUMP_S + (0.0 if now is None else max(now - self._newest_at, 0.0))
        if newest > -math.inf and (t < newest - JUMP_S or t > ahead or self._ahead_of_host(t, now)):
            side = -1 if t < newest else 1
            if self._run_side != side or not self._run_last <= t <= self._run_last + JUMP_S:
                self._run_side, self._run_count, self._run_first = side, 0, t
            self._run_count += 1
            self._run_last = t
            if self._run_count >= REANCHOR_READINGS and t - self._run_first >= REANCHOR_SPAN_S:
                return self._reanchor(sample, Verdict.RESTART if side < 0 else Verdict.JUMP, now)
            return self._drop("past" if side < 0 else "future")
        self._run_side = 0
        if now is not None:
            offset = now - t
            if offset < self._window_least:
                self._window_least = offset
            if now - self._window_at >= SLOW_WINDOW_S:
                self._judge_rate(now)
            if self.slow:
                return self._drop("slow_clock")
        last = self._last.get(sample.kind)
        if last is not None:
            if t == last:
                return self._drop("duplicate")
            if t < last:
                return self._drop("out_of_order")
            if t < last + MIN_INTERVAL_S:
                return self._drop("burst")
        if newest == -math.inf:
            self._anchor(t)
        self._accept(sample, now)
        return Verdict.ACCEPT


def _state(guard: PhoneGuard) -> str:
    """Every attribute, floats by ``repr`` (so NaN equals NaN and -0.0 differs from 0.0)."""
    return repr(sorted((k, repr(v)) for k, v in vars(guard).items() if k not in ("limits", "_limits_of")))


ODD = [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e160, -1e160, 5e-324, -5e-324]
VALUES = st.one_of(st.floats(-50.0, 50.0), st.sampled_from([*ODD, 40.0, 172.6, 5000.0]))


STEPS = st.one_of(
    st.just(0.005),
    st.just(0.0),
    st.just(MIN_INTERVAL_S / 2),
    st.floats(-2.0, 2.0),
    st.sampled_from([JUMP_S, -JUMP_S, JUMP_S + 1e-9, 100.0, -100.0, 1e9]),
)
LAGS = st.one_of(st.just(0.0), st.floats(-5.0, 5.0), st.sampled_from([-JUMP_S, JUMP_S, *ODD]))
STAMPS = st.sampled_from([None] * 12 + ODD)  # mostly the clock's own stamp
READINGS = st.tuples(STEPS, st.sampled_from(KINDS), VALUES, LAGS, st.integers(0, 9), STAMPS)


@st.composite
def streams(draw) -> list[tuple[SensorSample, float | None]]:
    """A phone stream on a clock that may run at any rate against the host's, lag it, jump, restart or
    stop, with host times that may be absent, odd or go back, and readings at the guard's edges."""
    rate = draw(st.sampled_from([1.0, 0.5, 1.05, 1.2, 2.0, 0.9]))
    t = draw(st.floats(-10.0, 1e4))
    host = draw(st.floats(0.0, 100.0))
    out = []
    for dt, kind, value, lag, pick, odd in draw(st.lists(READINGS, min_size=1, max_size=60)):
        t += dt
        host += abs(dt) / rate
        stamp = t if odd is None else odd
        now = None if pick == 0 else host + lag
        xyz = (value, 0.1, -0.2) if pick % 2 else (0.1, value, 9.8)
        out.append((SensorSample(stamp, SensorKind(kind), xyz), now))
    return out


@settings(max_examples=300, deadline=None)
@given(streams())
def test_admission_is_the_calling_admit_reading_for_reading(stream):
    fast, oracle = PhoneGuard(), CallingGuard()
    for sample, now in stream:
        assert fast.admit(sample, now) is oracle.admit(sample, now), (sample, now)
        assert fast.last_reason == oracle.last_reason
        assert _state(fast) == _state(oracle), (sample, now)
    assert fast.as_dict() == oracle.as_dict()


def test_a_phone_clock_running_fast_is_still_caught_ahead_of_the_host():
    """The spelt-out test still says what ``_ahead_of_host`` says: a stream gaining 0.9 s per 5 ms of host
    time is ``future`` within a second of host time, and reanchors as a jump."""
    guard = PhoneGuard()
    verdicts = []
    for k in range(400):
        now = k * 0.005
        verdicts.append(guard.admit(SensorSample(k * 0.9, SensorKind.GYR, (0.0, 0.0, 0.0)), now))
    assert Verdict.DROP in verdicts and guard.stats.dropped["future"] > 0
