"""The run's phases as a state machine on their own (:class:`hil.runtime.phases.RunPhases`), driven tick by
tick without a board, a phone or a host: the first warm-up (still window at rest, spin-up, the settle
time) into the scenario's slew, the slew into the hold, a fault back into a recovery warm-up, and the
operator's suspension with its time kept off the run's clock."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import ArrayLike

from hil.runtime.faults import FaultJournal
from hil.runtime.phases import ROTOR_SETTLE_S, Phase, RunPhases
from hil.runtime.runlog import EventLog
from hil.scenario import load_scenario


class _Estimator:
    """What the phases need of an estimator: its bias, and rest learning on or off."""

    def __init__(self) -> None:
        self.gyro_bias = np.zeros(3)
        self.rest_learning = True

    def set_gyro_bias(self, bias: ArrayLike) -> None:
        self.gyro_bias = np.asarray(bias, dtype=float)

    def set_rest_learning(self, enabled: bool) -> None:
        self.rest_learning = enabled


def _kinds(events: EventLog) -> list[str]:
    return [e["kind"] for e in events.events]


def _through_first_warmup(phases: RunPhases, estimator: _Estimator, dt: float = 0.02) -> float:
    """Ticks with the rotors at rest through the still window, then at nominal speed until the slew starts;
    returns the slew's start (s)."""
    scenario = phases.scenario
    n = scenario.n_units
    rest, spun = np.zeros(n), np.full(n, phases.nominal_rotor_speed)
    attitude = np.eye(3)
    t = 0.0
    while phases.resting or phases.spinup_since is None:
        if phases.collecting_bias:
            phases.add_bias_sample(np.array([1e-3, -2e-3, 5e-4]))
        phases.warm_up(
            t, rest, ready=True, phone_fresh=True, attitude=attitude, estimator=estimator, esc_dead=False
        )
        t += dt
    while not phases.warm_up(
        t, spun, ready=True, phone_fresh=True, attitude=attitude, estimator=estimator, esc_dead=False
    ):
        t += dt
    return t


def test_the_first_warm_up_measures_the_bias_at_rest_then_spins_up_and_starts_the_slew():
    scenario = load_scenario()
    events = EventLog(None)
    phases = RunPhases(scenario, events, FaultJournal(), hold=False)
    estimator = _Estimator()
    assert phases.phase is Phase.WARMUP and phases.first_warmup
    start = _through_first_warmup(phases, estimator)
    assert phases.phase is Phase.SLEW and phases.slew_start == start
    assert phases.spun_since is not None and start - phases.spun_since >= ROTOR_SETTLE_S - 1e-9
    assert np.allclose(phases.gyro_bias, [1e-3, -2e-3, 5e-4])  # the window's second half, averaged
    assert np.allclose(estimator.gyro_bias, phases.gyro_bias) and not estimator.rest_learning
    assert _kinds(events) == ["still_window", "spin_up", "slew_start"]
    assert phases.slew is not None
    phases.finish_slew(start + phases.slew.duration_s)
    assert phases.phase is Phase.HOLD and _kinds(events)[-1] == "slew_end"


def test_a_fault_brings_a_recovery_warm_up_and_a_new_slew_to_the_same_target():
    scenario = load_scenario()
    events = EventLog(None)
    phases = RunPhases(scenario, events, FaultJournal(), hold=False)
    estimator = _Estimator()
    start = _through_first_warmup(phases, estimator)
    target = phases.target
    phases.restart_warmup(start + 1.0, "failsafe", still=False)
    assert phases.phase is Phase.WARMUP and not phases.need_still
    assert _kinds(events)[-1] == "recovery_start"
    spun = np.full(scenario.n_units, phases.nominal_rotor_speed)
    assert phases.warm_up(
        start + 1.1,
        spun,
        ready=True,
        phone_fresh=True,
        attitude=np.eye(3),
        estimator=estimator,
        esc_dead=False,
    )
    assert phases.phase is Phase.SLEW and phases.target is target and phases.slew_start == start
    assert _kinds(events)[-2:] == ["spin_up", "resume"]


