"""Fault campaigns (issue 25): the ``[faults]`` section of dispersion files, faults drawn over the whole
run, the invariants checked on what each run recorded, and ``hil montecarlo --dispersions faults`` end to
end with zero violations (a fixed seed, and a seed drawn and printed).

The checker's teeth are tested on runs that really break an invariant: a record with a row that shows a
stale board, a pulse frame above the safe width while disarmed, a run that says "completed" when its
board was lost, a fault nobody reported.
"""

from __future__ import annotations

import json
import os
import random
import sys

import numpy as np
import pytest

from hil.cli import main as hil_main
from hil.montecarlo import load_dispersions, parse_dispersions, read_runs
from hil.montecarlo.dispersions import draw
from hil.montecarlo.fault_plan import fault_options, operator_schedule, run_window_s
from hil.montecarlo.runner import fault_bounds, run_one
from hil.runtime import RunOptions, run
from hil.runtime.invariants import INVARIANTS, InjectedFault, check_run
from hil.runtime.observer import Observers
from hil.runtime.operator import ScheduledOperator
from hil.runtime.record import RunRecorder
from hil.scenario import load_scenario
from protocol.errors import ConfigError

SCENARIO = "cubesat-1u"


def _sc(duration_s=12.0):
    sc = load_scenario(SCENARIO)
    return sc.with_changes(slew=sc.slew.__class__(**{**sc.slew.__dict__, "duration_s": duration_s}))


# --------------------------------------------------------------------------- the [faults] section
@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("[faults]\nmeteor = { count = 1 }", "faults.meteor"),
        ("[faults]\nhang = { count = 1, per_minute = 2 }", "faults.hang"),
        ("[faults]\nhang = { }", "faults.hang"),
        ("[faults]\nstall = { count = 1 }", "faults.stall.duration_s"),
        ("[faults]\nstall = { count = 1, duration_s = 1e9 }", "faults.stall.duration_s"),
        ("[faults]\nstall = { count = 1, duration_s = 1, colour = 3 }", "faults.stall.colour"),
        ("[faults]\nphone_spoof = { count = 1, spoof = ['meteor'] }", "faults.phone_spoof.spoof"),
        ("[faults]\nhang = { per_minute = 1e9 }", "faults.hang.per_minute"),
        ("[faults]\nnoise = { count = 1, duration_s = 1, corrupt = 2 }", "faults.noise.corrupt"),
        ("[faults]\nhang = { count = 1e300 }", "faults.hang.count"),
        (
            "[faults]\nhang = { count = { dist = 'uniform', low = -1e308, high = 1e308 } }",
            "faults.hang.count",
        ),
        (
            "[faults]\nhang = { count = { dist = 'normal', mean = 1.7e308, sigma = 1e308 } }",
            "faults.hang.count",
        ),
        ("faults = 3", "faults"),
    ],
)
def test_a_bad_faults_section_names_file_and_key(text, where):
    with pytest.raises(ConfigError) as err:
        parse_dispersions(text, load_scenario(SCENARIO), "my.toml")
    assert f"my.toml: {where}" in str(err.value)


def test_faults_are_drawn_over_the_whole_run_a_pure_function_of_seed_and_index():
    """Times uniform over the run's whole span (handshake, warm-up, spin-up, slew, hold): over many runs
    every phase gets faults; the same (seed, index) gives the same faults; adding a kind leaves the
    others' draws alone."""
    sc = load_scenario(SCENARIO)
    one = parse_dispersions("[faults]\nhang = { count = 1 }", sc)
    two = parse_dispersions("[faults]\nhang = { count = 1 }\nabort = { count = 1 }", sc)
    window = run_window_s(sc)
    times = []
    for i in range(400):
        a, b = draw(one, 5, i), draw(two, 5, i)
        assert a.faults == draw(one, 5, i).faults
        assert [f for f in b.faults if f.kind == "hang"] == list(a.faults)
        times += [f.t for f in a.faults]
    t = np.array(times)
    assert t.min() >= 0 and t.max() < window
    warmup = sc.loop.warmup_s
    phases = [(0, 0.5), (0.5, warmup), (warmup, warmup + 2), (warmup + 2, warmup + 20), (warmup + 20, window)]
    for lo, hi in phases:  # every phase gets its share of a uniform draw
        share = np.mean((t >= lo) & (t < hi))
        assert share == pytest.approx((hi - lo) / window, abs=0.06), (lo, hi)


