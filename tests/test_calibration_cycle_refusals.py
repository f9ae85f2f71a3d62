"""``hil calibrate unit | sweep | fit`` against the emulator: input refused before the board is driven,
the previous sets put back (guarded, read back) whatever ends an upload or a verification, a closed stdout
that ends the output and not the command, and outputs that are not regular files refused up front.

Each test reproduces a reviewer's finding (its number in the fix's commit): an ESC taught new endpoints
while the rotor map of the old ones was kept (1); a put-back after a failed verification that was a bare
loop, lost with the link (3); a BrokenPipeError mid-upload that skipped the put-back (4); an ``-o`` FIFO
that hung ``fit`` and ``unit`` (5); a ``--plot`` FIFO found after the file was written (6); a ``.tmp``
left by a failed write and a sweep CSV path found bad after the sweep (7); units given twice and output
folders that are files, found after the board was driven (8); and messages that misnamed the step or
printed a tolerance of 1e-05 as 0.0000 (9).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import hil.calibration.cycle as cycle
from hil.calibration.bench import BenchKind
from hil.calibration.benchlink import BenchLink, Settling
from hil.calibration.cycle import CycleOptions, calibrate_units
from hil.calibration.esc import EscProgram
from hil.calibration.sweep import SweepPlan
from hil.calibration.textfiles import write_atomic
from hil.calibration.verify import VerifyPlan, VerifyPoint
from hil.cli import main
from hil.link.board import BoardClient
from hil.timing.clock import LockstepClock
from protocol.errors import CalibrationError, ConfigError

BENCH = "emu://?unit_spread=7&esc_supply_switch=1"
FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "calibration"
QUICK = ["--directions", "up", "--settle", "0.1", "--settle-window", "0.2", "--dwell", "0.1"]
QUICK_ANGLE = ["--maps", "gimbal_angle", "--angle-step", "50", *QUICK]
QUICK_ESC = ["--supply-off-ms", "300", "--high-ms", "1500", "--low-ms", "1000"]
SETTLING = Settling(0.1, 0.2, 10.0, 0.1)


def _unit(tmp_path: Path, *extra: str) -> list[str]:
    return [
        "calibrate", "unit", "--port", BENCH, "--unit", "0", "-o", str(tmp_path / "cal.toml"),
        "--bench-dir", str(tmp_path / "bench"), *extra,
    ]  # fmt: skip


def _hil(*argv: str, timeout: float = 120, stdout=subprocess.PIPE) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", *argv],
        stdout=stdout,
        stderr=subprocess.PIPE,
        text=True,
        timeout=timeout,
    )


def _lockstep() -> tuple[BoardClient, object]:
    client = BoardClient(BENCH, clock=LockstepClock())
    client.connect()
    return client, client.transport.board


def _angle_options(tmp_path: Path, **verify) -> CycleOptions:
    return CycleOptions(
        out=tmp_path / "cal.toml",
        bench_dir=tmp_path / "bench",
        plans=(SweepPlan(BenchKind.GIMBAL_ANGLE, step_us=50, directions="up", settling=SETTLING),),
        verify=VerifyPlan(settling=SETTLING, **verify),
    )


# ------------------------------------------------------------------ 1: --program-esc needs the rotor
def test_program_esc_without_a_rotor_sweep_is_refused_before_the_board_is_driven(tmp_path, capsys):
    argv = _unit(tmp_path, *QUICK_ANGLE, "--program-esc", "--confirm-unloaded", *QUICK_ESC)
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert "--program-esc" in err and "--maps" in err and "rotor" in err, err
    assert "ESC" not in out and "sweep" not in out  # nothing was taught, nothing swept
    assert not (tmp_path / "cal.toml").exists() and not (tmp_path / "bench").exists()
    client, board = _lockstep()
    try:
        options = CycleOptions(
            out=tmp_path / "cal.toml",
            bench_dir=tmp_path / "bench",
            plans=(SweepPlan(BenchKind.GIMBAL_RATE),),
            esc=EscProgram(supply_off_ms=300, high_ms=1500, low_ms=1000),
        )
        with pytest.raises(ConfigError, match="--program-esc"):
            calibrate_units(BenchLink(client), [0], options, confirm_unloaded=True)
    finally:
        client.close()
    assert board.units[0].esc.programmed == []


# ------------------------------------------------------------------ 3, 9: a guarded put-back
def test_a_board_lost_as_a_failed_verification_is_put_back_is_waited_for_and_read_back(tmp_path, monkeypatch):
    """Verification fails (a tolerance of 1e-05 rad), and the board's cable is out for 1 s just then: the
    previous set is put back once it is back, read back, and the error says so (it used to upload in a
    bare loop, fail on the lost link, and say the sets "were put back")."""
    real = cycle.run_verify

    def verify_then_unplug(link, *args, **kw):
        report = real(link, *args, **kw)
        link.client.transport.board.faults.unplug(1.0)
        return report

    monkeypatch.setattr(cycle, "run_verify", verify_then_unplug)
    client, board = _lockstep()
    try:
        before = client.download_calibration(0).to_bytes()
        with pytest.raises(CalibrationError) as info:
            calibrate_units(BenchLink(client), [0], _angle_options(tmp_path, gimbal_angle_tolerance_rad=1e-5))
        msg = str(info.value)
        assert "verification point(s) outside tolerance" in msg and "(tolerance 1e-05)" in msg, msg
        assert "the board holds the previous sets of units [0], read back: put back (units [0])" in msg, msg
        assert "the fit plots drawn are kept" in msg and msg.endswith(f"{tmp_path / 'cal-unit0.png'})"), msg
        client.wait_for(lambda: client.connected, 5.0)
        assert client.download_calibration(0).to_bytes() == before
    finally:
        client.close()
    assert not (tmp_path / "cal.toml").exists()


def test_a_small_tolerance_is_printed_as_a_number_not_as_zero():
    point = VerifyPoint(0, BenchKind.GIMBAL_ANGLE, 0.5, 0.50002, 1e-5, True)
    line = point.line()
    assert "(tolerance 1e-05)" in line and "error +2e-05" in line and "FAIL" in line, line


# ------------------------------------------------------------------ 4, 9: whatever ends the upload
@pytest.mark.parametrize("error", [BrokenPipeError, KeyboardInterrupt])
def test_anything_that_ends_the_run_after_an_upload_puts_the_previous_set_back(tmp_path, error):
    """The report of "uploaded and read back" raises (stdout piped to ``sed '/read back/q'``: a
    BrokenPipeError, which skipped the put-back; Ctrl-C, said to cut short "the upload of unit 0's set"
    though it had finished)."""
    said: list[str] = []

    def report(line: str) -> None:
        said.append(line)
        if "uploaded and read back" in line:
            raise error(32, "Broken pipe") if error is BrokenPipeError else error()

    client, board = _lockstep()
    try:
        before = client.download_calibration(0).to_bytes()
        with pytest.raises(error):
            calibrate_units(BenchLink(client), [0], _angle_options(tmp_path), report=report)
        assert client.download_calibration(0).to_bytes() == before
    finally:
        client.close()
    assert not (tmp_path / "cal.toml").exists()
    if error is KeyboardInterrupt:
        assert said[-1].startswith("verification did not finish: the board holds the previous sets"), said[-1]


def test_unit_whose_stdout_reader_leaves_still_verifies_and_saves(tmp_path):
    """``hil calibrate unit ... | sed '/uploaded and read back/q'``: the output stops, the run does not
    (as ``hil run``'s progress lines): no traceback, verified and saved."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil", *_unit(tmp_path, *QUICK_ANGLE)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None and proc.stderr is not None
    for line in proc.stdout:
        if "uploaded and read back" in line:
            break
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=120) == 0, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert (tmp_path / "cal.toml").exists()


