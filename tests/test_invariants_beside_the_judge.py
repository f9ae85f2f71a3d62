"""The fault campaigns' judge (:func:`hil.runtime.invariants.check_run`) on synthetic run records: each
case a run that broke the standard in a way the judge once passed, beside the honest run it differs from.
(Real faulted runs through the judge: tests/test_fault_campaign.py, tests/test_fault_overlaps.py, ...)"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hil.runtime.faults import BoardLink
from hil.runtime.invariants import Bounds, InjectedFault, InvariantReport, check_run

NOMINAL = 500.0
B = Bounds(
    stale_after_s=0.25,
    tick_s=0.02,
    telemetry_s=0.05,
    phone_period_s=0.02,
    reconnect_max_s=1.0,
    recover_within_s=15.0,
    time_limit_s=80.0,
    nominal_rotor=NOMINAL,
    duration_s=40.0,
)
SLEW_AT = 4.0


class Record:
    """What check_run reads of a RunRecorder."""

    def __init__(self, rows: dict[str, np.ndarray], events: list[dict[str, Any]], summary: dict[str, Any]):
        self._rows, self.events, self.summary = rows, events, summary
        self.pulses_recorded = False
        self.unsafe_frames = self.frames_missed = 0
        self.unsafe_examples: list[str] = []

    def rows(self) -> dict[str, np.ndarray]:
        return self._rows


def rows(t1: float = SLEW_AT + 40.0) -> dict[str, np.ndarray]:
    """A healthy run's rows: live, ARMED, fresh telemetry and phone, rotors at nominal; slew then hold."""
    t = np.arange(0.02, t1 + 1e-9, 0.02)
    k = len(t)
    return {
        "t": t,
        "phase": np.where(t < SLEW_AT, 0.0, np.where(t < SLEW_AT + 10, 1.0, 2.0)),
        "board_link": np.full(k, float(BoardLink.LIVE)),
        "tel_age_ms": np.full(k, 10.0),
        "phone_age_ms": np.full(k, 5.0),
        "board_state": np.full(k, 2.0),
        "rotor_speed": np.full((k, 4), NOMINAL),
        "board_values": np.ones(k, dtype=bool),
    }


def silent(r: dict[str, np.ndarray], t0: float, t1: float, link: BoardLink = BoardLink.STALE) -> None:
    """The host saw the board ``link`` (no values) over [t0, t1)."""
    w = (r["t"] >= t0) & (r["t"] < t1)
    r["board_link"][w], r["board_values"][w], r["tel_age_ms"][w] = float(link), False, 300.0


def judge(injected=(), r=None, events=None, bounds: Bounds = B, **summary: Any) -> InvariantReport:
    """check_run on ``injected`` faults and a healthy record but ``r`` (rows), ``events`` and ``summary``,
    to ``bounds``."""
    s: dict[str, Any] = {
        "exit": "completed",
        "sim_s": 44.0,
        "slew_started": True,
        "lost": None,
        "faults": [],
        "operator": [],
        "outages": [],
        "phone_gap_list": [],
        "requirement": {"met": True},
        "link": {},
        "suspended_at_end": None,
    }
    s.update(summary)
    ev = [{"t": 0.0, "kind": "armed"}, {"t": SLEW_AT, "kind": "slew_start"}] if events is None else events
    return check_run(list(injected), Record(rows() if r is None else r, ev, s), bounds)  # type: ignore[arg-type]


def test_steering_on_no_phone_sample_at_all_is_stale_as_live():
    r = rows()
    r["phone_age_ms"][(r["t"] > 10.0) & (r["t"] < 20.0)] = np.nan  # steering, no phone sample
    assert judge().ok
    assert judge(r=r).violations["no_stale_as_live"]


def test_a_record_without_rows_or_events_is_no_run_unless_it_ended_before_its_first_tick():
    empty = {k: v[:0] for k, v in rows().items()}
    assert judge(r=empty).violations["no_crash_or_hang"]
    assert judge(events=[]).violations["no_crash_or_hang"]
    assert judge(r=empty, events=[], exit="aborted: the board refused to arm").ok