def test_draws_of_wide_distributions_stay_within_each_kind_s_range():
    """A normal whose tails pass a count's or a parameter's range (its mean in range, so the file is taken):
    every run's draw is clipped into the kind's range (it was an OverflowError for a count, and a phone
    clock jump of 1e300 s for an offset). A spread wider than the whole range is refused, naming the key."""
    text = (
        "[faults]\n"
        "hang = { count = { dist = 'normal', mean = 3, sigma = 90 } }\n"
        "phone_jump = { count = 2, offset_s = { dist = 'normal', mean = 0, sigma = 1e5 } }\n"
        "stall = { count = 2, duration_s = { dist = 'normal', mean = 1, sigma = 50 } }\n"
    )
    spec = parse_dispersions(text, load_scenario(SCENARIO), "wide.toml")
    for index in range(40):
        faults = draw(spec, 5, index).faults
        assert sum(f.kind == "hang" for f in faults) <= 100
        for f in faults:
            if f.kind == "phone_jump":
                assert -86_400.0 <= f.params["offset_s"] <= 86_400.0
            if f.kind == "stall":
                assert 0.0 < f.params["duration_s"] <= 60.0
    wider = "[faults]\nhang = { count = { dist = 'normal', mean = 3, sigma = 1e300 } }\n"
    with pytest.raises(ConfigError, match="wider than the whole range") as info:
        parse_dispersions(wider, load_scenario(SCENARIO), "wide.toml")
    assert info.value.where == "wide.toml: faults.hang.count.sigma"


def test_the_shipped_fault_file_has_every_kind_and_reaches_board_world_and_operator():
    from hil.runtime.invariants import FAULT_KINDS

    sc = load_scenario(SCENARIO)
    d = load_dispersions("faults", sc)
    assert d.faults is not None
    assert {k.kind for k in d.faults.kinds} == set(FAULT_KINDS)
    seen: set[str] = set()
    for i in range(200):
        faults = draw(d, 1, i).faults
        seen |= {f.kind for f in faults}
        options = fault_options(faults, {})
        assert len(operator_schedule(faults)) == sum(
            f.kind in ("disarm", "arm", "abort", "slew", "hold") for f in faults
        )
        board_faults = [f for f in faults if f.kind not in ("disarm", "arm", "abort", "slew", "hold")]
        assert sum(len(v) for v in options.values()) == len(board_faults)
    assert seen == set(FAULT_KINDS)


# --------------------------------------------------------------------------- the checker has teeth
def _recorded(sc, faults=(), schedule=()):
    recorder = RunRecorder(sc.n_units)
    observer = Observers(recorder, ScheduledOperator(list(schedule))) if schedule else recorder
    sc = sc.with_changes(fault_options=fault_options(tuple(faults), sc.fault_options))
    run(sc, RunOptions(out_root=None, observer=observer, rows_to_observer=True))
    return recorder


def test_a_clean_faulted_run_keeps_every_invariant():
    sc = _sc()
    faults = [InjectedFault("hang", 6.0), InjectedFault("phone_spoof", 8.0, {"spoof": "huge"})]
    report = check_run(faults, _recorded(sc, faults), fault_bounds(sc))
    assert report.ok, report.violations
    assert {k for k, _ in report.detection} == {"hang", "phone_spoof"}
    assert report.recovery


