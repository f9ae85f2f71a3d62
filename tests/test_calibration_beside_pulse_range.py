"""A calibration map whose pulses a board cannot put out, and the widths the boards make of a map.

A hunt found a file whose gimbal-rate dead zone and hold pulse lay at 10000 µs (the protocol's pulses are
500..2500 µs): ``hil calibrate show`` printed it (status 0), ``hil calibrate unit --maps gimbal_angle -o
FILE`` kept that map, uploaded it unverified and said "saved"; the firmware then clamped the hold width to
2500 µs (the gimbal at full rate under a rate-0 command) and the emulator raised ``FieldRangeError`` on its
next pulse frame (``firmware-sim`` dead). Here:

* the rule (docs/calibration.md §3, rule 8) where a set is validated — the file reader, the binary reader
  the emulator's upload uses, and the firmware's ``cal_validate`` — refusing the same sets, at the same
  place, on drawn sets;
* both boards refusing such an upload and holding the gimbal at the default hold pulse (no traceback);
* ``hil calibrate unit`` refusing such a file before the board is opened, and verifying a map kept from
  the file (a wrong, in-range one now fails the run and is put back);
* the emulator turning a map's width into a fine width exactly as the firmware's ``to_fine`` does
  (``firmware/src/app.c``, its source compiled for the host), clamped rather than raising.
"""

from __future__ import annotations

import ctypes
import re
import struct
import subprocess
from pathlib import Path

import hypothesis.strategies as st
import pytest
import test_firmware_differential as diff
from hypothesis import given, settings

from firmware_sim.avr.hostlib import cal_status_text, cal_validate
from firmware_sim.avr.paths import FIRMWARE_DIR
from firmware_sim.board.config import BoardConfig
from firmware_sim.board.core import Board
from firmware_sim.board.outputs import map_fine_width
from hil.calibration.files import CalibrationSet as FileSet
from hil.calibration.files import UnitEntry, load_calibration, parse_calibration, save_calibration
from hil.cli import main
from hil.timing.clock import LockstepClock
from protocol.calibration import (
    Conversion,
    GimbalRateMap,
    MonotoneCubic,
    UnitCalibration,
    default_unit_calibration,
    fragment,
)
from protocol.calibration.checks import f32
from protocol.calibration.codec import HEADER, KNOT
from protocol.crc import crc16_ccitt_false
from protocol.errors import CalibrationError
from protocol.messages import (
    PULSE_MAX_US,
    PULSE_MIN_US,
    ActuatorSetpoint,
    Arm,
    BoardState,
    GimbalMode,
    UnitSetpoint,
)
from protocol.pulse_widths import FINE_MAX

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "calibration"
BENCH = "emu://?unit_spread=7&esc_supply_switch=1"
QUICK_ANGLE = ["--maps", "gimbal_angle", "--angle-step", "50", "--directions", "up", "--settle", "0.1"]
QUICK_ANGLE += ["--settle-window", "0.2", "--dwell", "0.1"]
RATE_TABLES = {1: "lower", 2: "upper"}


def in_range(p: float) -> bool:
    return PULSE_MIN_US <= p <= PULSE_MAX_US


def first_out_of_range(columns: list[tuple[str, tuple[float, ...]]]) -> tuple[str, int] | None:
    """(column, index) of the first pulse out of range, in the order the maps check them."""
    for name, values in columns:
        for k, p in enumerate(values):
            if not in_range(p):
                return name, k
    return None


# ============================================================================ the rule, on files
def _rate_lines(cal: UnitCalibration, d: float) -> str:
    """Unit 0's ``[unit.gimbal_rate]`` lines with every pulse moved by ``d`` µs (still a valid map
    otherwise: the knots keep their order, the hold its place in the dead zone)."""
    r = cal.gimbal_rate
    hold, lower, upper = f32(r.hold_us + d), [f32(x + d) for x in r.lower.x], [f32(x + d) for x in r.upper.x]
    return (
        f"hold_us = {hold!r}\nlower_pulse_us = {lower!r}\nlower_rate_rad_s = {list(r.lower.y)!r}\n"
        f"upper_pulse_us = {upper!r}\nupper_rate_rad_s = {list(r.upper.y)!r}\n"
    )


