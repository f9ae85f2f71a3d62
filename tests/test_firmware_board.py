"""The board firmware on simavr, through its pty, beyond the conformance suite: calibration upload and
download with EEPROM persistence, the EEPROM configuration, PPM-sum, reliable-command rules, boot
reports after a reset, stack headroom, and ``firmware-sim --avr``."""

from __future__ import annotations

import os
import random
import signal
import struct
import subprocess
import sys
import time
from dataclasses import replace

import pytest
from conformance.host import SerialHost, heartbeat

from firmware_sim.avr import AvrBoard, HarnessOptions, eeprom
from firmware_sim.board.config import BoardConfig
from protocol.calibration import EscMotorModel, GimbalServoModel, fragment, model_unit_calibration, reassemble
from protocol.frame import Frame
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    CalibrationData,
    CalibrationRequest,
    ControlMode,
    Disarm,
    GimbalMode,
    Heartbeat,
    HelloReply,
    Log,
    Nack,
    NackReason,
    RawPulses,
    ResetCause,
    SetMode,
    Telemetry,
    UnitSetpoint,
)
from protocol.pulses import decode_ppm

UPLOADED = model_unit_calibration(
    EscMotorModel(low_us=1050.0, high_us=1950.0, deadband_us=20.0, kv_rad_s_per_v=60.0),
    GimbalServoModel(center_us=1520.0, max_rate_rad_s=1.5, direction=-1),
)


@pytest.fixture
def board():
    with AvrBoard(BoardConfig(telemetry_rate_hz=50.0)) as b:
        yield b
        b.check()


@pytest.fixture
def host(board):
    h = SerialHost(board.port)
    h.handshake()
    h.keepalive = heartbeat
    yield h
    h.close()


def upload(host, unit: int, data: bytes, transfer_id: int = 1) -> list:
    return [host.request(part) for part in fragment(unit, transfer_id, data)]


def logged(host, code: int, words: str, timeout: float = 1.0) -> Log:
    """A Log with ``code`` whose text contains ``words``, already received or arriving within ``timeout``."""

    def match(m):
        return isinstance(m, Log) and m.code == code and words in m.text

    for m in host.received:
        if match(m):
            return m
    return host.wait_for(match, timeout, f"Log {code} '{words}'")


@pytest.mark.firmware
def test_an_uploaded_calibration_drives_the_outputs_and_survives_a_reset(board, host):
    assert all(isinstance(a, Ack) for a in upload(host, 1, UPLOADED.to_bytes()))
    logged(host, 10, "stored")  # LogCode.CALIBRATION
    assert isinstance(host.request(Arm()), Ack)
    sp = ActuatorSetpoint(
        gimbal_mode=GimbalMode.RATE, units=tuple(UnitSetpoint(0.4, 350.0) for _ in range(4))
    )
    host.keepalive = lambda: sp
    host.poll(0.3)
    tel = host.wait_type(Telemetry, 1.0, lambda m: m.state == BoardState.ARMED)
    volts = tel.battery_mv / 1000
    assert abs(tel.pulses_us[2] - UPLOADED.gimbal_pulse_us(0.4, GimbalMode.RATE).value) <= 1.0
    rotor = [UPLOADED.rotor_pulse_us(350.0, volts + dv).value for dv in (-0.1, 0.1)]
    assert min(rotor) - 1 <= tel.pulses_us[3] <= max(rotor) + 1
    assert tel.pulses_us[2] != tel.pulses_us[0]  # unit 0 still on the default set
    assert all(u.rotor_speed > 100.0 for u in tel.units)  # the estimates follow the outputs
    angle = ActuatorSetpoint(
        gimbal_mode=GimbalMode.ANGLE, units=tuple(UnitSetpoint(0.5, 0.0) for _ in range(4))
    )
    host.keepalive = lambda: angle
    host.poll(0.6)
    tel = host.wait_type(Telemetry, 1.0)
    assert abs(tel.pulses_us[2] - UPLOADED.gimbal_pulse_us(0.5, GimbalMode.ANGLE).value) <= 1.0
    assert abs(tel.units[1].gimbal_angle - 0.5) < 0.02 and tel.pulses_us[3] == round(
        UPLOADED.rotor.esc.low_us
    )
    host.keepalive = heartbeat
    assert isinstance(host.request(Disarm()), Ack)
    host.poll(0.3)  # the EEPROM is written in the background
    assert board.calibration(1) == UPLOADED
    board.press_reset()
    host.keepalive = None
    reply = host.handshake()
    assert reply.reset_cause == ResetCause.EXTERNAL and board.calibration(1) == UPLOADED
    # and the board hands it back on request, fragment by fragment, each acknowledged
    host.send(CalibrationRequest(unit=1, transfer_id=9))
    parts, end = [], time.monotonic() + 3.0
    while len(parts) < 3 and time.monotonic() < end:
        for event in host.deframer.feed(host._read(0.05)):
            if isinstance(event, Frame) and isinstance(event.message, CalibrationData):
                parts.append(event.message)
                host.send(Ack(msg_id=CalibrationData.MSG_ID, seq=event.seq))
    assert reassemble(parts) == (1, UPLOADED.to_bytes())


