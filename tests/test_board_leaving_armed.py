"""Leaving ARMED withdraws the armed rotor pulse at once (issue 25, finding 7), on the sans-IO board in
lockstep.

The board once kept reporting the armed rotor width (e.g. 1700 µs) with state DISARMED for up to a pulse
frame after a Disarm: the state changed when the main loop handled the command, but the widths it
reports were recomputed only at the next pulse frame. The C firmware (``firmware/src/app.c``,
``enter_state``) applies the stopped outputs in the same main-loop pass as the state change, before it
reports anything: telemetry carries the safe width from then on, and the pins carry it from the next frame
start (the compare registers are double-buffered: a pulse already under way is never cut short). These
tests hold the Python board to the same at drawn moments of the pulse frame and the telemetry period, for
every way out of ARMED the host can cause: a Disarm, a Hello, and its own silence (link-loss FAILSAFE).
"""

from __future__ import annotations

from conformance.host import heartbeat, lockstep
from hypothesis import example, given, settings
from hypothesis import strategies as st

from firmware_sim.board.config import BoardConfig
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    Disarm,
    Heartbeat,
    Telemetry,
    UnitSetpoint,
)
from protocol.pulse_widths import FINE_PER_US

SPIN = ActuatorSetpoint(units=(UnitSetpoint(0.3, 450.0), UnitSetpoint(-0.3, 500.0)))
EXITS = {"disarm": BoardState.DISARMED, "hello": BoardState.DISARMED, "silence": BoardState.FAILSAFE}


def _rotors_safe(widths, safe: int) -> bool:
    """Every rotor channel (odd channels) at or below the safe width (0/None: no pulse)."""
    return all((w or 0) <= safe for w in widths[1::2])


@settings(max_examples=120, deadline=None)
@given(
    frame_rate=st.sampled_from([50.0, 100.0, 333.0, 490.0]),
    telemetry_rate=st.sampled_from([20.0, 50.0, 333.0, 1000.0]),
    phase_us=st.integers(0, 20_000),
    exit=st.sampled_from(sorted(EXITS)),
)
@example(frame_rate=50.0, telemetry_rate=1000.0, phase_us=3_000, exit="disarm")
@example(frame_rate=100.0, telemetry_rate=1000.0, phase_us=1_000, exit="silence")
@example(frame_rate=50.0, telemetry_rate=20.0, phase_us=9_000, exit="disarm")  # a Disarm on a frame's tick
def test_no_armed_rotor_pulse_is_reported_or_driven_once_the_board_has_left_armed(
    frame_rate, telemetry_rate, phase_us, exit
):
    """From the main-loop tick that leaves ARMED on, no Telemetry reports a rotor above the safe width, and
    no pulse frame in the board's own record carries one; the frame before the change still did (so the
    check is about the change, not about a board that was never moving)."""
    cfg = BoardConfig(n_units=2, frame_rate_hz=frame_rate, telemetry_rate_hz=telemetry_rate)
    safe = cfg.rotor_safe_us
    board, clock, host = lockstep(cfg)
    host.handshake()
    host.keepalive = heartbeat
    assert isinstance(host.request(Arm()), Ack)
    armed_from = len(host.received)
    host.keepalive = lambda: SPIN
    host.poll(0.3)
    assert board.state is BoardState.ARMED
    assert all(board.targets[ch] / FINE_PER_US > safe + 100 for ch in (1, 3))
    host.poll(phase_us / 1e6)  # the change lands anywhere in a pulse frame and a telemetry period
    changed_from = len(host.received)
    if exit == "disarm":
        host.keepalive = heartbeat
        assert isinstance(host.request(Disarm()), Ack)
    elif exit == "hello":
        host.keepalive = heartbeat
        host.handshake()
    else:
        host.keepalive = None  # the host goes quiet: FAILSAFE after the link timeout
    host.poll(cfg.link_timeout_s + 0.1 if exit == "silence" else 0.1)
    new = EXITS[exit]
    assert board.state is new
    # The state change's Heartbeat is stamped with the main-loop tick that made it (whole ms of uptime).
    beat = next(m for m in host.received[changed_from:] if isinstance(m, Heartbeat) and m.state == new)
    t_change = board.resets[-1].t + beat.time_ms / 1000

    tels = [m for m in host.received[armed_from:] if isinstance(m, Telemetry)]
    assert any(t.state is new for t in tels)
    late = [t for t in tels if t.state is not BoardState.ARMED and not _rotors_safe(t.pulses_us, safe)]
    assert not late, f"telemetry reports an armed rotor pulse after leaving ARMED: {late[0]}"
    # (a telemetry of the change's own millisecond may precede it: a frame fed exactly on a tick is
    # handled in a second pass of that tick)
    assert all(t.state is new for t in tels if t.time_ms > beat.time_ms)

    frames = list(board.timeline.frames)
    # a frame due at the change's own instant may start before it, as its telemetry may: a command fed
    # exactly on the tick is handled in that tick's second pass, after the frame under way began (a real
    # MCU's timer fires before its main loop reads the byte that ends the frame); every later one is safe
    after = [f for f in frames if f.t > t_change + 1e-9]
    before = [f for f in frames if f.t < t_change - 1e-9]
    assert after and before
    assert not _rotors_safe(before[-1].widths, safe)  # the frame under way at the change was armed
    bad = [f for f in after if not _rotors_safe(f.widths, safe)]
    assert not bad, f"pulse frame at {bad[0].t:.6f} s after the change at {t_change:.6f} s: {bad[0]}"
    # what the board says it puts out is what it now aims at: the safe rotor width, at once
    assert _rotors_safe(board.reported_outputs(), safe)