PYRAMID = (FIXTURES / "pyramid4.toml").read_text()
PYRAMID_UNIT0 = parse_calibration(PYRAMID).unit(0)
assert PYRAMID_UNIT0 is not None


def _moved(kind: str, d: float) -> tuple[str, list[tuple[str, tuple[float, ...]]]]:
    """pyramid4.toml with unit 0's gimbal_rate or gimbal_angle map moved by ``d`` µs, and the moved map's
    pulse columns as the file names them (in the order they are checked)."""
    cal = PYRAMID_UNIT0.calibration
    first = PYRAMID.index("[unit.gimbal_rate]")  # unit 0's sections come first
    if kind == "gimbal_rate":
        start = PYRAMID.index("\n", first) + 1
        end = PYRAMID.index("\n[", start) + 1
        r = cal.gimbal_rate
        columns = [
            ("hold_us", (f32(r.hold_us + d),)),
            ("lower_pulse_us", tuple(f32(x + d) for x in r.lower.x)),
            ("upper_pulse_us", tuple(f32(x + d) for x in r.upper.x)),
        ]
        return PYRAMID[:start] + _rate_lines(cal, d) + PYRAMID[end:], columns
    pulses = [f32(x + d) for x in cal.gimbal_angle.curve.x]
    angle = PYRAMID.index("pulse_us = ", PYRAMID.index("[unit.gimbal_angle]"))
    end = PYRAMID.index("\n", angle)
    return PYRAMID[:angle] + f"pulse_us = {pulses!r}" + PYRAMID[end:], [("pulse_us", tuple(pulses))]


shifts = st.one_of(
    st.floats(-9000.0, 9000.0, width=32),
    st.sampled_from([0.0, 500.0, 501.0, 600.0, -500.0, -600.0, 8500.0]),  # 10000 µs: the hunt's file
)


@settings(max_examples=60, deadline=None)
@given(kind=st.sampled_from(["gimbal_rate", "gimbal_angle"]), d=shifts)
def test_a_file_is_refused_exactly_when_a_gimbal_pulse_leaves_the_range_naming_file_unit_and_key(kind, d):
    text, columns = _moved(kind, d)
    bad = first_out_of_range(columns)
    if bad is None:
        parse_calibration(text, "cal.toml")  # in range: read as before
        return
    with pytest.raises(CalibrationError) as info:
        parse_calibration(text, "cal.toml")
    key, k = bad
    where = f"cal.toml: unit[0].{kind}.{key}" + ("" if key == "hold_us" else f"[{k}]")
    assert info.value.where == where, str(info.value)
    assert "outside the pulses a board puts out, 500..2500 µs" in str(info.value)


