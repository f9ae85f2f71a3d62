"""The board firmware under simavr, ARMED and spinning, its UBEC rail dipping into the brown-out zone
(under ``brownout_release_v``, 4.5 V, above the MCU's 4.3 V reset level) and coming back: the rotors go
to the safe pulse and stay there until a new ``Arm``, as after a SHED. (A dip straight to BROWN_OUT
skipped the SHED latch: the rotors started again by themselves when the rail returned.)

The dip's depth and length are drawn (the seed is in every assertion message)."""

from __future__ import annotations

import random

import pytest
from conformance.host import SerialHost, heartbeat

from firmware_sim.avr import AvrBoard
from firmware_sim.board.config import BoardConfig
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    GimbalMode,
    PowerState,
    ResetCause,
    Telemetry,
    UnitSetpoint,
)

CONFIG = BoardConfig(n_units=2, telemetry_rate_hz=50.0, link_timeout_s=0.5)
HEALTHY = "power 12.4 3.0 5.0 0.5"  # battery V, A, rail V, A (the harness's analog inputs)


def setpoint() -> ActuatorSetpoint:
    return ActuatorSetpoint(
        gimbal_mode=GimbalMode.RATE, units=tuple(UnitSetpoint(0.0, 400.0) for _ in range(CONFIG.n_units))
    )


def rotor_widths(board: AvrBoard, t0: float, t1: float) -> set[float]:
    return {f.widths[1] for f in board.timeline() if t0 <= f.t < t1}


@pytest.mark.firmware
def test_a_rail_dip_into_the_brown_out_zone_latches_the_rotors_off_until_an_arm():
    seed = random.randrange(2**32)
    rng = random.Random(seed)
    rail_v, dip_s = rng.uniform(4.32, 4.48), rng.uniform(0.15, 0.4)
    why = f"seed {seed}: the rail at {rail_v:.3f} V for {dip_s:.2f} s"
    with AvrBoard(CONFIG) as board:
        host = SerialHost(board.port, clock=board.now)
        host.handshake()
        host.keepalive = heartbeat
        assert isinstance(host.request(Arm()), Ack)
        host.keepalive = setpoint
        board.command(HEALTHY)
        host.stream(0.5)
        t_dip = board.now()
        assert min(rotor_widths(board, t_dip - 0.2, t_dip)) > CONFIG.rotor_safe_us, why
        board.command(f"power 12.4 3.0 {rail_v:.3f} 0.5")
        host.stream(dip_s)
        t_back = board.now()
        board.command(HEALTHY)
        host.stream(0.6)
        t_end = board.now()
        assert [r.cause for r in board.resets()] == [ResetCause.POWER_ON], why  # no reset: above 4.3 V
        tel = [m for m in host.received if isinstance(m, Telemetry)]
        assert any(m.power == PowerState.BROWN_OUT for m in tel), why
        assert tel[-1].power == PowerState.NORMAL and tel[-1].state == BoardState.ARMED, why
        # the safe pulse from the first power sample in the zone (within 0.1 s) until the new Arm
        assert rotor_widths(board, t_dip + 0.1, t_end) == {CONFIG.rotor_safe_us}, (why, t_back)
        assert isinstance(host.request(Arm()), Ack), why
        t_arm = board.now()
        host.stream(0.4)
        assert min(rotor_widths(board, t_arm + 0.2, board.now())) > CONFIG.rotor_safe_us, why
        host.close()
        board.check()