@pytest.mark.parametrize(
    "argv", [["show", str(FIXTURES / "pyramid4.toml")], ["show", "--hex", str(FIXTURES / "pyramid4.toml")]]
)
def test_show_into_a_closed_pipe_ends_quietly(argv):
    """``hil calibrate show f.toml | head -1``: a BrokenPipeError traceback (or Python's "Exception
    ignored" at exit), status 1 or 120; now the output just ends."""
    r, w = os.pipe()
    os.close(r)  # the reader is gone before anything is written
    try:
        done = _hil("calibrate", *argv, stdout=w)
    finally:
        os.close(w)
    assert done.returncode == 0 and done.stderr == "", done.stderr


def test_sweep_into_a_closed_pipe_completes(tmp_path):
    r, w = os.pipe()
    os.close(r)
    try:
        done = _hil(
            "calibrate", "sweep", "--port", BENCH, "--unit", "0", "--map", "gimbal_angle", "--step", "100",
            "--out-dir", str(tmp_path), *QUICK, stdout=w,
        )  # fmt: skip
    finally:
        os.close(w)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert "# status: complete" in (tmp_path / "unit0_gimbal_angle.csv").read_text()


# ------------------------------------------------------------------ 5, 6: outputs that are not files
def test_an_out_fifo_is_refused_before_reading_or_connecting(tmp_path):
    fifo = tmp_path / "cal.toml"
    os.mkfifo(fifo)
    fit = _hil("calibrate", "fit", str(FIXTURES / "bench" / "unit0_gimbal_angle.csv"), "-o", str(fifo),
               "--base", "default", timeout=60)  # fmt: skip
    assert fit.returncode == 2 and f"-o {fifo}" in fit.stderr and "not a regular file" in fit.stderr
    unit = _hil(*_unit(tmp_path, *QUICK_ANGLE), timeout=60)
    assert unit.returncode == 2 and f"-o {fifo}" in unit.stderr and "not a regular file" in unit.stderr
    assert "sweep" not in unit.stdout and not (tmp_path / "bench").exists()


