"""A pulse longer than its frame: at 490 Hz (the top of ``frame_rate_hz``) a frame lasts 2041 µs, yet a
``RawPulses`` of 2500 µs (the top of the protocol's range), a map's width or a safe rotor pulse past it
were put out as asked.

On the ATmega2560 a width past the frame leaves OCRnx at or beyond the timer's TOP, and fast-PWM mode 14
then never clears the pin: a constant high, no pulse at all to a servo or an ESC — while the Python board
reported 2500 µs pulses, frame after frame (the two far sides answering differently). Now every width is
cut to the frame's longest pulse (its period less ``PULSE_GAP_US``), the same on both boards, and said
(``Telemetry`` ``clamped``); a configuration whose safe rotor pulse (which goes out unclamped, from the
link watchdog's tick interrupt) does not fit its frame is refused by both, naming ``rotor_safe_us``.

Judged on each board's own pulse record (the simavr harness stamps the pins' edges): pulse frames keep
coming at the frame rate, every width in them lies within the frame, and both boards agree.
"""

from __future__ import annotations

import struct

import hypothesis.strategies as st
import pytest
from hypothesis import HealthCheck, given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig, longest_pulse_fine
from hil.timing.clock import LockstepClock
from protocol.crc import crc16_ccitt_false
from protocol.errors import ConfigError
from protocol.frame import encode_frame
from protocol.messages import (
    ESC_CALIBRATION_CONFIRM,
    SCHEMA_HASH,
    Arm,
    BoardState,
    ControlMode,
    EscCalibrate,
    Flags,
    Hello,
    NackReason,
    RawPulses,
    SetMode,
)
from protocol.pulse_widths import FINE_PER_US


def run(board, clock: LockstepClock, dt: float) -> None:
    end = clock.now() + dt
    while clock.now() < end - 1e-9:
        clock.set(max(min(end, board.next_deadline(), clock.now() + 0.005), clock.now() + 1e-6))
        board.step()
        board.take_output()


def raw_pulses_run(board, clock: LockstepClock, widths: tuple[int, ...]) -> float:
    """Hello, RAW_PULSES, Arm, then ``widths`` every 20 ms for 0.2 s: returns when the stream began."""
    run(board, clock, 0.2)
    board.feed(encode_frame(Hello(schema_hash=SCHEMA_HASH), 0, 0))
    run(board, clock, 0.05)
    board.feed(encode_frame(SetMode(ControlMode.RAW_PULSES), 1, int(Flags.ACK_REQUESTED)))
    run(board, clock, 0.05)
    board.feed(encode_frame(Arm(), 2, int(Flags.ACK_REQUESTED)))
    run(board, clock, 0.05)
    assert board.state is BoardState.ARMED
    start = clock.now()
    for seq in range(3, 13):
        board.feed(encode_frame(RawPulses(widths), seq, 0))
        run(board, clock, 0.02)
    return start


def check(board, start: float, end: float) -> list[tuple[float, ...]]:
    """Every frame from 50 ms into the stream: present at the frame rate, each width inside the frame."""
    cfg = board.config
    period = 1.0 / cfg.frame_rate_hz
    longest_us = longest_pulse_fine(cfg.frame_rate_hz) / FINE_PER_US
    frames = [f for f in board.timeline.frames if start + 0.05 <= f.t < end]
    expected = (end - start - 0.05) / period
    assert len(frames) >= 0.9 * expected, (
        f"{type(board).__name__}: {len(frames)} pulse frames in {end - start - 0.05:.3f} s at "
        f"{cfg.frame_rate_hz} Hz (~{expected:.0f} due): a pin held high puts out none"
    )
    for f in frames:
        # None: no falling edge in the frame, the pin held high (or low) through it
        assert all(w is not None and w <= longest_us + 0.5 for w in f.widths), (
            f"{type(board).__name__}: {f.widths} µs at {f.t:.4f} s in a {period * 1e6:.0f} µs frame"
        )
    return [f.widths for f in frames]


rates = st.sampled_from([392.0, 400.0, 450.0, 490.0])
width = st.sampled_from([500, 1500, 2020, 2021, 2022, 2040, 2041, 2042, 2499, 2500])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rate=rates, data=st.data())
def test_the_python_board_never_reports_a_pulse_longer_than_its_frame(rate, data):
    cfg = BoardConfig(n_units=2, frame_rate_hz=rate)
    widths = tuple(data.draw(width) for _ in range(cfg.n_channels))
    clock = LockstepClock()
    board = Board(cfg, clock)
    start = raw_pulses_run(board, clock, widths)
    longest_us = longest_pulse_fine(rate) / FINE_PER_US
    for got in check(board, start, clock.now()):
        assert got == tuple(min(w, longest_us) for w in widths)


