"""The emulated board (firmware_sim), ARMED and spinning, its UBEC rail folding back into the brown-out
zone (the gimbals driven past the UBEC's current limit: under ``brownout_release_v``, 4.5 V, above the
MCU's 4.3 V reset level) and coming back: the rotors go to the safe pulse and stay there until a new
``Arm``, as after a SHED — the firmware's rule (tests/test_firmware_brownout_latch.py). The current limit,
so the depth of the dip, is drawn."""

from __future__ import annotations

from conformance.host import lockstep
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.board.config import BoardConfig, UbecParams
from protocol.messages import Ack, ActuatorSetpoint, Arm, BoardState, PowerState, ResetCause, UnitSetpoint

CFG = BoardConfig(n_units=4, frame_rate_hz=100.0, telemetry_rate_hz=100.0, link_timeout_s=0.25)


def setpoint(gimbal_rate: float) -> ActuatorSetpoint:
    return ActuatorSetpoint(units=tuple(UnitSetpoint(gimbal_rate, 450.0) for _ in range(CFG.n_units)))


@settings(max_examples=4, deadline=None)
@given(limit_a=st.floats(0.98, 1.01))  # the rail folds back to ~4.34 .. 4.47 V
def test_a_rail_dip_into_the_brown_out_zone_latches_the_rotors_off_until_an_arm(limit_a):
    cfg = CFG.replace(power=CFG.power.__class__(ubec=UbecParams(current_limit_a=limit_a)))
    board, _, host = lockstep(cfg)
    host.handshake()
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: setpoint(0.0)
    host.poll(1.0)
    assert all(w > cfg.rotor_safe_us for w in board.outputs[1::2])
    host.keepalive = lambda: setpoint(1.5)  # the gimbals draw past the UBEC's limit
    host.poll(0.5)
    assert board.power_state is PowerState.BROWN_OUT
    assert all(w == cfg.rotor_safe_us for w in board.outputs[1::2])
    host.keepalive = lambda: setpoint(0.0)  # the rail comes back
    host.poll(0.5)
    assert board.power_state is PowerState.NORMAL and board.state is BoardState.ARMED
    assert all(w == cfg.rotor_safe_us for w in board.outputs[1::2])  # latched until a new Arm
    assert [r.cause for r in board.resets] == [ResetCause.POWER_ON]
    host.keepalive = None
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: setpoint(0.0)
    host.poll(0.3)
    assert all(w > cfg.rotor_safe_us for w in board.outputs[1::2])
