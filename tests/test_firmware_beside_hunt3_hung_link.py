"""A main loop that hangs while ARMED: the rotors go to the safe pulse at the link timeout (plus one frame),
not at the MCU watchdog's reset — on the C firmware and on the Python board alike.

docs/protocol.md ("Link watchdog"): if the board's main loop handles no valid frame for ``link_timeout``,
an ARMED board's rotors go to the safe pulse no later than the next pulse frame. A hung main loop handles
none, whatever the host sends. The firmware keeps that promise from its 1 kHz tick interrupt
(``app_tick``: the rotor channels held at the safe pulse at the timeout, plus a 4 ms grace while
received bytes wait). The Python board modelled no such interrupt: its rotors ran on at their last width
through the whole hang, until the MCU watchdog reset it (0.5 s by default, up to 8 s), so a fault
campaign on the emulator saw spinning rotors that the firmware had long stopped.

Drawn: the moment of the hang (over the first setpoints, the spin-up and the steady run), whether the host
keeps streaming through it, and the MCU watchdog's period. Judged on each board's own pulse record: every
frame from the link timeout + grace + one frame (+ a tick) after the last frame the board handled until
its reset has every rotor channel at the safe pulse, and the reset's cause is WATCHDOG.
"""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from hypothesis import HealthCheck, given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from hil.timing.clock import LockstepClock
from protocol.frame import encode_frame
from protocol.messages import (
    SCHEMA_HASH,
    ActuatorSetpoint,
    Arm,
    BoardState,
    Flags,
    GimbalMode,
    Hello,
    ResetCause,
    UnitSetpoint,
)

GRACE_S = 0.004  # firmware/src/app.c: LINK_GRACE_MS
TICK_S = 0.001  # the firmware's link watchdog counts whole ms
SETPOINT_PERIOD_S = 0.02


def config(watchdog_s: float) -> BoardConfig:
    return BoardConfig(n_units=2, frame_rate_hz=100.0, link_timeout_s=0.25, mcu_watchdog_s=watchdog_s)


def run(board, clock: LockstepClock, dt: float) -> None:
    end = clock.now() + dt
    while clock.now() < end - 1e-9:
        clock.set(max(min(end, board.next_deadline(), clock.now() + 0.005), clock.now() + 1e-6))
        board.step()
        board.take_output()


def play(board, clock: LockstepClock, hang_after: float, streaming: bool) -> tuple[float, float]:
    """Hello, Arm, a stream of setpoints; the main loop hangs ``hang_after`` s into it. Returns (when the
    board last handled a frame before the hang: the link watchdog's origin, the hang's time)."""
    cfg = board.config
    sp = ActuatorSetpoint(GimbalMode.RATE, tuple(UnitSetpoint(0.2, 400.0) for _ in range(cfg.n_units)))
    run(board, clock, 0.2)
    board.feed(encode_frame(Hello(schema_hash=SCHEMA_HASH), 0, 0))
    run(board, clock, 0.05)
    board.feed(encode_frame(Arm(), 1, int(Flags.ACK_REQUESTED)))
    run(board, clock, 0.05)
    assert board.state is BoardState.ARMED
    hang_at = clock.now() + hang_after
    board.faults.hang(at=hang_at)
    seq, last_fed = 2, clock.now()
    while clock.now() < hang_at + cfg.mcu_watchdog_s + 0.3:
        if streaming or clock.now() < hang_at:
            board.feed(encode_frame(sp, seq & 0xFF, 0))
            seq += 1
            if clock.now() < hang_at:
                last_fed = clock.now()
        run(board, clock, SETPOINT_PERIOD_S)
    return last_fed, hang_at


def check(board, last_fed: float, hang_at: float) -> None:
    cfg = board.config
    resets = [r for r in board.resets if r.t > hang_at]
    assert resets and resets[0].cause is ResetCause.WATCHDOG, board.resets
    reset_at = resets[0].t
    frame_s = 1.0 / cfg.frame_rate_hz
    line_s = 0.005  # a setpoint frame's time on the firmware's UART (115200 baud): handled that late
    stopped_by = max(last_fed + line_s + cfg.link_timeout_s, hang_at) + GRACE_S + TICK_S + frame_s
    frames = [f for f in board.timeline.frames if stopped_by <= f.t < reset_at]
    assert frames, "no frame between the link timeout and the reset: the draw left no window"
    safe = float(cfg.rotor_safe_us)
    for f in frames:
        rotors = [w for ch, w in enumerate(f.widths) if ch % 2]
        assert all(w == safe for w in rotors), (
            f"{type(board).__name__}: rotors {rotors} µs at {f.t:.4f} s in a main loop hung since "
            f"{hang_at:.4f} s (link timeout at {last_fed + cfg.link_timeout_s:.4f} s, reset {reset_at:.4f} s)"
        )


draws = dict(
    hang_after=st.floats(0.0, 0.6),
    streaming=st.booleans(),
    watchdog_s=st.sampled_from([0.5, 0.8, 1.5]),
)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**draws)
def test_the_python_board_stops_its_rotors_at_the_link_timeout_in_a_hung_main_loop(
    hang_after, streaming, watchdog_s
):
    clock = LockstepClock()
    board = Board(config(watchdog_s), clock)
    last_fed, hang_at = play(board, clock, hang_after, streaming)
    check(board, last_fed, hang_at)


@pytest.mark.firmware
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**draws)
def test_the_firmware_stops_its_rotors_at_the_link_timeout_in_a_hung_main_loop(
    hang_after, streaming, watchdog_s
):
    from firmware_sim.avr.stepped import FirmwareBoard

    clock = LockstepClock()
    with FirmwareBoard(config(watchdog_s), clock=clock) as board:
        last_fed, hang_at = play(board, clock, hang_after, streaming)
        check(board, last_fed, hang_at)
