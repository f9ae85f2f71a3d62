"""``hil replay LOG --port URL``: a recorded phone drives a board through the controller — in lockstep
against the in-process board with a real trial's ground truth, and in real time over a real pty against a
spawned firmware-sim; bad combinations of options are clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hil.cli import main
from hil.logs import read_log
from hil.runtime.runlog import read_events, read_telemetry
from hil.scenario.paths import SHARED_DATA
from protocol.messages import BoardState

BROAD_SLOW = SHARED_DATA / "broad" / "01_undisturbed_slow_rotation_A.mat"
SENSORLOGGER = SHARED_DATA / "sensorlogger-android"


def _summary(out) -> tuple[dict, object]:
    (run_dir,) = out.iterdir()
    return json.loads((run_dir / "summary.json").read_text()), run_dir


def test_a_broad_trial_drives_the_in_process_board_in_lockstep(tmp_path, capsys):
    out = tmp_path / "runs"
    args = ["replay", str(BROAD_SLOW), "--port", "emu://?units=4&telemetry_rate=50", "--window", "28", "44",
            "--out", str(out), "--no-plots"]  # fmt: skip
    assert main(args) == 0
    s, run_dir = _summary(out)
    assert s["exit"] == "completed" and (s["mode"], s["source"]) == ("lockstep", "log")
    log = read_log(BROAD_SLOW).window(28, 44)  # still until 33.8 s, then the slow rotations start
    assert s["replay"]["samples_released"] == s["phone_samples"] == log.n_samples  # every sample played
    assert any("still window" in line for line in s["replay"]["setup"])  # the log's own gyro bias
    # the trial's optical ground truth is the truth: the estimator is scored against it
    assert s["estimator_rmse_deg"] is not None and 0.1 < s["estimator_rmse_deg"] < 8.0
    tel = read_telemetry(run_dir / "telemetry.csv")
    assert np.nanmax(tel["est_err_deg"][tel["phase"] == 2]) < 15.0
    # the board spun the rotors up, then the controller worked the gimbals against the recorded rotation
    assert tel["rotor_speed_0"][-1] > 300.0 and s["peak_gimbal_rate"] > 0.05
    assert np.any(np.abs(tel["cmd_gimbal_rate_0"][tel["phase"] >= 1]) > 0.01)
    events = [e for e in read_events(run_dir / "events.jsonl")[0]]
    kinds = [e["kind"] for e in events]
    assert kinds.index("replay_start") < kinds.index("slew_start")
    assert next(e for e in events if e["kind"] == "slew_start")["angle_deg"] == pytest.approx(0.0, abs=1e-9)
    assert "exit              completed  (lockstep" in capsys.readouterr().out


def test_a_phone_log_drives_firmware_sim_over_a_real_pty_in_real_time(tmp_path):
    out = tmp_path / "runs"
    args = ["replay", str(SENSORLOGGER), "--port", "spawn://firmware-sim?units=4&telemetry_rate=50",
            "--window", "0", "7", "--out", str(out), "--no-plots"]  # fmt: skip
    assert main(args) == 0
    s, run_dir = _summary(out)
    assert s["exit"] == "completed" and (s["mode"], s["source"]) == ("port", "log")
    assert 6.5 < s["sim_s"] < 9.0 and 0.7 < s["realtime_factor"] < 1.3  # played on the wall clock
    assert s["replay"]["samples_released"] == s["phone_samples"] > 900  # 7 s of three 50 Hz sensors
    assert s["estimator_rmse_deg"] is None  # no ground truth in this export
    assert s["link"]["frames_in"] > 100 and s["failsafe_events"] == 0
    tel = read_telemetry(run_dir / "telemetry.csv")
    seen = tel["rotor_speed_0"][np.isfinite(tel["rotor_speed_0"])]  # ticks before the first telemetry: empty
    assert seen[-1] > seen[0] + 100.0  # firmware-sim's rotors spun up
    assert np.all(tel["board_state"][-5:] == int(BoardState.ARMED))  # armed to the end


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--port", "emu://?units=4", "--paced"], "leave out --paced"),
        (["--port", "spawn://firmware-sim?units=4", "--lockstep"], "lockstep only against the in-process"),
        (["--port", "emu://?units=3"], "the board has 3 units, the scenario's spacecraft 4"),
        (["--port", "emu://?units=4", "--scenario", "nope"], "cubesat-1u"),
    ],
)
def test_bad_combinations_are_clear_errors(tmp_path, capsys, extra, message):
    # 4 s: longer than the warm-up and the rotors' settling (3 s), which a shorter log is refused for first
    assert main(["replay", str(SENSORLOGGER), "--window", "0", "4", "--out", str(tmp_path), *extra]) == 2
    assert message in capsys.readouterr().err