def test_a_plot_fifo_is_refused_before_the_calibration_file_is_written(tmp_path):
    fifo = tmp_path / "plot.png"
    os.mkfifo(fifo)
    out = tmp_path / "cal.toml"
    done = _hil("calibrate", "fit", str(FIXTURES / "bench" / "unit0_gimbal_angle.csv"), "-o", str(out),
                "--base", "default", "--plot", str(fifo), timeout=60)  # fmt: skip
    assert done.returncode == 2 and f"--plot {fifo}" in done.stderr and "not a regular file" in done.stderr
    assert not out.exists()


# ------------------------------------------------------------------ 7: a failed write, a bad CSV path
def test_a_write_refused_leaves_no_tmp_file(tmp_path, capsys):
    target = tmp_path / "v.json"
    target.mkdir()
    with pytest.raises(ConfigError):
        write_atomic(target, "{}")
    assert main(["calibrate", "vectors", str(FIXTURES / "pyramid4.toml"), "-o", str(target)]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.json"]


def test_a_sweep_csv_path_that_is_a_folder_is_refused_before_the_board_is_armed(tmp_path, capsys):
    (tmp_path / "unit0_gimbal_angle.csv").mkdir()
    argv = ["calibrate", "sweep", "--port", BENCH, "--unit", "0", "--map", "gimbal_angle", "--step", "100"]
    assert main([*argv, "--out-dir", str(tmp_path), *QUICK]) == 2
    out, err = capsys.readouterr()
    assert "a folder" in err and "sweep" not in out, (out, err)


# ------------------------------------------------------------------ 8: refused before the board is driven
def test_a_unit_given_twice_is_refused_before_its_esc_is_taught(tmp_path, capsys):
    argv = _unit(tmp_path, "--unit", "0", "--program-esc", "--confirm-unloaded", *QUICK_ESC)
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert "give each unit once" in err and "ESC" not in out, (out, err)


def test_an_output_folder_that_is_a_file_is_refused_before_the_sweep(tmp_path, capsys):
    (tmp_path / "afile").write_text("")
    argv = ["calibrate", "unit", "--port", BENCH, "--unit", "0", "-o", str(tmp_path / "afile" / "cal.toml")]
    assert main([*argv, "--bench-dir", str(tmp_path / "bench"), *QUICK_ANGLE]) == 2
    out, err = capsys.readouterr()
    assert "is not a folder" in err and "sweep" not in out, (out, err)
    assert not (tmp_path / "bench").exists()