def test_show_refuses_the_hunts_file_with_its_hold_at_10000_us(tmp_path, capsys):
    """The hunt's file: dead zone 9990..10010 µs, hold 10000 µs (``show`` printed it, status 0)."""
    path = tmp_path / "hold10000.toml"
    path.write_text(_moved("gimbal_rate", 10000.0 - PYRAMID_UNIT0.calibration.gimbal_rate.hold_us)[0])
    assert main(["calibrate", "show", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: unit[0].gimbal_rate.hold_us: 10000 µs is outside the pulses a board puts out" in err, err


# ============================================================================ the rule, in bytes and in C
def _with_crc(body: bytes) -> bytes:
    return body + struct.pack("<H", crc16_ccitt_false(body))


def _knot(data: bytes, table: int, knot: int) -> int:
    return HEADER.size + KNOT.size * (sum(data[24 : 24 + table]) + knot)


def moved_set(table: int, d: float) -> bytes:
    """The default set with table ``table``'s knot pulses (and, for a rate table, the hold) moved by
    ``d`` µs, its CRC made good: only validation can refuse it."""
    data = default_unit_calibration().to_bytes()
    body = bytearray(data[:-2])
    if table in RATE_TABLES:
        for t in RATE_TABLES:  # the whole rate map moves, so its dead zone keeps the hold
            for k in range(data[24 + t]):
                (x,) = struct.unpack_from("<f", body, _knot(data, t, k))
                struct.pack_into("<f", body, _knot(data, t, k), x + d)
        (hold,) = struct.unpack_from("<f", body, 20)
        struct.pack_into("<f", body, 20, hold + d)
    else:
        for k in range(data[24 + table]):
            (x,) = struct.unpack_from("<f", body, _knot(data, table, k))
            struct.pack_into("<f", body, _knot(data, table, k), x + d)
    return _with_crc(bytes(body))


def _columns(data: bytes, table: int) -> list[tuple[str, tuple[float, ...]]]:
    def xs(t: int) -> tuple[float, ...]:
        return tuple(struct.unpack_from("<f", data, _knot(data, t, k))[0] for k in range(data[24 + t]))

    if table in RATE_TABLES:
        return [("hold_us", (struct.unpack_from("<f", data, 20)[0],)), ("lower.x", xs(1)), ("upper.x", xs(2))]
    return [("curve.x", xs(3))]


def _python_where(data: bytes) -> str | None:
    try:
        UnitCalibration.from_bytes(data, source="set")
    except CalibrationError as exc:
        return exc.where
    return None


@settings(max_examples=80, deadline=None)
@given(table=st.sampled_from([1, 3]), d=shifts)
def test_the_binary_reader_refuses_a_set_exactly_when_a_gimbal_pulse_leaves_the_range(table, d):
    """The reader the emulator's upload and ``hil calibrate`` read-backs use."""
    data = moved_set(table, d)
    bad = first_out_of_range(_columns(data, table))
    where = _python_where(data)
    if bad is None:
        assert where is None, where
    else:
        name, k = bad
        section = "gimbal_rate" if table in RATE_TABLES else "gimbal_angle"
        assert where == f"set: {section}.{name}" + ("" if name == "hold_us" else f"[{k}]"), where


@pytest.mark.firmware
@settings(max_examples=120, deadline=None)
@given(table=st.sampled_from([1, 3]), d=shifts)
def test_the_firmware_refuses_what_python_refuses_at_the_same_place(table, d):
    """``cal_validate`` (firmware/src/calib.c) against the Python reference, on the same bytes: the
    firmware took every one of these sets before (tests/test_firmware_calibration.py compares the other
    rules)."""
    data = moved_set(table, d)
    bad = first_out_of_range(_columns(data, table))
    status, c_table, c_knot = cal_validate(data)
    assert (status == 0) == (_python_where(data) is None), (status, _python_where(data))
    if bad is None:
        return
    assert cal_status_text(status) == "gimbal pulse outside 500..2500 us"
    name, k = bad
    want = {"hold_us": (0xFF, 0), "lower.x": (1, k), "upper.x": (2, k), "curve.x": (3, k)}[name]
    assert (c_table, c_knot) == want


# ============================================================================ both boards, one upload
@pytest.mark.firmware
@pytest.mark.parametrize("table", [1, 3], ids=["rate map at 10000 us", "angle map at 10000 us"])
def test_both_boards_refuse_the_upload_and_hold_at_the_default_pulse(table):
    """The hunt's set, uploaded to the firmware (simavr) and the emulator on one clock: both NACK it
    BAD_CALIBRATION, and an armed rate-0 command holds at the default set's 1500 µs on both (the firmware
    put out 2500 µs, the emulator raised FieldRangeError on its next frame)."""
    d = 10000.0 - (1500.0 if table == 1 else 1000.0)
    data = moved_set(table, d)
    pair = diff.Pair(BoardConfig())
    try:
        n = pair.config.n_units
        pair.run(0.15)
        pair.send(diff.hello())
        pair.run(0.1)
        for part in fragment(0, 7, data):
            pair.send(part, diff.RELIABLE)
            pair.run(0.004)
        pair.run(0.1)
        pair.compare()
        for k in pair.boards:
            assert pair.seen[k].answers[-1][-1] == "BAD_CALIBRATION", (k, pair.seen[k].answers)
        pair.send(Arm(), diff.RELIABLE)
        hold = ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(0.0, 0.0),) * n)
        for _ in range(4):
            pair.send(hold)
            pair.run(0.1)
            pair.compare()
        pair.compare(final=True)
        for k in pair.boards:
            assert pair.seen[k].telemetry.state is BoardState.ARMED, k
            assert pair.seen[k].telemetry.pulses_us[0] == 1500, (k, pair.seen[k].telemetry.pulses_us)
    finally:
        pair.close()