def test_the_checker_sees_a_fault_nobody_reported():
    """A fault the plan says was injected, that the run never saw (it was not injected): a violation."""
    sc = _sc()
    report = check_run([InjectedFault("brownout", 6.0)], _recorded(sc), fault_bounds(sc))
    assert report.violations["faults_detected"] and "brownout" in report.violations["faults_detected"][0]


def test_the_checker_sees_a_stale_row_an_unsafe_pulse_and_a_dishonest_exit():
    sc = _sc()
    recorder = _recorded(sc)
    k = len(recorder._rows) // 2
    row = list(recorder._rows[k])
    row[2] = 1.0  # board_link STALE, yet the row keeps its board values
    recorder._rows[k] = tuple(row)
    recorder.unsafe_frames, recorder.unsafe_examples = (
        1,
        ["frame at t=3.0 s: channel 1 at 1700 us while DISARMED"],
    )
    recorder.summary["lost"] = "board lost at t=5.000 s for 16.0 s (link_lost): not back within 15 s"
    report = check_run([], recorder, fault_bounds(sc))
    assert report.violations["no_stale_as_live"]
    assert report.violations["safe_when_not_armed"]
    assert report.violations["honest_exit"]  # "completed" while lost
    assert report.violations["back_in_control"]


def test_the_checker_sees_a_run_that_ran_past_its_end():
    sc = _sc()
    recorder = _recorded(sc)
    assert check_run([], recorder, fault_bounds(sc)).ok
    late = list(recorder._rows[-1])
    late[0] += 2.0  # a row 2 s after the run's end: it ran on (to a tick that saw the board again)
    recorder._rows.append(tuple(late))
    recorder._board_values.append(recorder._board_values[-1])
    report = check_run([], recorder, fault_bounds(sc))
    assert any("was due to end" in v for v in report.violations["honest_exit"])


def test_a_run_that_crashed_or_hung_is_a_violation():
    sc = _sc()
    report = check_run([], _recorded(sc), fault_bounds(sc), error="RunHung: no end after 280 s")
    assert report.violations["no_crash_or_hang"]


# --------------------------------------------------------------------------- faults at every phase
@pytest.mark.parametrize("at", [0.05, 0.6, 1.9, 2.6, 3.5, 9.0, 16.0])
def test_a_board_unplugged_and_plugged_back_in_any_phase_is_re_armed_and_steered_again(at):
    """The board restarted at moments spread over the run (the handshake, the still window, the spin-up,
    the slew's start, the slew, the hold): re-armed through the handshake, back in control, invariants
    kept (issue 25, finding 1 in lockstep: a board restarted during the warm-up never came back)."""
    sc = _sc(duration_s=30.0)
    faults = [InjectedFault("unplug", at, {"duration_s": 1.5})]
    recorder = _recorded(sc, faults)
    report = check_run(faults, recorder, fault_bounds(sc))
    assert report.ok, report.violations
    s = recorder.summary
    assert s["exit"] == "completed"
    armed = recorder.first_event("armed")
    if armed is not None and armed["t"] < at:  # a session was up: a reset to report and a re-arm
        assert s["board_resets"] >= 1 and s["rearms"] >= 1
        assert any(f["kind"] == "reset" and f["cause"] == "POWER_ON" for f in s["faults"])
    else:  # during the first handshake: tried again until the board is back (before: an error, exit 2)
        assert recorder.first_event("connect_retry") is not None