def test_completed_needs_the_board_live_and_armed_at_the_end_and_nothing_open():
    lost = rows()
    silent(lost, 43.0, 99.0, BoardLink.LOST)
    outage = {"start": 43.0, "end": None, "duration_s": 1.0, "causes": ["link_lost"], "recovered": False}
    assert judge(r=lost, outages=[outage]).violations["honest_exit"]
    disarmed = rows()
    disarmed["board_state"][disarmed["t"] > 39.0] = 1.0
    assert judge(r=disarmed).violations["honest_exit"]
    gap = {"start": 43.5, "end": None, "duration_s": 0.5, "causes": ["phone_gap"], "recovered": False}
    assert judge(phone_gap_list=[gap]).violations["honest_exit"]


def test_one_report_is_credited_to_one_fault_of_its_unit_and_never_before_it():
    dead = [InjectedFault("dead_esc", 10.0, {"channel": 1}), InjectedFault("dead_esc", 10.5, {"channel": 5})]
    unit0 = {"t": 11.2, "kind": "rotor_not_following", "unit": 0}
    assert judge(dead, faults=[unit0, {**unit0, "t": 11.8, "unit": 2}]).ok
    assert judge(dead, faults=[unit0]).violations["faults_detected"]  # unit 2's never said
    spoofs = [InjectedFault("phone_spoof", 20.0, {"spoof": "huge"})]
    note = {"t": 20.01, "kind": "readings_dropped", "reason": "out_of_range", "since_last": 1}
    assert judge(spoofs, faults=[note]).ok
    spoofs.append(InjectedFault("phone_spoof", 20.08, {"spoof": "saturated"}))
    assert judge(spoofs, faults=[note]).violations["faults_detected"]  # one reading dropped, not two
    assert judge(spoofs[:1], faults=[{**note, "t": 19.95}]).violations["faults_detected"]  # before it


def test_a_reset_s_cause_is_checked_unless_its_episode_merged_resets():
    journal = [
        {"t": 10.5, "kind": "reset", "cause": "WATCHDOG"},  # wrong: it browned out
        {"t": 19.27, "kind": "stale"},
        {"t": 19.9, "kind": "reset", "cause": "WATCHDOG"},
    ]
    r = rows()
    silent(r, 19.27, 19.9)
    faults = [InjectedFault("brownout", 10.0), InjectedFault("hang", 19.0)]
    assert judge(faults, r, faults=journal).violations["faults_detected"]
    journal[0]["cause"] = "BROWN_OUT"
    assert judge(faults, r, faults=journal).ok


@pytest.mark.parametrize(
    "dead, ok",
    [
        ([], False),
        ([InjectedFault("dead_esc", 15.0, {"channel": 0})], False),  # a gimbal servo: the rotors fine
        ([InjectedFault("dead_esc", 99.0, {"channel": 1})], False),  # after the run
        ([InjectedFault("dead_esc", 15.0, {"channel": 1})], True),  # unit 0's rotor: exempt
    ],
)
def test_rotors_at_nominal_when_steering_again_but_a_dead_one(dead, ok):
    r = rows()
    r["rotor_speed"][(r["t"] >= 20.0) & (r["t"] < 20.1), 0] = 0.1 * NOMINAL
    events = [
        {"t": 0.0, "kind": "armed"},
        {"t": SLEW_AT, "kind": "slew_start"},
        {"t": 20.0, "kind": "resume"},
    ]
    journal = [{"t": 16.0, "kind": "esc_dead"}] if dead and dead[0].t < 44 else []
    assert (not judge(dead, r, events, faults=journal).violations["back_in_control"]) is ok