@pytest.mark.firmware
def test_bad_uploads_are_refused_and_the_old_set_stays(board, host):
    data = bytearray(UPLOADED.to_bytes())
    data[40] ^= 0x10  # a damaged knot: the set's own CRC no longer checks
    parts = fragment(0, 2, bytes(data))
    answers = [host.request(p) for p in parts]
    assert isinstance(answers[-1], Nack) and answers[-1].reason == NackReason.BAD_CALIBRATION
    logged(host, 10, "refused")
    assert host.request(replace(parts[0], unit=5)).reason == NackReason.OUT_OF_RANGE
    assert isinstance(host.request(Arm()), Ack)
    assert host.request(fragment(0, 3, UPLOADED.to_bytes())[0]).reason == NackReason.BAD_STATE
    assert board.calibration(0) != UPLOADED


@pytest.mark.firmware
def test_reliable_command_rules_and_an_incompatible_host(board, host):
    assert host.request(SetMode(mode=1)).__class__ is Ack  # RAW_PULSES, disarmed
    seq = host.send(Arm())
    assert host.wait_type(Ack, 1.0, lambda m: m.seq == seq)
    assert host.request(SetMode(mode=0)).reason == NackReason.BAD_STATE  # modes change disarmed
    assert isinstance(host.request(Disarm()), Ack)
    host.send(Arm(), seq=seq)  # a retry of the old Arm: answered from the cache, not executed again
    assert host.wait_type(Ack, 1.0, lambda m: m.seq == seq)
    assert host.wait_type(Telemetry, 1.0).state == BoardState.DISARMED
    assert host.request(SetMode(mode=2)).reason == NackReason.UNSUPPORTED
    reply = host.handshake(schema_hash=SCHEMA_HASH ^ 1)
    assert reply.schema_hash == SCHEMA_HASH
    logged(host, 8, "incompatible")  # LogCode.HANDSHAKE
    assert board.stack_headroom() >= 256  # bytes of RAM the stack never reached


STOPWATCH_S = 64e-6  # clock.h: the start-up stopwatch's resolution
STARTED_S = 0.05  # board time after a reset by which its start-up is over and its tick runs