@pytest.mark.parametrize(
    "fault",
    [
        InjectedFault("unplug", 14.0, {"duration_s": 10.0}),  # out 1.7 s before the end, back long after
        InjectedFault("hang", 15.3),  # stale 0.1 s before the end
        InjectedFault("stall", 15.2, {"duration_s": 3.0}),
    ],
    ids=lambda f: f.kind,
)
def test_a_board_out_at_the_run_s_end_ends_the_run_then_lost_not_completed_at_its_return(fault):
    """A board the host cannot see when the run's time is up (12 s after the slew's start, at ~15.7 s):
    the run ends then, lost with its outage still on. It used to run on to the first tick that saw the
    board again — 9.5 s later for the unplug — and then say ``completed``, exit status 0."""
    sc = _sc(duration_s=12.0)
    recorder = _recorded(sc, [fault])
    report = check_run([fault], recorder, fault_bounds(sc))
    assert report.ok, report.violations
    s = recorder.summary
    assert s["exit"].startswith("lost:") and "not back when the run ended" in s["exit"]
    due = recorder.first_event("slew_start")["t"] + 12.0
    assert recorder.rows()["t"][-1] <= due + 1.0 / sc.loop.control_rate_hz + 1e-9


@pytest.mark.parametrize("offset_s", [-5.0, 100.0])
def test_a_phone_clock_that_restarts_or_jumps_is_no_phone_gap(offset_s):
    """The phone's clock moving (an app restarted: back; a clock stepped: forward) is a restart of the
    estimator, counted as such; the samples never paused, so no phone gap is counted or left open (it used
    to open one, ``phone_gaps`` 1 in the summary, and one opened at the end would have read as the phone
    lost)."""
    sc = _sc()
    faults = [InjectedFault("phone_jump", 8.0, {"offset_s": offset_s})]
    recorder = _recorded(sc, faults)
    report = check_run(faults, recorder, fault_bounds(sc))
    assert report.ok, report.violations
    s = recorder.summary
    assert s["exit"] == "completed" and s["phone_restarts"] == 1
    assert s["phone_gaps"] == 0 and s["phone_gap_list"] == []
    kind = "phone_restart" if offset_s < 0 else "phone_jump"
    assert [f["kind"] for f in s["faults"] if f["kind"].startswith("phone")] == [kind]


@pytest.mark.parametrize("late_s", [0.5, 2.0])
def test_a_phone_that_starts_streaming_late_gets_its_whole_still_window(late_s):
    """The phone silent for its first ``late_s`` (a phone gap from t = 0): the still window starts with its
    first samples, not at the first tick (it used to end 2 s later with 0.12 s of samples in it, the gyro
    bias 25 % off)."""
    sc = _sc()
    faults = [InjectedFault("phone_gap", 0.0, {"duration_s": late_s})]
    recorder = _recorded(sc, faults)
    assert check_run(faults, recorder, fault_bounds(sc)).ok
    still = recorder.first_event("still_window")
    spin_up = recorder.first_event("spin_up")
    assert still["t"] >= late_s
    assert spin_up["t"] - still["t"] >= sc.loop.warmup_s - 1e-9


def test_an_arm_that_could_not_reach_the_board_is_named_in_the_exit():
    """The operator's Disarm and Arm both while the board is unplugged: the Disarm's intent is kept (the
    board comes back disarmed), the Arm is refused (no session) and arms nothing; the exit says both,
    not a Disarm that was "not armed again" as though no Arm had come."""
    sc = _sc()
    faults = [
        InjectedFault("unplug", 8.0, {"duration_s": 3.0}),
        InjectedFault("disarm", 9.0),
        InjectedFault("arm", 10.0, {"after_disarm_s": 1.0}),
    ]
    recorder = _recorded(sc, faults, operator_schedule(tuple(faults)))
    assert check_run(faults, recorder, fault_bounds(sc)).ok
    exit_reason = recorder.summary["exit"]
    assert exit_reason.startswith("disarmed by the operator at t=9.0")
    assert "an Arm at t=10.0" in exit_reason and "refused" in exit_reason


# --------------------------------------------------------------------------- campaigns end to end
def _campaign(tmp_path, seed, runs, capsys):
    out = tmp_path / f"mc-{seed}"
    status = hil_main([
        "montecarlo", SCENARIO, "--dispersions", "faults", "--runs", str(runs), "--seed", str(seed),
        "--workers", "2", "--out", str(out), "--no-plots",
    ])  # fmt: skip
    captured = capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    return status, summary, captured.out + captured.err, out


