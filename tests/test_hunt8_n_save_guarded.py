"""``hil calibrate unit`` ending between its verification and the calibration file's save: the board must
not keep a set that no file records while the command says it failed.

The new sets were uploaded and verified; then the save failed (the file hand-edited meanwhile so that its
re-read under the lock is refused) or the run was interrupted just before it. The board kept the new sets,
the file was not written, and the command said only the file's error or "interrupted": the board and the
array's calibration file disagreed, unsaid, and the next run took the board's unrecorded set as "the
previous set" to put back. The emulator is the board, in lockstep time (as tests/test_calibration_cycle_
refusals.py drives it); the file is a real one.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hil.calibration.bench import BenchKind
from hil.calibration.benchlink import BenchLink, Settling
from hil.calibration.cycle import CycleOptions, calibrate_units
from hil.calibration.files import CalibrationSet, load_calibration, save_calibration
from hil.calibration.sweep import SweepPlan
from hil.calibration.verify import VerifyPlan
from hil.link.board import BoardClient
from hil.timing.clock import LockstepClock
from protocol.errors import CalibrationError

BENCH = "emu://?unit_spread=7&esc_supply_switch=1"
FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "calibration"
SETTLING = Settling(0.1, 0.2, 10.0, 0.1)


def _options(tmp_path: Path) -> CycleOptions:
    return CycleOptions(
        out=tmp_path / "cal.toml",
        bench_dir=tmp_path / "bench",
        plans=(SweepPlan(BenchKind.GIMBAL_ANGLE, step_us=50, directions="up", settling=SETTLING),),
        verify=VerifyPlan(settling=SETTLING),
    )


def _lockstep() -> BoardClient:
    client = BoardClient(BENCH, clock=LockstepClock())
    client.connect()
    return client


def test_a_file_hand_edited_during_the_run_puts_the_previous_set_back_and_says_so(tmp_path):
    """Unit 3 of the array's file gets a NaN knot (a hand edit) while unit 0 is verified: the save's
    re-read refuses the file, naming the knot — and the board must then hold unit 0's previous set, said."""
    out = tmp_path / "cal.toml"
    array = load_calibration(FIXTURES / "pyramid4.toml")
    save_calibration(CalibrationSet(array.units[1:]), out)  # units 1-3; unit 0 is the one calibrated
    said: list[str] = []

    def report(line: str) -> None:
        said.append(line)
        if "gimbal_angle commanded" in line:  # the verification's table: the next step is the save
            text = out.read_text()
            edited = text.replace("angle_rad = [", "angle_rad = [nan, ", 3)  # units 1, 2, 3 ...
            out.write_text(edited.replace("angle_rad = [nan, ", "angle_rad = [", 2))  # ... then only 3

    client = _lockstep()
    try:
        before = client.download_calibration(0).to_bytes()
        with pytest.raises(CalibrationError) as info:
            calibrate_units(BenchLink(client), [0], _options(tmp_path), report=report)
        msg = str(info.value)
        assert "unit[2].gimbal_angle.angle_rad[0]: nan" in msg, msg  # the knot edited (third [[unit]])
        assert f"the save of {out} did not finish" in msg, msg
        assert "the board holds the previous sets of units [0], read back" in msg, msg
        assert client.download_calibration(0).to_bytes() == before
    finally:
        client.close()
    assert not any(line.startswith("saved units") for line in said), said


@pytest.mark.parametrize("delay_s", [0.0, 0.002, 0.01])
def test_ctrl_c_after_the_verification_leaves_board_and_file_agreeing_and_says_which(tmp_path, delay_s):
    """A real ``python -m hil calibrate unit`` sent SIGINT ``delay_s`` after its verification table came:
    within the few ms before its save it ended saying only "interrupted (SIGINT)", no file written, the
    verified set left on the board. Now either the file was saved (and it says so: the board holds the
    same sets), or the previous sets were put back, said."""
    out = tmp_path / "cal.toml"
    argv = [
        sys.executable, "-m", "hil", "calibrate", "unit", "--port", BENCH, "--unit", "0", "-o", str(out),
        "--bench-dir", str(tmp_path / "bench"), "--maps", "gimbal_angle", "--angle-step", "50",
        "--directions", "up", "--settle", "0.1", "--settle-window", "0.2", "--dwell", "0.1",
    ]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if "gimbal_angle commanded" in line:
            time.sleep(delay_s)
            proc.send_signal(signal.SIGINT)
            break
    rest, err = proc.communicate(timeout=120)
    said = "".join(lines) + rest
    assert proc.returncode in (0, 130), err
    if out.exists():
        assert f"saved units [0] in {out}" in said, said
    else:
        assert "did not finish: the board holds the previous sets of units [0], read back" in said, (
            said,
            err,
        )


def test_a_run_that_saves_still_leaves_its_set_on_the_board_and_in_the_file(tmp_path):
    """The guard changes nothing for a run that ends well: the board and the file hold the same set."""
    client = _lockstep()
    try:
        result = calibrate_units(BenchLink(client), [0], _options(tmp_path))
        held = client.download_calibration(0).to_bytes()
    finally:
        client.close()
    saved = load_calibration(result.saved).unit(0)
    assert saved is not None and saved.calibration.to_bytes() == held == result.calibrations[0].to_bytes()
