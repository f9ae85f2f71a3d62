"""A rotor measured far beyond the spacecraft's fastest speed (:meth:`hil.runtime.actuators.ActuatorWatch
.rotor_speeds`): a board whose telemetry read a rotor at 2 500 rad/s (the wire's limit; the spacecraft's
fastest is 628 rad/s) was shown live and steered on, with no record. Now it is ``rotor_overspeed`` in the
fault journal (a note: the host stays in control), ``events.jsonl`` and a warning, once per unit and run;
a rotor within its speed is never reported."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_actuator_watch_fast import Recorder

from firmware_sim.board.actuators import UnitModel
from hil.runtime import RunOptions, run
from hil.runtime.actuators import OVERSPEED, ActuatorWatch
from hil.runtime.record import RunRecorder
from protocol.messages import ROTOR_SPEED_LIMIT
from tests.fault_support import short_scenario

N = 4
MAX_SPEED = 628.3
SPEED = st.one_of(
    st.floats(-ROTOR_SPEED_LIMIT, ROTOR_SPEED_LIMIT),
    st.sampled_from([0.0, -0.0, MAX_SPEED, OVERSPEED * MAX_SPEED, -OVERSPEED * MAX_SPEED, ROTOR_SPEED_LIMIT]),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(SPEED, min_size=N, max_size=N), max_size=40))
def test_each_rotor_beyond_its_speed_is_reported_once_and_none_within(ticks):
    seen = Recorder()
    watch = ActuatorWatch(N, seen, seen, 50.0, MAX_SPEED)  # type: ignore[arg-type]
    first: dict[int, tuple[float, float]] = {}
    for k, rotor in enumerate(ticks):
        watch.rotor_speeds(0.02 * k, rotor)
        for unit, speed in enumerate(rotor):
            if abs(speed) > OVERSPEED * MAX_SPEED:
                first.setdefault(unit, (0.02 * k, speed))
    noted = [c for c in seen.calls if c[0] == "note"]
    assert [(c[1], dict(c[3])["unit"], dict(c[3])["measured"]) for c in noted] == sorted(
        (t, unit, speed) for unit, (t, speed) in first.items()
    )
    assert [c[2] for c in seen.calls] == ["rotor_overspeed"] * (2 * len(first))


def _runaway(factor: float, after_reads: int) -> Any:
    """UnitModel.state with the first unit asked for its state read ``factor`` × its rotor's speed (at
    most the wire's limit) from its ``after_reads``-th read on (its telemetry: 50 a second)."""
    state = UnitModel.state
    first: list[UnitModel] = []
    reads = [0]

    def read(self: UnitModel) -> Any:
        got = state(self)
        if not first:
            first.append(self)
        if self is not first[0]:
            return got
        reads[0] += 1
        if reads[0] < after_reads:
            return got
        speed = min(got.rotor_speed * factor, ROTOR_SPEED_LIMIT)
        return got.__class__(got.gimbal_angle, got.gimbal_rate, speed)

    return read


@pytest.mark.parametrize("factor", [1.0, 4.0])
def test_a_rotor_read_at_four_times_its_speed_in_a_run_is_reported(monkeypatch, factor):
    monkeypatch.setattr(UnitModel, "state", _runaway(factor, 250))  # ~5 s in
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    run(sc, RunOptions(out_root=None, observer=recorder, rows_to_observer=True))
    over = [f for f in recorder.summary["faults"] if f["kind"] == "rotor_overspeed"]
    if factor == 1.0:
        assert over == []
        return
    assert len(over) == 1 and over[0]["unit"] == 0 and over[0]["measured"] > OVERSPEED * MAX_SPEED
    assert [e["kind"] for e in recorder.events].count("rotor_overspeed") == 1