def test_a_fault_campaign_with_a_fixed_seed_keeps_every_invariant(tmp_path, capsys):
    """40 runs, every fault kind among them, seed 25: zero invariant violations and exit 0; runs.csv has
    each run's faults and each invariant's verdict."""
    status, summary, text, out = _campaign(tmp_path, 25, 40, capsys)
    assert summary["invariant_violations"] == dict.fromkeys(INVARIANTS, 0), summary["first_violations"]
    assert status == 0, text
    assert summary["failed"] == 0 and summary["runs"] == 40
    assert len(summary["faults_injected"]) >= 12
    assert summary["detection_s"]["all"]["n"] > 20 and summary["recovery_s"]["all"]["n"] > 10
    results = read_runs(out)
    assert all(f"inv.{name}" in results.values for name in INVARIANTS)
    assert "faults.list" in results.text and "exit" in results.text
    assert "invariants       0 violations, in 0 of 40 runs:" in text  # how many were checked, said


def test_a_fault_campaign_with_a_drawn_seed_keeps_every_invariant(tmp_path, capsys):
    """10 runs with a seed drawn now (printed, so a failure can be rerun)."""
    seed = int(os.environ.get("FAULT_SEED", random.SystemRandom().randrange(1_000_000)))
    print(f"fault campaign seed {seed} (rerun with FAULT_SEED={seed})", file=sys.stderr)
    status, summary, text, _ = _campaign(tmp_path, seed, 10, capsys)
    assert summary["invariant_violations"] == dict.fromkeys(INVARIANTS, 0), (
        seed,
        summary["first_violations"],
    )
    assert status == 0, (seed, text)


def test_a_campaign_that_violates_an_invariant_exits_non_zero(tmp_path):
    from hil.cli.montecarlo import exit_status
    from hil.montecarlo.campaign import CampaignReport

    report = CampaignReport(tmp_path, 3, 0, 3, 0, 1.0, 1)
    report.summary = {"runs": 3, "failed": 0, "runs_with_violations": 1}
    status, why = exit_status(report)
    assert status == 1 and "violated an invariant" in why


def test_one_drawn_run_is_reproduced_by_its_seed_and_index():
    sc = _sc()
    d = load_dispersions("faults", sc)
    a = run_one(sc, draw(d, 7, 3), 5.0)
    b = run_one(sc, draw(d, 7, 3), 5.0)
    assert a.checks == b.checks and a.metrics == b.metrics


# --------------------------------------------------------------------------- what the campaigns found
def test_a_dead_rotor_esc_while_the_host_steers_is_reported():
    """A rotor ESC dies mid-slew: the rotor coasts down (in the world as on the board's model; before,
    the world's rotor kept its speed), and the host, whose setpoint follows the rotor down out of the
    board's detector's sight, reports it within the campaign's bound."""
    sc = _sc(duration_s=30.0)
    faults = [InjectedFault("dead_esc", 9.0, {"channel": 5})]
    recorder = _recorded(sc, faults)
    report = check_run(faults, recorder, fault_bounds(sc))
    assert report.ok, report.violations
    reported = [f for f in recorder.summary["faults"] if f["kind"] in ("rotor_not_following", "esc_dead")]
    assert reported and reported[0]["t"] < 9.0 + 8.0