def test_the_operators_suspension_holds_faults_and_moves_the_run_clock():
    scenario = load_scenario()
    events = EventLog(None)
    phases = RunPhases(scenario, events, FaultJournal(), hold=False)
    start = _through_first_warmup(phases, _Estimator())
    phases.suspend(start + 2.0, "gcs")
    assert phases.phase is Phase.SUSPENDED
    phases.restart_warmup(start + 3.0, "phone_gap", still=True)
    assert phases.phase is Phase.SUSPENDED and _kinds(events)[-1] == "fault_while_suspended"
    assert not phases.time_is_up(start + 1e6, 1.0)  # no requirement clock while suspended
    phases.end_suspension(start + 7.0, "gcs")
    assert phases.phase is Phase.WARMUP and phases.need_still  # the phone went away meanwhile
    assert _kinds(events)[-2:] == ["recovery_start", "suspension_end"]
    assert phases.suspended_s == pytest.approx(5.0) and phases.suspended_after_slew_s == pytest.approx(5.0)
    assert not phases.time_is_up(
        start + 14.9, 10.0
    )  # 9.9 s of the run's clock: the 5 s suspended not counted
    assert phases.time_is_up(start + 15.0, 10.0)


def test_no_tick_commands_the_rotors_before_the_first_still_window_at_rest_has_ended(tmp_path):
    """The first tick, before any telemetry, sent the blind hold — rotors at nominal speed — to a board
    already armed: its rotors were kicked to ~20 rad/s inside the still window that measures the gyro bias
    with them stopped (and a board hung then spun them up). Every command and every rotor speed before
    the spin-up is now zero."""
    from hil.runtime import RunOptions, run
    from hil.runtime.runlog import read_events, read_telemetry

    sc = load_scenario("cubesat-1u")
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=0.5))
    events = read_events(result.run_dir / "events.jsonl")[0]
    spin_up = next(e["t"] for e in events if e["kind"] == "spin_up")
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    before = tel["t"] < spin_up
    assert before.sum() > 50  # the still window's ticks (2 s at 50 Hz)
    for unit in range(sc.n_units):
        assert np.all(np.nan_to_num(tel[f"cmd_rotor_speed_{unit}"][before]) == 0.0)
        assert np.all(np.nan_to_num(tel[f"rotor_speed_{unit}"][before]) == 0.0)


@pytest.mark.parametrize(
    ("target", "said"),
    [
        (np.full((3, 3), np.nan), "not finite"),
        (np.diag([1.0, 1.0, np.inf]), "not finite"),
        (np.diag([1.0, 1.0, -1.0]), "not orthonormal"),  # a reflection
        (2.0 * np.eye(3), "not orthonormal"),
        (np.eye(2), "shape (2, 2)"),
        ([["a"] * 3] * 3, "not numbers"),
    ],
)
def test_a_retarget_to_what_is_not_a_rotation_is_refused_and_the_slew_kept(target, said):
    """A script's (or a plugin operator's) ``Host.retarget`` to a NaN matrix was taken: the slew planned to
    it gave NaN setpoints, and the run ended later on ``ActuatorSetpoint … = nan is out of range``, far
    from the cause. It is refused, saying why, and the slew under way is kept."""
    scenario = load_scenario()
    phases = RunPhases(scenario, EventLog(None), FaultJournal(), hold=False)
    start = _through_first_warmup(phases, _Estimator())
    slew, target_before = phases.slew, phases.target.copy()
    reason = phases.retarget(start + 1.0, np.eye(3), target)
    assert reason is not None and reason.startswith("the target is not a rotation") and said in reason
    assert phases.slew is slew and np.array_equal(phases.target, target_before)
    rounded = np.round(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) @ np.eye(3), 7)
    assert phases.retarget(start + 2.0, np.eye(3), rounded) is None  # a rotation within 1e-6 is taken