# ============================================================================ hil calibrate unit
def _unit_argv(out: Path, tmp_path: Path) -> list[str]:
    argv = ["calibrate", "unit", "--port", BENCH, "--unit", "0", "-o", str(out)]
    return [*argv, "--bench-dir", str(tmp_path / "bench"), *QUICK_ANGLE]


def test_unit_refuses_a_file_beyond_the_range_before_the_board_is_opened(tmp_path, capsys):
    """``--maps gimbal_angle`` kept the file's gimbal_rate map (hold 10000 µs), uploaded it and said
    "saved", status 0."""
    out = tmp_path / "cal.toml"
    text = _moved("gimbal_rate", 10000.0 - PYRAMID_UNIT0.calibration.gimbal_rate.hold_us)[0]
    out.write_text(text)
    assert main(_unit_argv(out, tmp_path)) == 2
    printed, err = capsys.readouterr()
    assert f"{out}: unit[0].gimbal_rate.hold_us: 10000 µs is outside" in err, err
    assert "sweep" not in printed and not (tmp_path / "bench").exists()
    assert out.read_text() == text


def _wrong_rate_map() -> GimbalRateMap:
    """A gimbal-rate map inside 500..2500 µs but of no unit: its dead zone and hold at 2400 µs (a
    servo centred near 1500 µs turns fast there)."""
    rates = default_unit_calibration().gimbal_rate
    lower = MonotoneCubic.pchip([1900.0, 2000.0, 2100.0, 2200.0, 2300.0, 2390.0], rates.lower.y)
    upper = MonotoneCubic.pchip([2410.0, 2430.0, 2450.0, 2470.0, 2490.0, 2500.0], rates.upper.y)
    return GimbalRateMap(2400.0, lower, upper)


def test_unit_verifies_a_map_kept_from_the_file_and_puts_the_board_back_when_it_misses(tmp_path, capsys):
    """The file's gimbal_rate map is new to the board, so it is verified though only the angle was swept:
    the hold point misses, the previous set goes back, the file is left as it was (it used to be uploaded
    unverified: status 0, "saved")."""
    out = tmp_path / "cal.toml"
    default = default_unit_calibration()
    wrong = UnitCalibration(default.rotor, _wrong_rate_map(), default.gimbal_angle)
    save_calibration(FileSet((UnitEntry(0, "unit0", wrong, {}),)), out)
    before = out.read_text()
    code = main(_unit_argv(out, tmp_path))
    printed, err = capsys.readouterr()
    assert code != 0, printed
    said = f"unit 0: verifying gimbal_rate (kept from {out}, new to the board), gimbal_angle (swept)"
    assert said in printed, printed
    assert "not verified: rotor (what the board held, unchanged)" in printed
    assert "verification point(s) outside tolerance" in err and "gimbal_rate" in err, err
    assert "the board holds the previous sets of units [0], read back: put back (units [0])" in err, err
    assert out.read_text() == before


def test_unit_does_not_verify_a_map_the_board_already_held(tmp_path, capsys):
    """A file whose gimbal_rate and rotor maps are the board's own (the default set): only the swept
    angle map is new, and only it is verified (the default rate map would not fit this bench's unit)."""
    out = tmp_path / "cal.toml"
    save_calibration(FileSet((UnitEntry(0, "unit0", default_unit_calibration(), {}),)), out)
    assert main(_unit_argv(out, tmp_path)) == 0
    printed = capsys.readouterr().out
    assert "unit 0: verifying gimbal_angle (swept); not verified: rotor, gimbal_rate" in printed, printed
    assert "gimbal_rate  commanded" not in printed
    assert load_calibration(out).unit(0).calibration.gimbal_rate == default_unit_calibration().gimbal_rate