def test_noise_all_within_a_stall_is_not_expected_to_damage_a_frame():
    """CI's drawn seed 44244, run 3: noise (4.9 % of bytes, 0.58 s) 13 ms into a 1.24 s stall — no byte on
    the link to damage. The judge took the stall's first 0.25 s, the board still shown live, for time the
    noise could damage frames in, and failed the honest run ("no damaged frame counted by either side").
    The same noise with the board talking is still expected to damage one."""
    sc = _sc(duration_s=6.0)
    noise = InjectedFault("noise", 9.013, {"duration_s": 0.581, "corrupt": 0.0488})
    faults = [InjectedFault("stall", 9.0, {"duration_s": 1.24}), noise]
    recorder = _recorded(sc, faults)
    report = check_run(faults, recorder, fault_bounds(sc))
    assert report.ok, report.violations
    link = recorder.summary["link"]
    assert not sum((link.get("bad_frames") or {}).values()) + (link.get("board_rx_bad") or 0)  # nothing hit
    recorder.summary["link"] = {**link, "bad_frames": {}, "board_rx_bad": 0}
    alone = check_run([noise], recorder, fault_bounds(sc))  # the same record, the noise on a live link
    assert any("no damaged frame" in v for v in alone.violations.get("faults_detected", [])), alone.violations


def test_a_rotor_that_never_spins_up_is_given_up_on_not_the_end_of_the_run():
    """A rotor ESC dead from the first warm-up: the run once ended in an error ("the rotors did not reach
    400 rad/s within 20 s"); now the host reports the unit, goes on with the array it has, and the run's
    requirement says why it was missed if it was."""
    sc = _sc(duration_s=15.0)
    faults = [InjectedFault("dead_esc", 0.5, {"channel": 1})]
    recorder = _recorded(sc, faults)
    s = recorder.summary
    assert not s["exit"].startswith("error"), s["exit"]
    failed = [f for f in s["faults"] if f["kind"] == "spin_up_failed"]
    assert failed and failed[0]["units"] == [0]
    assert s["requirement"]["met"] or s["requirement"]["explained"]
    assert check_run(faults, recorder, fault_bounds(sc)).ok


def test_a_handshake_after_a_reset_is_not_another_reconnect():
    """Once a session had reconnected, every later handshake (after a watchdog reset, say) counted as a
    reconnect too: the board's session count is cumulative."""
    sc = _sc(duration_s=20.0)
    faults = [InjectedFault("unplug", 4.0, {"duration_s": 1.0}), InjectedFault("hang", 14.0)]
    s = _recorded(sc, faults).summary
    assert s["reconnects"] == 1 and s["board_resets"] == 2


@pytest.mark.parametrize(
    ("seed", "index", "found"),
    [
        (1, 16, "noise while the board was unplugged: nothing to count (a checker's false alarm, fixed)"),
        (1, 19, "a dead rotor ESC never reported (the world's rotor kept its speed)"),
        (2, 43, "a rotor ESC dead from the first warm-up ended the run in an error"),
        (2, 165, "a missed requirement whose why left out the link damage"),
        (1, 226, "an operator's Arm lost in a stall, never tried again: the board lost"),
        (1, 35, "a reset reported late behind an overlapping stall (a checker's false alarm, fixed)"),
        (1, 52, "an Arm from before a brown-out retried onto the rebooted board, arming it unseen"),
        (
            1,
            511,
            "a re-arm judged by its answer, lost to byte damage, not its send (a checker's false alarm)",
        ),
        (1, 675, "an operator's Arm refused for want of a session, yet the host re-armed the board itself"),
        (27, 195, "a gimbal stuck while asked for 4.5 mrad/s, the pointing 0.9° off, never reported"),
    ],
)
def test_a_run_the_campaigns_failed_now_keeps_every_invariant(seed, index, found):
    """A failing seed becomes a test: each (seed, index) of ``faults.toml`` on ``cubesat-1u`` that broke
    an invariant on the way (``found``: why), run again — every invariant kept."""
    sc = load_scenario(SCENARIO)
    result = run_one(sc, draw(load_dispersions("faults", sc), seed, index), 5.0)
    assert result.ok, result.error
    violations = {k: v for k, v in result.checks.items() if k.startswith("inv.") and k != "inv.first" and v}
    assert not violations, (found, result.checks["inv.first"])