def test_only_suspensions_after_the_slew_s_start_move_its_end():
    r = rows(t1=10.0 + 46.0)  # 6 s past its due
    events = [
        {"t": 0.0, "kind": "armed"},
        {"t": 1.0, "kind": "suspension_start"},
        {"t": 7.0, "kind": "suspension_end", "suspended_s": 6.0},
        {"t": 10.0, "kind": "slew_start"},
    ]
    late = judge([], r, events, suspended_s=6.0, suspended_after_slew_s=0.0, sim_s=56.0)
    assert any("due to end" in v for v in late.violations["honest_exit"])
    assert judge([], r, events, suspended_s=6.0, suspended_after_slew_s=6.0, sim_s=56.0).ok


def test_a_dead_esc_is_due_after_the_next_live_armed_stretch_not_masked_for_good():
    dead = InjectedFault("dead_esc", 10.0, {"channel": 1})
    stall = InjectedFault("stall", 15.0, {"duration_s": 0.3})
    r = rows()
    silent(r, 15.27, 15.34)
    stale = {"t": 15.27, "kind": "stale"}
    assert judge([dead, stall], r, faults=[stale]).violations["faults_detected"]
    assert judge([dead, stall], r, faults=[stale, {"t": 21.0, "kind": "esc_dead"}]).ok
    r["board_state"][r["t"] > 16.0] = 1.0  # disarmed for the rest of the run: it could not be told
    report = judge([dead, stall], r, faults=[stale], exit="disarmed by the operator")
    assert not report.violations["faults_detected"] and report.unseen


def test_a_stall_past_the_board_s_link_timeout_is_expected_a_shorter_one_listed_unseen():
    longer = [InjectedFault("stall", 6.0, {"duration_s": 0.29})]
    assert judge(longer).violations["faults_detected"]
    assert judge(longer, faults=[{"t": 6.30, "kind": "failsafe"}]).ok
    shorter = judge([InjectedFault("stall", 6.0, {"duration_s": 0.2})])
    assert shorter.ok and shorter.unseen


@pytest.mark.parametrize(
    "fault, journal, silence",
    [
        (InjectedFault("stall", 10.0, {"duration_s": 3.0}), [{"t": 10.27, "kind": "stale"}], (10.27, 13.0)),
        (
            InjectedFault("hang", 20.0),
            [{"t": 20.27, "kind": "stale"}, {"t": 20.9, "kind": "reset", "cause": "WATCHDOG"}],
            (20.27, 20.9),
        ),
    ],
)
def test_a_row_live_while_the_board_was_silent_is_stale_as_live(fault, journal, silence):
    assert judge([fault], faults=journal).violations["no_stale_as_live"]  # the host's flags say LIVE
    r = rows()
    silent(r, *silence)
    assert judge([fault], r, faults=journal).ok


def test_a_dead_rotor_esc_on_a_board_that_senses_no_rotor_is_unseen_not_a_missed_detection():
    """The C firmware's board has no sensors on the units (its rotor speeds are estimates from its own
    outputs): a dead rotor ESC there can be told by nothing, and a seeded campaign through it (seed 778,
    run 6) flagged the run's silence about it a ``faults_detected`` violation. Unseen there, said why;
    on a board that senses its rotors the same silence stays a violation; a dead gimbal servo is judged
    as before on either."""
    import dataclasses

    blind = dataclasses.replace(B, rotors_sensed=False)
    for channel in (1, 3, 5, 7):
        dead = [InjectedFault("dead_esc", 10.0, {"channel": channel})]
        assert judge(dead).violations["faults_detected"]
        report = judge(dead, bounds=blind)
        assert report.ok, report.violations
        assert any("does not sense its rotors" in u for u in report.unseen), report.unseen
    gimbal = [InjectedFault("dead_esc", 10.0, {"channel": 4})]
    assert judge(gimbal).ok and judge(gimbal, bounds=blind).ok


def test_only_the_firmware_board_is_said_to_sense_no_rotor():
    from hil.montecarlo.runner import fault_bounds
    from hil.scenario import load_scenario

    scenario = load_scenario("cubesat-1u")
    assert fault_bounds(scenario).rotors_sensed
    assert fault_bounds(scenario.with_board("emulator")).rotors_sensed
    assert not fault_bounds(scenario.with_board("firmware")).rotors_sensed
