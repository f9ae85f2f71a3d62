"""A bench whose pack sags until the board's power manager sheds the rotors (SHED) during a rotor sweep,
through the real ``hil calibrate sweep`` against the in-process board: the sweep stops at once, naming
the shed and the battery's voltage, in its message and in its CSV's status — not, after waiting out its
settling for pulses that never came, "no telemetry while holding the command" (a hunt's finding)."""

from __future__ import annotations

import subprocess
import sys


def test_a_sweep_stops_naming_the_boards_shed(tmp_path):
    argv = [
        "calibrate",
        "sweep",
        "--port",
        "emu://?unit_spread=7&sag=4@30/5",
        "--unit",
        "0",
        "--map",
        "rotor",
        "--out-dir",
        str(tmp_path),
        "--directions",
        "up",
        "--step",
        "25",
    ]
    done = subprocess.run([sys.executable, "-m", "hil", *argv], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr[-2000:]
    assert "stopped early: the board shed the rotors (power SHED, battery" in done.stderr, done.stderr[-2000:]
    (csv,) = tmp_path.glob("unit0_rotor.csv")
    status = [line for line in csv.read_text().splitlines() if line.startswith("# status:")]
    assert status and "the board shed the rotors" in status[0], status
