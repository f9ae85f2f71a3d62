"""Calibrating a bench through its board: ``hil calibrate esc | sweep | unit`` against the emulator in
simulated time (``emu://``), on a real pty (``spawn://firmware-sim``) and the C firmware under simavr.

The emulated bench units (``unit_spread``) have their own motor and servo models, drawn from a seed by
``hil.calibration.generate.bench_units``, and ESCs at factory endpoints until programmed: what a fit
recovers is compared with those true models, to the tolerances docs/calibration.md states.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from firmware_sim.board import Board
from hil.calibration.bench import BenchKind, read_bench_csv
from hil.calibration.benchlink import BenchLink
from hil.calibration.cycle import CycleOptions, calibrate_units
from hil.calibration.files import load_calibration
from hil.calibration.fit import FitOptions
from hil.calibration.generate import bench_units
from hil.calibration.sweep import SweepPlan
from hil.cli import main
from hil.link.board import BoardClient
from hil.timing.clock import LockstepClock
from protocol.calibration import default_unit_calibration
from protocol.errors import CalibrationError, ConfigError
from protocol.messages import GimbalMode

SEED = 7
BENCH = f"emu://?unit_spread={SEED}&esc_supply_switch=1"
QUICK_ESC = ["--supply-off-ms", "300", "--high-ms", "1500", "--low-ms", "1000"]
PULSES = np.arange(1000.0, 2000.1, 5.0)

# The stated recovery tolerances (docs/calibration.md, "Calibrating a bench"), noise-free emulated units.
KV_REL = 0.01
DEADBAND_US = 5.0
SPEED_OF_FULL = 0.01  # the rotor speed curve, of the full-throttle speed
RATE_RAD_S = 0.02
DEAD_ZONE_US = 5.0
ANGLE_RAD = 0.01


def test_a_whole_bench_cycle_recovers_each_units_motor_constants(tmp_path, capsys):
    out, bench = tmp_path / "cal" / "array.toml", tmp_path / "bench"
    argv = ["calibrate", "unit", "--port", BENCH, "-o", str(out), "--bench-dir", str(bench)]
    argv += [
        "--unit",
        "0",
        "--unit",
        "1",
        "--unit",
        "2",
        "--unit",
        "3",
        "--program-esc",
        "--confirm-unloaded",
    ]
    argv += [*QUICK_ESC, "--rotor-step", "50", "--rate-step", "40", "--angle-step", "50"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.count("ESC taught 1000-2000 us") == 4
    # progress: every ESC phase, every sweep step and verification point, with the time left
    assert printed.count("ESC: step 3/3 LOW") == 4
    assert "rotor sweep 21/41, 2000 us up: unit 0 " in printed and "gimbal_angle sweep 41/41" in printed
    assert "about " in printed and " left" in printed and "verify 12/12" in printed
    for unit in range(4):  # the fit plots, as hil calibrate fit saves them
        assert f"unit {unit}: fit plot -> {out.parent / f'array-unit{unit}.png'}" in printed
        assert (out.parent / f"array-unit{unit}.png").read_bytes()[:4] == b"\x89PNG"
    assert "FAIL" not in printed and printed.count(" ok") >= 4 * (4 + 5 + 3)  # every verified point
    cset = load_calibration(out)
    assert [u.index for u in cset.units] == [0, 1, 2, 3]
    for entry, truth in zip(cset.units, bench_units(4, SEED), strict=True):
        cal, motor, servo = entry.calibration, truth.motor, truth.gimbal
        rotor = cal.rotor
        assert rotor.kv_rad_s_per_v == pytest.approx(motor.kv_rad_s_per_v, rel=KV_REL)
        assert rotor.esc.deadband_us == pytest.approx(motor.deadband_us, abs=DEADBAND_US)
        full = motor.kv_rad_s_per_v * 12.0
        speed = [rotor.speed(p, 12.0).value - motor.speed(p, 12.0) for p in PULSES]
        assert max(map(abs, speed)) <= SPEED_OF_FULL * full
        rate = [cal.gimbal_rate.rate(p).value - servo.rate(p) for p in PULSES]
        assert max(map(abs, rate)) <= RATE_RAD_S
        lo, hi = cal.gimbal_rate.dead_zone_us
        assert lo == pytest.approx(servo.center_us - servo.deadband_us, abs=DEAD_ZONE_US)
        assert hi == pytest.approx(servo.center_us + servo.deadband_us, abs=DEAD_ZONE_US)
        angle = [cal.gimbal_angle.angle(p).value - servo.angle(p) for p in PULSES]
        assert max(map(abs, angle)) <= ANGLE_RAD
        assert set(entry.fits) == {"rotor", "gimbal_rate", "gimbal_angle"}
        csv = bench / f"unit{entry.index}_rotor.csv"
        assert entry.fits["rotor"].source == "../bench/" + csv.name
        head = csv.read_text().splitlines()[:6]
        assert any(line.startswith("# board: vscmg-hil ADK-VSCMG") for line in head)
        assert any(line.startswith("# date: ") for line in head)
        assert "# status: complete" in csv.read_text()
        assert any(line.startswith("# battery at start: ") for line in head)
        data = read_bench_csv(csv)
        assert len(data) == 2 * 21 - 1 and data.pulse_us.min() == 1000 and data.pulse_us.max() == 2000


def lockstep_bench(n_units: int = 2) -> tuple[BoardClient, Board]:
    client = BoardClient(
        f"emu://?units={n_units}&unit_spread={SEED}&esc_supply_switch=1", clock=LockstepClock()
    )
    client.connect()
    return client, client.transport.board


def quick_rotor(tmp_path, **kw) -> CycleOptions:
    plan = SweepPlan(BenchKind.ROTOR, step_us=50, directions="up")
    base = CycleOptions(
        out=tmp_path / "array.toml",
        bench_dir=tmp_path / "bench",
        plans=(plan,),
        fit=FitOptions(rotor_knots=5),
    )
    return dataclasses.replace(base, **kw)


def test_an_esc_still_at_its_factory_endpoints_fails_the_fit_and_nothing_is_uploaded(tmp_path):
    client, board = lockstep_bench()
    before = list(board.calibrations)
    try:
        with pytest.raises(CalibrationError, match="stops rising before the high endpoint"):
            calibrate_units(BenchLink(client), [0], quick_rotor(tmp_path, verify=None))
    finally:
        client.close()
    assert board.calibrations == before and board.calibrations[0] is default_unit_calibration()
    assert not (tmp_path / "array.toml").exists()
    assert (tmp_path / "bench" / "unit0_rotor.csv").exists()  # the sweep is kept for a look


def test_a_failed_verification_puts_the_previous_sets_back_and_writes_no_file(tmp_path):
    client, board = lockstep_bench()
    before = list(board.calibrations)

    def report(line: str) -> None:
        if "uploaded and read back" in line:  # the rotor's ESC dies between the upload and the check
            board.faults.dead_esc(1, at=board.now)

    try:
        with pytest.raises(CalibrationError, match="verification point"):
            calibrate_units(
                BenchLink(client),
                [0],
                quick_rotor(tmp_path, esc=quick_program()),
                confirm_unloaded=True,
                report=report,
            )
        assert client.download_calibration(0).to_bytes() == before[0].to_bytes()
    finally:
        client.close()
    assert board.units[0].esc.programmed[-1][1:] == (1000, 2000)
    assert not (tmp_path / "array.toml").exists()


def quick_program():
    from hil.calibration.esc import EscProgram

    return EscProgram(supply_off_ms=300, high_ms=1500, low_ms=1000)


def test_programming_needs_the_operators_confirmation(tmp_path, capsys):
    assert main(["calibrate", "esc", "--port", BENCH, "--unit", "0"]) == 2
    assert "confirm that the rotor is off or unloaded" in capsys.readouterr().err
    client, board = lockstep_bench()
    try:
        with pytest.raises(ConfigError, match="confirm"):
            calibrate_units(BenchLink(client), [0], quick_rotor(tmp_path, esc=quick_program()))
    finally:
        client.close()
    assert board.units[0].esc.programmed == [] and board.esc_calibration.phase.name == "IDLE"


# ------------------------------------------------------------------ through a real pty
# (real time: the boards get a 1 s link watchdog, so a host starved by a loaded CPU does not trip it)
def test_unit_on_a_pty_teaches_the_esc_sweeps_fits_uploads_and_verifies(tmp_path, capsys):
    out = tmp_path / "unit.toml"
    port = f"spawn://firmware-sim?units=2&unit_spread={SEED}&esc_supply_switch=1&link_timeout=1"
    argv = ["calibrate", "unit", "--port", port, "--unit", "0", "--maps", "rotor", "-o", str(out)]
    argv += ["--bench-dir", str(tmp_path), "--program-esc", "--confirm-unloaded", *QUICK_ESC]
    argv += ["--directions", "up", "--rotor-step", "50", "--rotor-knots", "6", "--settle", "0.2"]
    argv += ["--settle-window", "0.3", "--dwell", "0.15"]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "unit 0: ESC taught 1000-2000 us" in printed and "uploaded and read back" in printed
    rotor = load_calibration(out).unit(0).calibration.rotor
    truth = bench_units(2, SEED)[0].motor
    assert rotor.kv_rad_s_per_v == pytest.approx(truth.kv_rad_s_per_v, rel=KV_REL)
    assert rotor.esc.deadband_us == pytest.approx(truth.deadband_us, abs=DEADBAND_US)
    assert "# port: spawn://firmware-sim" in (tmp_path / "unit0_rotor.csv").read_text()


def test_a_sweep_stops_at_the_current_guard(tmp_path, capsys):
    argv = [
        "calibrate",
        "sweep",
        "--port",
        "spawn://firmware-sim?units=2&link_timeout=1",
        "--unit",
        "0",
        "--out-dir",
    ]
    argv += [str(tmp_path), "--directions", "up", "--step", "100", "--max-current", "0.6"]
    argv += ["--settle", "0.2", "--settle-window", "0.3", "--dwell", "0.1"]
    assert main(argv) == 1
    assert "stopped early: battery current" in capsys.readouterr().err
    path = tmp_path / "unit0_rotor.csv"
    text = path.read_text()
    assert "# status: partial: stopped early: battery current" in text and "over the limit 0.6 A" in text
    data = read_bench_csv(path)
    assert data.partial is not None and "stopped early: battery current" in data.partial
    assert 1300 <= data.pulse_us.max() < 2000  # it got some way, then stopped short of the top
    rows = [line.split(",") for line in text.splitlines() if line and not line.startswith("#")]
    assert rows[0][3] == "battery_a"
    amps = np.array([float(r[3]) for r in rows[1:]])
    assert len(amps) == len(data) and amps.max() <= 0.6


@pytest.mark.firmware  # the C firmware under simavr: the AVR toolchain (.ci/apt-packages)
def test_the_same_commands_drive_the_firmware_under_simavr(tmp_path, capsys):
    from firmware_sim.avr import AvrBoard
    from firmware_sim.board.config import BoardConfig

    # a 1 s link watchdog: these tests are about calibration, not about a host starved by a loaded CPU
    config = BoardConfig(n_units=2, frame_rate_hz=100.0, link_timeout_s=1.0, esc_supply_switch=True)
    with AvrBoard(config) as avr:
        assert (
            main(["calibrate", "esc", "--port", avr.port, "--unit", "1", "--confirm-unloaded", *QUICK_ESC])
            == 0
        )
        assert (
            "unit 1: ESC taught 1000-2000 us (SUPPLY_OFF -> HIGH -> LOW -> DONE)" in capsys.readouterr().out
        )
        esc = avr.esc(1)
        assert [(p.low_us, p.high_us) for p in esc.programmed] == [(1000, 2000)]
        assert avr.esc(0).programmed == []
        argv = ["calibrate", "sweep", "--port", avr.port, "--unit", "1", "--map", "gimbal_rate", "--out-dir"]
        argv += [str(tmp_path), "--directions", "up", "--step", "100", "--settle", "0.2"]
        argv += ["--settle-window", "0.2", "--dwell", "0.1"]
        assert main(argv) == 0
    data = read_bench_csv(tmp_path / "unit1_gimbal_rate.csv")
    assert len(data) == 11
    # The firmware has no sensors: it reports its open-loop estimate through its own (default) maps.
    cal = default_unit_calibration()
    expected = [np.clip(cal.gimbal_value(p, GimbalMode.RATE).value, -2.0, 2.0) for p in data.pulse_us]
    assert np.allclose(data.value, expected, atol=0.01)
