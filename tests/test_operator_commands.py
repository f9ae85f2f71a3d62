"""Operator commands as first-class run events (issue 25, finding 2): a Disarm suspends the run — no
reference, no setpoints, no requirement clock, no re-arming — an Arm warms it up again (spin-up, checks,
a new slew to the target), both are in the summary, and a run left disarmed does not say "completed".

The commands go through :class:`hil.runtime.operator.ScheduledOperator`, the path the ground station's and
a fault campaign's commands take, in lockstep against the emulated board and its world.
"""

from __future__ import annotations

import numpy as np

from hil.cli.run import exit_status, format_summary
from hil.runtime import RunOptions, run
from hil.runtime.host import Phase
from hil.runtime.operator import OperatorCommand, ScheduledOperator
from hil.runtime.runlog import read_events, read_telemetry
from hil.scenario import load_scenario


def _run(tmp_path, schedule, duration_s):
    sc = load_scenario("cubesat-1u")
    commands = [(t, OperatorCommand(i + 1, name, origin="test")) for i, (t, name) in enumerate(schedule)]
    operator = ScheduledOperator(commands)
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=duration_s, observer=operator))
    events, bad = read_events(result.run_dir / "events.jsonl")
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    assert bad == 0 and tel.dropped_lines == 0
    return sc, result, events, tel


def _t(events, kind, after=-np.inf, **match):
    def fits(e):
        return e["kind"] == kind and e["t"] > after and all(e.get(k) == v for k, v in match.items())

    return next(e["t"] for e in events if fits(e))


def test_a_disarm_suspends_the_run_and_an_arm_warms_it_up_again(tmp_path):
    """Disarm mid-slew at 9 s, Arm at 16 s: nothing of the warm-up happens before the Arm, the reference
    does not move meanwhile, and after the Arm the rotors spin up to nominal before a new slew, which
    settles (the requirement clock stood still while the run was suspended)."""
    sc, result, events, tel = _run(tmp_path, [(9.0, "disarm"), (16.0, "arm")], duration_s=35.0)
    s = result.summary
    disarm = _t(events, "command", command="disarm", status="sent")
    arm = _t(events, "command", command="arm", status="sent")
    between = [e for e in events if disarm <= e["t"] < arm]
    assert not [e for e in between if e["kind"] in ("spin_up", "resume", "recovery_start", "slew_start")]
    assert _t(events, "suspended") == disarm
    t, phase = tel["t"], tel["phase"]
    suspended = (t > disarm + 0.05) & (t < arm)
    assert suspended.any() and np.all(phase[suspended] == Phase.SUSPENDED)
    assert np.all(np.isnan(tel["track_err_deg"][suspended]))  # no reference while suspended
    assert np.all(tel["board_state"][suspended] != 2)  # the board stays disarmed until the Arm
    restart = _t(events, "recovery_start", after=arm - 1e-9, reason="operator_arm")
    spin = _t(events, "spin_up", after=restart - 1e-9)
    resume = _t(events, "resume", after=spin)
    nominal = sc.spacecraft.nominal_rotor_speed
    at_resume = np.searchsorted(t, resume)
    rotors = np.array([tel[f"rotor_speed_{i}"][at_resume] for i in range(sc.n_units)])
    assert np.all(np.abs(rotors - nominal) <= 0.05 * nominal), rotors
    assert s["exit"] == "completed" and exit_status(s) == 0
    assert s["settled"] and s["final_error_deg"] <= sc.settle_deg
    # the rotors at nominal at the end too, the array well away from a singularity (before the fix: the
    # rotors at 265/379/380/369 rad/s, δ 0.54-0.60; a recovery's gimbal angles differ from a run without one)
    end = np.array([tel[f"rotor_speed_{i}"][-1] for i in range(sc.n_units)])
    assert np.all(np.abs(end - nominal) <= 0.05 * nominal), end
    assert tel["delta"][-1] > 0.75
    assert abs(s["suspended_s"] - (arm - disarm)) < 0.05
    ops = [(o["command"], o["status"], o["origin"]) for o in s["operator"]]
    assert ops == [("disarm", "acked", "test"), ("arm", "acked", "test")]
    printed = format_summary(s)
    assert "operator" in printed and "disarm" in printed and "arm" in printed


