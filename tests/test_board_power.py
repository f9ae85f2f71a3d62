"""Power: battery (analytic sag, coulomb counting), UBEC rail, staged thresholds, and the board's
warn → limit → shed → brown-out sequence in lockstep time."""

from __future__ import annotations

import math

import pytest
from conformance.host import lockstep
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.board import McuPhase
from firmware_sim.board.config import BatteryParams, BoardConfig, PowerThresholds, UbecParams
from firmware_sim.board.power_models import Battery, PowerManager, ubec_output
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    FaultFlag,
    Heartbeat,
    Log,
    Nack,
    NackReason,
    PowerState,
    ResetCause,
    Telemetry,
    UnitSetpoint,
)


@settings(max_examples=60, deadline=None)
@given(power=st.floats(0.0, 200.0), soc=st.floats(0.0, 1.0), r=st.floats(0.001, 0.5))
def test_battery_terminal_voltage_solves_the_constant_power_load(power, soc, r):
    b = Battery(BatteryParams(internal_resistance_ohm=r, initial_soc=soc))
    voc = b.ocv()
    v, amps = b.terminal(power)
    if voc * voc >= 4 * r * power:
        assert v == pytest.approx(voc - r * amps, rel=1e-9, abs=1e-9)  # Ohm's law on the pack
        assert v * amps == pytest.approx(power, rel=1e-9, abs=1e-9)  # the load gets its power
        assert voc / 2 - 1e-9 <= v <= voc
    else:
        assert v == pytest.approx(voc / 2)  # past the pack's maximum power: collapse


def test_ocv_curve_and_coulomb_counting():
    b = Battery(BatteryParams(cells=3, capacity_mah=1000.0, initial_soc=1.0))
    assert b.ocv() == pytest.approx(12.6)
    b.discharge(1.0, 360.0)  # 1 A for 6 min = 100 mAh = 10 %
    assert b.soc == pytest.approx(0.9)
    assert b.ocv() == pytest.approx(3 * 4.08)
    b.soc = 0.55
    assert b.ocv() == pytest.approx(3 * (3.82 + 3.87) / 2)
    b.sag_v = 2.0
    assert b.ocv() == pytest.approx(3 * (3.82 + 3.87) / 2 - 2.0)


def test_ubec_regulates_folds_back_and_drops_out():
    p = UbecParams(set_voltage_v=5.0, current_limit_a=2.0, dropout_v=0.5)
    assert ubec_output(p, 12.0, 1.0) == (5.0, 1.0, False)
    v, a, over = ubec_output(p, 12.0, 4.0)
    assert over and v == pytest.approx(2.5) and a == pytest.approx(2.0)  # constant current at the limit
    v, a, over = ubec_output(p, 5.2, 1.0)
    assert not over and v == pytest.approx(4.7)  # in dropout


def test_power_stages_have_hysteresis():
    t = PowerThresholds(
        warn_v_cell=3.5, limit_v_cell=3.4, shed_v_cell=3.3, hysteresis_v_cell=0.1, filter_time_constant_s=0.0
    )
    pm = PowerManager(t, cells=1)
    down = [
        (3.6, PowerState.NORMAL),
        (3.45, PowerState.WARN),
        (3.35, PowerState.LIMIT),
        (3.25, PowerState.SHED),
    ]
    for v, want in down:
        assert pm.update(v, 0.01) is want, v
    up = [
        (3.35, PowerState.SHED),
        (3.41, PowerState.LIMIT),
        (3.45, PowerState.LIMIT),
        (3.55, PowerState.WARN),
        (3.59, PowerState.WARN),
        (3.61, PowerState.NORMAL),
    ]
    for v, want in up:
        assert pm.update(v, 0.01) is want, v


def test_power_filter_is_first_order():
    t = PowerThresholds(filter_time_constant_s=0.05)
    pm = PowerManager(t, cells=1)
    pm.update(4.0, 0.0)
    pm.update(3.0, 0.05)
    assert pm.filtered_v_cell == pytest.approx(3.0 + math.exp(-1.0))


CFG = BoardConfig(n_units=4, frame_rate_hz=100.0, telemetry_rate_hz=100.0, link_timeout_s=0.25)
FAST = ActuatorSetpoint(units=tuple(UnitSetpoint(0.0, 450.0) for _ in range(4)))


def spinning(cfg=CFG, seconds=1.5):
    board, clock, host = lockstep(cfg)
    host.handshake()
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: FAST
    host.poll(seconds)
    return board, clock, host


def test_telemetry_reports_the_power_system_consistently():
    board, clock, host = spinning()
    tel = host.wait_type(Telemetry, 0.05)
    b = board.battery
    assert tel.battery_ma > 1000  # four rotors at speed
    assert tel.battery_mv / 1000 == pytest.approx(b.ocv() - b.resistance * tel.battery_ma / 1000, abs=0.01)
    assert tel.ubec_mv == 5000 and tel.battery_soc == 100
    soc0 = board.battery.soc
    host.poll(2.0)
    assert board.battery.soc < soc0
    dsoc = (soc0 - board.battery.soc) * 1000 * 3.6  # coulombs
    assert dsoc == pytest.approx(board.power.battery_a * 2.0, rel=0.05)  # steady current for 2 s