@pytest.mark.firmware
def test_the_uptime_counts_from_the_reset_itself(board):
    """The board's clock (Telemetry and Heartbeat ``time_ms``) counts from the reset, not from when start-up
    code got round to it: a host, a test or a log lines its uptimes up with what happened on the pins by
    the reset. Before the start-up stopwatch ran, the stack paint took ~1 ms that no clock counted: every
    uptime was late by that much (a conformance check of a Disarm's pulse timing saw it on a CI run).

    The clock variable is sampled at every rising pulse edge and after every 1 ms slice, through a power-on
    and a reset press: it is never ahead of the time since the reset, and lags it by less than a tick plus
    the stopwatch's resolution at the samples nearest a tick."""
    board.watch("ms", 4)
    start = board.now()
    while board.now() < start + 0.3:
        time.sleep(0.01)
    board.press_reset()
    start = board.now()
    while board.now() < start + 0.3:
        time.sleep(0.01)
    resets = [r.t for r in board.resets()]
    assert len(resets) == 2
    lags: list[list[float]] = [[], []]
    for t, raw in board.records.watched:
        boot = sum(r <= t for r in resets) - 1
        # the tick running: start-up (the boot counter's EEPROM writes, ~10 ms) over. Before, the variable
        # holds the last boot's value, then 0 — a change a loaded harness may not sample
        if boot >= 0 and t - resets[boot] >= STARTED_S:
            lags[boot].append(t - resets[boot] - int.from_bytes(raw, "little") / 1000)
    for boot in lags:
        assert len(boot) > 200
        assert min(boot) >= -STOPWATCH_S  # never ahead
        assert min(boot) < 1e-3 + STOPWATCH_S, f"the uptime lags the reset by {min(boot) * 1e3:.3f} ms"


@pytest.mark.firmware
def test_a_width_changes_at_a_frame_start_never_in_the_middle_of_a_pulse(board, host):
    """A width written while its pulse is high takes effect at the next frame: the ATmega's compare
    registers are double-buffered in fast-PWM mode, so no pulse is stretched into the next frame (a
    lowered width whose match already passed) or cut short. simavr applies a write at once; the harness
    models the buffer (``firmware/harness/ocr.c``). Writes here land at every phase of the frame."""
    n = 2 * board.config.n_units
    wide, narrow = RawPulses(pulses_us=(1900,) * n), RawPulses(pulses_us=(1100,) * n)
    assert isinstance(host.request(SetMode(mode=ControlMode.RAW_PULSES)), Ack)
    assert isinstance(host.request(Arm()), Ack)
    # Sent at random intervals (a host that reads between sends falls into step with the board's
    # telemetry, and so with its frames): the changes land at every phase of a frame, each decrease with
    # a ~4 % chance of coming while the wider pulse is past the narrower one's end.
    t0 = board.now() + 0.05
    pace = random.Random(7)
    for k in range(400):
        host.send(wide if k % 2 else narrow)
        time.sleep(pace.uniform(0.002, 0.012))
        host.poll(0.0)
    frames = [f for f in board.timeline() if f.t > t0]
    assert len(frames) > 50
    widths = [w for f in frames for w in f.widths]
    assert all(w is not None and min(abs(w - 1900), abs(w - 1100)) <= 1 for w in widths)
    narrow_share = sum(w < 1500 for w in widths) / len(widths)
    assert 0.1 < narrow_share < 0.9
    assert board.records.truncated == 0


@pytest.mark.firmware
def test_after_a_stall_the_harness_keeps_pace_with_wall_time_instead_of_racing(board):
    """A harness the machine did not run for a while lets the board's clock fall behind rather than race
    to catch up (board seconds squeezed into wall milliseconds, in which no host byte can arrive, would
    trip the link watchdog for nothing). Its lag correction had the wrong sign: after one 0.3 s stall the
    board ran ~11x wall time from then on, ~12 000 "lag resets" a second."""
    time.sleep(0.2)
    os.kill(board.process.pid, signal.SIGSTOP)
    time.sleep(0.3)
    os.kill(board.process.pid, signal.SIGCONT)
    time.sleep(0.1)
    board_0, wall_0 = board.now(), time.monotonic()
    time.sleep(1.0)
    board_1, wall_1 = board.now(), time.monotonic()
    assert (board_1 - board_0) / (wall_1 - wall_0) < 1.1  # never ahead of wall time (behind if loaded)
    assert board.link_stats()["lag_resets"] < 50