def test_a_run_left_disarmed_by_the_operator_does_not_say_completed(tmp_path):
    _, result, events, _ = _run(tmp_path, [(5.8, "disarm")], duration_s=10.0)
    s = result.summary
    assert s["exit"].startswith("disarmed by the operator at t=5.8")
    assert exit_status(s) == 1
    assert s["operator"][0]["command"] == "disarm" and s["suspended_at_end"] is not None
    assert "disarmed by the operator" in format_summary(s)
    # the time limit still ends it: no hang while nobody re-arms
    assert s["sim_s"] < 2.0 + 10.0 + 25.0 + 15.0 + 5.0


def test_faults_while_suspended_do_not_restart_the_warm_up_and_the_arm_brings_it_back(tmp_path):
    """A link stall (the board fails safe) while the operator has the run disarmed changes nothing until
    the Arm; the Arm then re-arms and warms up as after any recovery."""
    sc = load_scenario("cubesat-1u").with_changes(fault_options={"stall": ["10.0:0.5"]})
    operator = ScheduledOperator(
        [(8.0, OperatorCommand(1, "disarm", origin="test")), (13.0, OperatorCommand(2, "arm", origin="test"))]
    )
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=30.0, observer=operator))
    events, _ = read_events(result.run_dir / "events.jsonl")
    s = result.summary
    assert not [e for e in events if 8.0 < e["t"] < 13.0 and e["kind"] in ("rearmed", "spin_up", "resume")]
    assert _t(events, "resume", after=13.0) > 13.0
    assert s["exit"] == "completed" and s["settled"]


def test_an_operators_arm_lost_in_a_stall_is_carried_on_by_the_host(tmp_path):
    """The operator's Arm goes out while the link carries nothing (a campaign's finding: the Arm failed,
    the host then waited for an armed board nobody armed, and lost it 15 s later): the host re-arms
    through the protocol once the link carries again, and the run completes."""
    sc = load_scenario("cubesat-1u").with_changes(fault_options={"stall": ["16.0:1.2"]})
    operator = ScheduledOperator(
        [
            (10.0, OperatorCommand(1, "disarm", origin="test")),
            (16.3, OperatorCommand(2, "arm", origin="test")),
        ]
    )
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=30.0, observer=operator))
    events, _ = read_events(result.run_dir / "events.jsonl")
    s = result.summary
    assert [o["status"] for o in s["operator"]] == ["acked", "failed"]
    assert _t(events, "rearm_for_operator") > 16.3
    assert _t(events, "rearmed", after=16.3) > 16.3
    assert s["exit"] == "completed" and s["lost"] is None


def test_an_arm_that_cannot_go_out_leaves_the_run_suspended_and_the_board_disarmed(tmp_path):
    """The operator's Arm while the board's cable is out (no session: refused). A campaign found the host
    then taking the board for its own again and re-arming it after the reconnect — armed and live while
    the run still said suspended. Now nothing changes: refused, the board comes back disarmed and stays so,
    the run ends disarmed by the operator."""
    sc = load_scenario("cubesat-1u").with_changes(fault_options={"unplug": ["9.0:2.0"]})
    operator = ScheduledOperator(
        [(6.0, OperatorCommand(1, "disarm", origin="test")), (10.0, OperatorCommand(2, "arm", origin="test"))]
    )
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=10.0, observer=operator))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    s = result.summary
    assert [o["status"] for o in s["operator"]] == ["acked", "refused"]
    assert s["rearms"] == 0
    after = (tel["t"] > 12.0) & (tel["board_link"] == 0)
    assert after.any() and not np.any(tel["board_state"][after] == 2)  # never armed again
    assert s["exit"].startswith("disarmed by the operator")