@pytest.mark.firmware
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rate=rates, data=st.data())
def test_the_firmware_keeps_pulsing_and_agrees_with_the_python_board_at_a_pulse_past_its_frame(rate, data):
    from firmware_sim.avr.stepped import FirmwareBoard

    cfg = BoardConfig(n_units=2, frame_rate_hz=rate)
    widths = tuple(data.draw(width) for _ in range(cfg.n_channels - 1)) + (2500,)
    clock = LockstepClock()
    with FirmwareBoard(cfg, clock=clock) as board:
        start = raw_pulses_run(board, clock, widths)
        got = check(board, start, clock.now())
    py_clock = LockstepClock()
    py = Board(cfg, py_clock)
    py_start = raw_pulses_run(py, py_clock, widths)
    want = check(py, py_start, py_clock.now())
    assert set(got) == set(want), f"firmware {set(got)} µs, Python board {set(want)} µs"


@pytest.mark.parametrize(
    ("rate", "safe_us", "takes"),
    [
        (490.0, 2021, True),
        (490.0, 2022, False),
        (400.0, 2480, True),
        (400.0, 2481, False),
        (392.0, 2500, True),
    ],
)
def test_a_safe_rotor_pulse_past_the_frame_is_refused_by_the_emulators_config(rate, safe_us, takes):
    cfg = BoardConfig(frame_rate_hz=rate, rotor_safe_us=safe_us)
    if takes:
        cfg.validate()
    else:
        with pytest.raises(ConfigError, match="rotor_safe_us"):
            cfg.validate()


@pytest.mark.firmware
@pytest.mark.parametrize(
    ("rate", "safe_us", "takes"),
    [
        (490.0, 2021, True),
        (490.0, 2022, False),
        (400.0, 2480, True),
        (400.0, 2500, False),
        (392.0, 2500, True),
    ],
)
def test_a_safe_rotor_pulse_past_the_frame_is_refused_by_the_firmwares_config(rate, safe_us, takes):
    from firmware_sim.avr import eeprom
    from firmware_sim.avr.hostlib import config_parse

    body = bytearray(eeprom.config_block(BoardConfig())[:-2])
    offsets = eeprom.field_offsets()
    body[offsets["frame_rate_hz"] : offsets["frame_rate_hz"] + 4] = struct.pack("<f", rate)
    body[offsets["rotor_safe_us"] : offsets["rotor_safe_us"] + 2] = struct.pack("<H", safe_us)
    status, got, problem = config_parse(bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body))))
    assert (status == 0) is takes
    if not takes:
        assert status == 3 and problem == 8  # config.c: BAD_ROTOR_SAFE_US, "rotor_safe_us"
        assert got["rotor_safe_us"] == BoardConfig().rotor_safe_us


@pytest.mark.firmware
@pytest.mark.parametrize(("high_us", "takes"), [(2021, True), (2022, False), (2500, False)])
def test_an_esc_endpoint_past_the_frame_is_refused_by_both_boards(high_us, takes):
    """At 490 Hz an ESC taught a 2500 µs top endpoint got a constant high from the firmware (or, cut to
    the frame, another endpoint than the one asked for and reported): both refuse it OUT_OF_RANGE."""
    from test_firmware_differential import Pair, hello

    cfg = BoardConfig(n_units=2, frame_rate_hz=490.0, esc_supply_switch=True)
    pair = Pair(cfg)
    try:
        pair.run(0.15)
        pair.send(hello())
        pair.run(0.1)
        seq = pair.send(
            EscCalibrate(
                unit=1,
                confirm=ESC_CALIBRATION_CONFIRM,
                low_us=1000,
                high_us=high_us,
                supply_off_ms=150,
                high_ms=200,
                low_ms=200,
            ),
            int(Flags.ACK_REQUESTED),
        )
        pair.run(0.1)
        for which, seen in pair.seen.items():
            answers = [a for a in seen.answers if a[0] in ("ack", "nack") and a[2] == seq]
            want = (
                ("ack", EscCalibrate.MSG_ID, seq)
                if takes
                else ("nack", EscCalibrate.MSG_ID, seq, NackReason.OUT_OF_RANGE.name)
            )
            assert answers == [want], which
    finally:
        pair.close()
