"""Ctrl-C (SIGINT) and SIGTERM during ``python -m hil calibrate``, a subprocess sent a real signal, its board
a real one on a pty (``spawn://firmware-sim``): the board is put back to rest and the command says the
state its telemetry then shows; a sweep keeps the bench CSV of the steps it measured, marked partial,
which ``hil calibrate fit`` then refuses.
"""

from __future__ import annotations

import signal
import subprocess
import sys

from operator_support import Operated

from hil.calibration.bench import read_bench_csv

PORT = "spawn://firmware-sim?units=2&link_timeout=1"  # 1 s: a loaded CPU may delay a heartbeat
QUICK_SWEEP = ["--directions", "up", "--step", "50", "--settle", "0.2", "--settle-window", "0.3"]
LEFT_AT_REST = (
    "hil calibrate: the board was left DISARMED in SETPOINT mode (no ESC being taught), its outputs at "
    "rest: unit 0 gimbal 1500 us, rotor 1000 us; unit 1 gimbal 1500 us, rotor 1000 us"
)


def test_ctrl_c_during_a_sweep_leaves_the_board_at_rest_and_keeps_a_partial_csv(tmp_path):
    op = Operated(
        ["calibrate", "sweep", "--port", PORT, "--unit", "0", "--out-dir", str(tmp_path), *QUICK_SWEEP]
    )
    op.wait_for("rotor sweep 4/21")
    op.proc.send_signal(signal.SIGINT)
    code, err = op.finish()
    assert code == 130, err
    assert LEFT_AT_REST in err and err.rstrip().endswith("hil calibrate: interrupted (SIGINT)")
    path = tmp_path / "unit0_rotor.csv"
    kept = next(line for _, line in op.lines if "partial bench CSV kept" in line)
    steps = int(kept.split("kept, ")[1].split(" of ")[0])
    assert 4 <= steps < 21 and kept.endswith(f"of 21 steps, marked '# status: partial' -> {path}")
    text = path.read_text()
    assert f"# status: partial: stopped early: interrupted (SIGINT); {steps} of 21 steps" in text
    data = read_bench_csv(path)
    assert len(data) == steps and data.partial is not None and data.pulse_us.max() == 1000 + 50 * (steps - 1)
    fit = subprocess.run(
        [sys.executable, "-m", "hil", "calibrate", "fit", str(path), "-o", str(tmp_path / "c.toml")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert fit.returncode == 2 and "a partial sweep" in fit.stderr and "--allow-partial" in fit.stderr


def test_sigterm_while_an_esc_is_taught_aborts_it_to_minimum_and_says_so():
    port = PORT + "&esc_supply_switch=1"
    op = Operated(
        ["calibrate", "esc", "--port", port, "--unit", "1", "--confirm-unloaded", "--high-ms", "8000"]
    )
    op.wait_for("step 2/3 HIGH")
    op.proc.send_signal(signal.SIGTERM)
    code, err = op.finish()
    assert code == 143, err
    assert "ESC calibration of unit 1 aborted (DISARM): channel at 1000 us" in err  # the board's log
    assert LEFT_AT_REST in err and err.rstrip().endswith("hil calibrate: interrupted (SIGTERM)")
    assert "ESC taught" not in op.stdout


def test_ctrl_c_while_the_operator_is_asked_gives_up_and_leaves_the_esc_at_minimum():
    op = Operated(["calibrate", "esc", "--port", PORT, "--unit", "0", "--confirm-unloaded"])
    op.wait_for("Press Enter once it is connected")
    op.proc.send_signal(signal.SIGINT)
    code, err = op.finish()
    assert code == 130, err
    assert "ESC calibration of unit 0 aborted (DISARM)" in err and LEFT_AT_REST in err
