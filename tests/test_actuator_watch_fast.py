"""The host's actuator watch on the control tick (:meth:`hil.runtime.actuators.ActuatorWatch.following`,
issue 29: host speed) against the check it replaced, kept as its oracle
(:meth:`~hil.runtime.actuators.ActuatorWatch.following_reference`): fed the same ticks — rotors that lag
their setpoints, gimbals that stick, NaN, ±0 and absurd speeds, mode changes — both report the same
actuators at the same moments with the same figures, and keep the same record of what is off."""

from __future__ import annotations

import math
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.runtime.actuators import ActuatorWatch
from protocol.messages import ActuatorSetpoint, GimbalMode, UnitSetpoint, UnitState


class Recorder:
    """Stands in for the fault journal and the event log: what was noted, in order."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []

    def note(self, t: float, kind: str, **fields: Any) -> None:
        self.calls.append(("note", t, kind, sorted(fields.items())))

    def write(self, t: float, kind: str, **fields: Any) -> None:
        self.calls.append(("write", t, kind, sorted(fields.items())))


N = 4
SPEED = st.one_of(st.floats(-700.0, 700.0), st.sampled_from([math.nan, 0.0, -0.0, 1e160, -1e160, 600.0]))
RATE = st.one_of(st.floats(-0.02, 0.02), st.sampled_from([math.nan, 0.0, -0.0, 1e160, 0.002, -0.002]))
TICK = st.tuples(
    st.floats(0.0, 0.5),  # time to the next tick
    st.sampled_from([GimbalMode.RATE, GimbalMode.RATE, GimbalMode.ANGLE]),
    st.lists(st.tuples(RATE, SPEED, RATE, SPEED), min_size=N, max_size=N),  # asked and measured
)


def _pair() -> tuple[ActuatorWatch, ActuatorWatch, Recorder, Recorder]:
    a, b = Recorder(), Recorder()
    return ActuatorWatch(N, a, a, 50.0, 628.3), ActuatorWatch(N, b, b, 50.0, 628.3), a, b  # type: ignore[arg-type]


@settings(max_examples=200, deadline=None)
@given(st.lists(TICK, max_size=60), st.booleans())
def test_the_watch_reports_as_the_reference_does(ticks, steady):
    fast, oracle, seen_fast, seen_oracle = _pair()
    t = 0.0
    for k, (dt, mode, per_unit) in enumerate(ticks):
        t += dt
        if steady and k % 3:  # long stretches of one lagging state, so that LAG_S runs out
            per_unit = [(0.01, 700.0, 0.0, 0.0)] * N
        command = ActuatorSetpoint(mode, tuple(UnitSetpoint(g, w) for g, w, _, _ in per_unit))
        units = [UnitState(0.0, rate, speed) for _, _, rate, speed in per_unit]
        rotor = [speed for _, _, _, speed in per_unit]
        fast.following(t, rotor, units, command)
        oracle.following_reference(t, rotor, units, command)
        assert seen_fast.calls == seen_oracle.calls
        assert fast._since == oracle._since and fast._noted == oracle._noted


def test_a_rotor_that_lags_and_a_gimbal_that_sticks_are_reported_once():
    fast, _, seen, _ = _pair()
    command = ActuatorSetpoint(GimbalMode.RATE, tuple(UnitSetpoint(0.01, 700.0) for _ in range(N)))
    units = [UnitState(0.0, 0.0, 600.0) for _ in range(N)]
    for k in range(150):
        fast.following(0.02 * k, [600.0] * N, units, command)
    kinds = [(call[2], dict(call[3])["unit"]) for call in seen.calls if call[0] == "note"]
    assert sorted(kinds) == sorted(
        [("rotor_not_following", i) for i in range(N)] + [("gimbal_not_following", i) for i in range(N)]
    )