# ======================================================================= widths clamped as the firmware's
@pytest.fixture(scope="module")
def c_to_fine(tmp_path_factory):
    """The firmware's ``to_fine`` (static in firmware/src/app.c), its source taken from app.c and compiled
    for the host with the firmware's headers, as libfirmware-host.so compiles the sans-IO modules."""
    pytest.importorskip("firmware_sim.avr.hostlib")
    source = (FIRMWARE_DIR / "src" / "app.c").read_text()
    found = re.search(r"static uint32_t to_fine\(float value\)\n\{.*?\n\}\n", source, re.S)
    assert found, "to_fine is no longer in firmware/src/app.c: update this test"
    shim = tmp_path_factory.mktemp("to_fine") / "to_fine.c"
    shim.write_text(
        '#include <math.h>\n#include <stdint.h>\n#include "protocol_gen.h"\n#include "pulses.h"\n'
        f"{found.group(0)}\nuint32_t host_to_fine(float value);\n"
        "uint32_t host_to_fine(float value) { return to_fine(value); }\n"
    )
    lib = shim.with_suffix(".so")
    cmd = ["cc", "-O2", "-std=gnu11", "-Wall", "-Werror", "-fPIC", "-shared"]
    subprocess.run([*cmd, f"-I{FIRMWARE_DIR / 'include'}", str(shim), "-lm", "-o", str(lib)], check=True)
    fn = ctypes.CDLL(str(lib)).host_to_fine
    fn.restype, fn.argtypes = ctypes.c_uint32, [ctypes.c_float]
    return fn


# Widths a float32 map could yield, and the edges; within ±1e6 µs (beyond ±2^31/512 µs the AVR's 32-bit
# lrintf is undefined, and no map comes near: its pulses lie in 500..2500 µs).
EDGES = [0.0, -0.0, -1e-3, 499.99997, 500.0, 1500.0009765625, 2499.9998, 2500.0, 2500.0002, 2500.001]
EDGES += [1e6, -1e6]
widths = st.one_of(st.sampled_from(EDGES), st.floats(-1e6, 1e6, width=32))


@pytest.mark.firmware
@settings(max_examples=400, deadline=None)
@given(w=widths)
def test_a_maps_width_becomes_the_fine_width_the_firmware_makes_of_it(c_to_fine, w):
    assert map_fine_width(w) == c_to_fine(w)
    assert 0 <= map_fine_width(w) <= FINE_MAX


class WidthStub:
    """The default unit, but for a gimbal map that puts out ``width_us`` for every rate: a map width out
    of range, which no set can hold any more, reaching the emulator's pulse stage directly."""

    def __init__(self, width_us: float) -> None:
        self._cal = default_unit_calibration()
        self.width_us = width_us

    def __getattr__(self, name: str):
        return getattr(self._cal, name)

    def gimbal_pulse_us(self, value: float, mode: GimbalMode) -> Conversion:
        return Conversion(self.width_us)


@pytest.mark.firmware
@settings(max_examples=25, deadline=None)
@given(w=widths.filter(lambda w: not in_range(w) or w in EDGES))
def test_the_emulator_puts_out_the_firmwares_width_for_a_map_width_out_of_range(c_to_fine, w):
    """An armed emulator whose gimbal map gives ``w``: its target is the firmware's fine width for ``w``,
    its frames stay within 0..2500 µs, and it raises nothing (it raised FieldRangeError from every frame)."""
    clock = LockstepClock()
    board = Board(BoardConfig(n_units=1), clock=clock, calibrations=[WidthStub(w)])
    sp = ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(0.5, 0.0),))

    def run(until: float) -> None:
        while clock.now() < until - 1e-9:
            clock.set(max(min(until, clock.now() + 0.01, board.next_deadline()), clock.now() + 1e-6))
            board.step()

    run(0.2)  # booted
    for seq, (msg, flags) in enumerate(((diff.hello(), 0), (Arm(), diff.RELIABLE), (sp, 0))):
        board.feed(diff.encode_frame(msg, seq, flags))
        run(clock.now() + 0.1)
    assert board.state is BoardState.ARMED
    assert board.targets[0] == c_to_fine(w)
    for frame in board.timeline.frames:
        assert frame.widths[0] is None or frame.widths[0] <= PULSE_MAX_US