def test_sag_warns_limits_sheds_then_browns_out():
    board, clock, host = spinning()
    t0 = clock.now()
    board.faults.sag(drop_v=9.0, ramp_s=3.0, duration=4.0)
    host.poll(3.5)
    tels = [m for m in host.received if isinstance(m, Telemetry) and m.time_ms >= 1000 * (t0 - 0.06)]
    first = {}
    for m in tels:
        first.setdefault(PowerState(m.power), m.time_ms)
    assert (
        first[PowerState.WARN]
        < first[PowerState.LIMIT]
        < first[PowerState.SHED]
        < first[PowerState.BROWN_OUT]
    )
    limited = [m for m in tels if m.power == PowerState.LIMIT and m.time_ms > first[PowerState.LIMIT] + 20]
    cal = board.calibrations[0]
    assert limited and all(m.faults & FaultFlag.SETPOINT_CLAMPED for m in limited)
    for m in limited:
        v = m.battery_mv / 1000
        lo, hi = cal.rotor_pulse_us(0.0, v).value, cal.rotor_pulse_us(1e9, v).value
        assert all(p <= round(lo + 0.5 * (hi - lo)) + 2 for p in m.pulses_us[1::2])
    shed = [m for m in tels if m.time_ms > first[PowerState.SHED] + 10]
    assert shed and all(all(p == CFG.rotor_safe_us for p in m.pulses_us[1::2]) for m in shed)
    assert any(isinstance(m, Log) and "SHED" in m.text for m in host.received)
    resets = board.resets
    assert resets[-1].cause is ResetCause.BROWN_OUT
    assert resets[-1].t > t0 + 2.0  # the rail only falls below 4.3 V once the pack is below ~4.8 V
    # Held in reset while the pack is flat: no heartbeats.
    assert board.phase is McuPhase.RESET
    n = len(host.received)
    host.poll(0.3)
    assert not any(isinstance(m, Heartbeat) for m in host.received[n:])
    host.poll(0.5)  # the sag ends at t0 + 4 s: the MCU boots
    assert board.phase is McuPhase.RUNNING and board.state is BoardState.BOOT
    host.keepalive = None
    assert host.handshake().reset_cause == ResetCause.BROWN_OUT


def test_shed_is_latched_and_arm_is_refused_while_shedding():
    board, clock, host = spinning()
    board.faults.sag(drop_v=2.9, ramp_s=0.2)  # 12.5 V -> ~9.6 V loaded: below shed (9.9 V)
    host.poll(1.0)
    assert board.power_state is PowerState.SHED  # the rotors stopped, the pack recovers only ~0.2 V
    assert all(w == CFG.rotor_safe_us for w in board.outputs[1::2])
    assert board.state is BoardState.ARMED  # shedding is a power stage, not a state change
    host.keepalive = None
    answer = host.request(Arm())
    assert isinstance(answer, Nack) and answer.reason == NackReason.POWER
    board.faults.clear()
    host.keepalive = lambda: FAST
    host.poll(0.5)
    assert board.power_state is PowerState.NORMAL
    assert all(w == CFG.rotor_safe_us for w in board.outputs[1::2])  # latched until a new Arm
    assert isinstance(host.request(Arm()), Ack)
    host.poll(0.2)
    assert all(w > CFG.rotor_safe_us for w in board.outputs[1::2])


def test_ubec_overcurrent_is_flagged():
    cfg = CFG.replace(power=CFG.power.__class__(ubec=UbecParams(current_limit_a=1.05)))
    board, clock, host = lockstep(cfg)
    host.handshake()
    host.request(Arm())
    host.keepalive = lambda: ActuatorSetpoint(units=tuple(UnitSetpoint(1.5, 0.0) for _ in range(4)))
    host.poll(0.5)
    assert board.state is BoardState.ARMED
    tel = host.wait_type(Telemetry, 0.05)
    assert tel.faults & FaultFlag.UBEC_OVERCURRENT
    assert 4500 < tel.ubec_mv < 5000  # folded back, still above the MCU's brown-out level
    assert board.resets[-1].cause is ResetCause.POWER_ON
    assert any(isinstance(m, Log) and "UBEC over current" in m.text for m in host.received)


UNIT_LOADS = st.lists(
    st.tuples(
        st.booleans(),  # gimbal driven
        st.booleans(),  # rotor driven
        st.floats(-5.0, 5.0),  # gimbal rate, rad/s
        st.floats(-2000.0, 2000.0),  # rotor speed, rad/s
        st.floats(-5000.0, 5000.0),  # rotor acceleration, rad/s²
    ),
    min_size=1,
    max_size=6,
)


@settings(max_examples=200, deadline=None)
@given(loads=UNIT_LOADS, battery_v=st.floats(0.0, 20.0))
def test_unit_loads_are_the_per_unit_references_summed_in_unit_order(loads, battery_v):
    """The supply's one loop gives the very floats the units' own load methods sum to."""
    from firmware_sim.board import Board
    from firmware_sim.board.power import unit_loads

    units = Board(BoardConfig(n_units=len(loads))).units
    for unit, (gimbal_on, rotor_on, rate, speed, accel) in zip(units, loads, strict=True):
        unit.gimbal_driven, unit.rotor_driven = gimbal_on, rotor_on
        unit.follow(0.0, rate, speed, 1.0, accel)
    gimbal_a = rotor_w = 0.0
    for unit in units:
        gimbal_a += unit.gimbal_current_a()
        rotor_w += unit.rotor_power_w(battery_v)
    assert unit_loads(units, battery_v) == (gimbal_a, rotor_w)