@pytest.mark.firmware
def test_the_eeprom_configuration_shapes_the_board_and_ppm_follows_the_channels():
    cfg = BoardConfig(
        n_units=3,
        frame_rate_hz=200.0,
        telemetry_rate_hz=25.0,
        ppm=True,
        identity=replace(BoardConfig().identity, serial="BENCH-3"),
    )
    with AvrBoard(cfg) as b:
        h = SerialHost(b.port)
        reply = h.handshake()
        assert (reply.n_units, reply.frame_rate_hz, reply.serial) == (3, 200, "BENCH-3")
        h.keepalive = heartbeat
        tel = h.wait_type(Telemetry, 1.0)
        assert len(tel.pulses_us) == 6 and len(tel.units) == 3
        h.poll(0.2)
        frames = b.timeline()[-10:]
        periods = {round((f2.t - f1.t) * 1e6) for f1, f2 in zip(frames, frames[1:], strict=False)}
        assert periods == {5000} and all(len(f.widths) == 6 for f in frames)
        trains = b.ppm_trains()
        assert trains and decode_ppm(trains[-1].edges_us) == tuple(round(w) for w in frames[-1].widths)
        h.close()


@pytest.mark.firmware
def test_a_damaged_configuration_block_means_defaults_and_says_so():
    image = bytearray(eeprom.EepromImage(BoardConfig(n_units=2)).to_bytes())
    image[eeprom.field_offsets()["crc"]] ^= 0xFF
    with AvrBoard(BoardConfig(), eeprom_image=bytes(image)) as b:
        h = SerialHost(b.port)
        assert h.handshake().n_units == BoardConfig().n_units
        b.press_reset()  # boot reports go out at boot: reset the board with the host listening
        assert "defaults" in logged(h, 1, "configuration refused", 2.0).text  # LogCode.BOOT
        assert h.handshake().reset_cause == ResetCause.EXTERNAL
        h.close()


@pytest.mark.firmware
def test_firmware_sim_avr_serves_the_firmware_on_a_pty_until_stopped():
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--avr", "--units", "2", "--frame-rate", "100"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/pts/")
        h = SerialHost(path)
        reply: HelloReply = h.handshake()
        assert (reply.n_units, reply.frame_rate_hz) == (2, 100)
        h.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        proc.stdout.close()
        proc.stderr.close()


@pytest.mark.parametrize("option", [["--dead-esc", "1@3"], ["--unit-spread", "7"]])
def test_firmware_sim_avr_refuses_faults_it_cannot_inject(option):
    result = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--avr", *option],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == 2 and option[0] in result.stderr


@pytest.mark.firmware
def test_the_boot_id_counts_the_boots_in_eeprom_mixed_with_the_serial(tmp_path):
    """The firmware's boot id (firmware/README.md, "Configuration"): the EEPROM boot counter moved on by one
    at every boot — a reset button, a watchdog reset, the board's process started again on its EEPROM
    file — and mixed with the serial: the HelloReply's and every Heartbeat's id, one the host has not
    heard from that board before. The counter's four slots take turns; a board of another serial and the
    same count announces another id."""
    serial = "BENCH-9"
    cfg = BoardConfig(identity=replace(BoardConfig().identity, serial=serial))
    options = HarnessOptions(eeprom_file=tmp_path / "eeprom.bin")
    ids = []
    for process in range(2):  # the same board (its EEPROM) in two harness processes
        with AvrBoard(cfg, options) as b:
            h = SerialHost(b.port)
            for boot in range(3):
                if boot:
                    b.press_reset()
                reply = h.handshake()
                count = eeprom.read_boot_count(b.eeprom())
                assert count == 3 * process + boot + 1, (process, boot)
                assert reply.boot_id == eeprom.boot_id(count, serial) != 0
                h.keepalive = heartbeat
                beat = h.wait_type(Heartbeat, 1.0)
                assert beat.boot_id == reply.boot_id
                h.keepalive = None
                ids.append(reply.boot_id)
            h.close()
    assert len(set(ids)) == len(ids) == 6
    image = (tmp_path / "eeprom.bin").read_bytes()
    slots = struct.unpack_from(f"<{eeprom.BOOT_COUNT_SLOTS}I", image, eeprom.BOOT_COUNT_BASE)
    assert sorted(slots) == [3, 4, 5, 6] and all(
        c % eeprom.BOOT_COUNT_SLOTS == i for i, c in enumerate(slots)
    )
    assert eeprom.boot_id(6, "BENCH-8") != eeprom.boot_id(6, serial)
