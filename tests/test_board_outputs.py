"""Pulse outputs, actuator response, telemetry and the closed-loop hook of the sans-IO board (lockstep)."""

from __future__ import annotations

import math

import pytest
from conformance.host import lockstep

from firmware_sim.board.config import BoardConfig
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    ControlMode,
    FaultFlag,
    GimbalMode,
    Heartbeat,
    Log,
    RawPulses,
    SetMode,
    Telemetry,
    UnitSetpoint,
    UnitState,
)
from protocol.pulse_widths import FINE_PER_US, fine_width, reported_us

CFG = BoardConfig(n_units=2, frame_rate_hz=100.0, telemetry_rate_hz=50.0, heartbeat_rate_hz=5.0)


def armed(cfg=CFG, setpoint=None):
    board, clock, host = lockstep(cfg)
    host.handshake()
    assert isinstance(host.request(Arm()), Ack)
    if setpoint is not None:
        host.keepalive = lambda: setpoint
    return board, clock, host


def pulse_bounds(cal, speed, volts, dv=0.05):
    """Rotor pulse range for a battery voltage known to ±dv (the board converts at its filtered reading)."""
    a = cal.rotor_pulse_us(speed, volts - dv).value
    b = cal.rotor_pulse_us(speed, volts + dv).value
    return math.floor(min(a, b)) - 1, math.ceil(max(a, b)) + 1


def test_setpoints_become_pulses_through_the_calibration_map():
    sp = ActuatorSetpoint(
        gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(0.4, 300.0), UnitSetpoint(-0.8, 150.0))
    )
    board, clock, host = armed(setpoint=sp)
    host.poll(0.5)
    tel = host.wait_type(Telemetry, 0.1)
    volts = tel.battery_mv / 1000
    for i, u in enumerate(sp.units):
        cal = board.calibrations[i]
        gimbal = cal.gimbal_pulse_us(u.gimbal, GimbalMode.RATE).value
        assert board.targets[2 * i] == fine_width(gimbal)  # to 1/512 µs, not to the µs
        assert tel.pulses_us[2 * i] == reported_us(fine_width(gimbal))
        lo, hi = pulse_bounds(cal, u.rotor_speed, volts)
        assert lo <= tel.pulses_us[2 * i + 1] <= hi
    # the timeline carries the target dithered in whole 0.5 µs ticks: the frames around the telemetry are
    # within a tick of what telemetry reports, and the last 10 frames' mean is the fine width
    t_tel = board.resets[-1].t + tel.time_ms / 1000
    frame = [f for f in board.timeline.frames if f.t <= t_tel + 1e-9][-1]
    assert all(abs(w - p) <= 0.5 for w, p in zip(frame.widths, tel.pulses_us, strict=True))
    edges = board.timeline.edges(channel=0, since=clock.now() - 0.1)
    widths = [e.width_us for e in edges]
    target = board.targets[0] / FINE_PER_US
    assert len(edges) == 10 and set(widths) == {math.floor(2 * target) / 2, math.floor(2 * target) / 2 + 0.5}
    assert sum(widths) / 10 == pytest.approx(target, abs=0.5 / 10)


def test_frames_keep_exact_period_at_490_hz():
    board, clock, host = lockstep(BoardConfig(n_units=1, frame_rate_hz=490.0, timeline_frames=10_000))
    host.poll(5.0)
    frames = list(board.timeline.frames)
    t0 = frames[0].t
    assert t0 == pytest.approx(board.resets[-1].t + board.config.boot_time_s, abs=1e-9)
    for k, f in enumerate(frames):
        assert f.t == pytest.approx(t0 + k / 490.0, abs=1e-6)  # integer-µs schedule, no drift
    assert len(frames) == math.floor((clock.now() - t0) * 490.0) + 1


def test_telemetry_and_heartbeat_rates():
    board, clock, host = lockstep(CFG)
    host.handshake()
    host.keepalive = Heartbeat
    start = len(host.received)
    host.poll(2.0)
    got = host.received[start:]
    tels = [m for m in got if isinstance(m, Telemetry)]
    beats = [m for m in got if isinstance(m, Heartbeat)]
    assert len(tels) in (99, 100, 101)
    assert len(beats) in (9, 10, 11)
    dts = {b.time_ms - a.time_ms for a, b in zip(tels, tels[1:], strict=False)}
    assert dts == {20}


def test_rotor_follows_a_first_order_lag():
    board, clock, host = armed()
    host.keepalive = lambda: ActuatorSetpoint(units=(UnitSetpoint(0.0, 400.0), UnitSetpoint(0.0, 0.0)))
    host.poll(0.011)
    t_change = next(f.t for f in board.timeline.frames if f.widths[1] > 1100)
    tau = board.config.motor.time_constant_s
    clock.set(t_change + tau)
    board.step()
    target = board.units[0].steady_rotor_speed(board.outputs[1], board.power.battery_v)
    assert board.units[0].rotor_speed == pytest.approx((1 - math.exp(-1)) * target, rel=0.03)
    host.poll(1.5)
    target = board.units[0].steady_rotor_speed(board.outputs[1], board.power.battery_v)
    assert board.units[0].rotor_speed == pytest.approx(target, rel=0.01)
    assert board.units[1].rotor_speed == 0.0


def test_gimbal_rate_integrates_to_the_analytic_angle():
    board, clock, host = armed(
        setpoint=ActuatorSetpoint(units=(UnitSetpoint(0.5, 0.0), UnitSetpoint(0.0, 0.0)))
    )
    host.poll(0.011)
    t_change = next(f.t for f in board.timeline.frames if f.widths[0] != board.timeline.frames[0].widths[0])
    cal = board.calibrations[0]
    target = board.targets[0] / FINE_PER_US  # the mean width; the frames dither it in 0.5 µs ticks
    rate = cal.gimbal_value(target, GimbalMode.RATE).value
    # one tick's worth of rate: what one frame of the dither may be off by
    tick_rate = cal.gimbal_value(target + 0.5, GimbalMode.RATE).value - rate
    frame_s = 1.0 / board.config.frame_rate_hz
    host.poll(1.0)
    T = clock.now() - t_change
    tau = board.config.gimbal.time_constant_s
    angle = rate * (T - tau * (1 - math.exp(-T / tau)))
    assert board.units[0].gimbal_angle == pytest.approx(angle, abs=tick_rate * frame_s)
    assert board.units[0].gimbal_rate == pytest.approx(rate, abs=tick_rate)


def test_gimbal_angle_mode_converges_slew_limited():
    sp = ActuatorSetpoint(
        gimbal_mode=GimbalMode.ANGLE, units=(UnitSetpoint(1.0, 0.0), UnitSetpoint(-0.5, 0.0))
    )
    board, clock, host = armed(setpoint=sp)
    host.poll(0.1)
    assert abs(board.units[0].gimbal_rate) <= board.config.gimbal.max_rate_rad_s + 1e-12
    host.poll(2.0)
    cal = board.calibrations[0]
    want0 = cal.gimbal_value(board.outputs[0], GimbalMode.ANGLE).value
    want1 = board.calibrations[1].gimbal_value(board.outputs[2], GimbalMode.ANGLE).value
    assert board.units[0].gimbal_angle == pytest.approx(want0, abs=1e-3)
    assert board.units[1].gimbal_angle == pytest.approx(want1, abs=1e-3)
    assert want0 == pytest.approx(1.0, abs=0.01)  # the map's round trip


def test_failsafe_in_angle_mode_holds_the_gimbals_where_they_are():
    sp = ActuatorSetpoint(
        gimbal_mode=GimbalMode.ANGLE, units=(UnitSetpoint(3.0, 0.0), UnitSetpoint(-3.0, 0.0))
    )
    board, clock, host = armed(setpoint=sp)
    host.poll(0.4)  # slewing towards ±3 rad at the servo's 2 rad/s at most
    host.keepalive = None
    host.poll(CFG.link_timeout_s + 0.05)
    assert board.state is BoardState.FAILSAFE
    held = [u.gimbal_angle for u in board.units]
    assert 0.3 < held[0] < 2.5 and -2.5 < held[1] < -0.3  # caught mid-slew
    host.poll(1.0)
    for i, unit in enumerate(board.units):
        assert unit.gimbal_angle == pytest.approx(held[i], abs=0.02)  # held, not carried on to the target
        want = board.calibrations[i].gimbal_pulse_us(held[i], GimbalMode.ANGLE).value
        assert board.outputs[2 * i] == pytest.approx(want, abs=1.0)  # the pulse that stands for it
        assert board.outputs[2 * i + 1] == CFG.rotor_safe_us


def test_raw_pulses_mode_passes_widths_through():
    board, clock, host = lockstep(CFG)
    host.handshake()
    assert isinstance(host.request(SetMode(mode=ControlMode.RAW_PULSES)), Ack)
    assert isinstance(host.request(Arm()), Ack)
    host.keepalive = lambda: RawPulses(pulses_us=(1234, 1400, 1777, 1111))
    host.poll(0.2)
    assert board.outputs == (1234, 1400, 1777, 1111)
    tel = host.wait_type(Telemetry, 0.1)
    assert tel.mode == ControlMode.RAW_PULSES and tel.pulses_us == (1234, 1400, 1777, 1111)
    bad_before = board.counters["bad_setpoints"]
    host.send(RawPulses(pulses_us=(1500,)))
    host.poll(0.05)
    assert board.counters["bad_setpoints"] == bad_before + 1
    assert any(isinstance(m, Log) and "raw pulses for 1 channels" in m.text for m in host.received)
    host.send(ActuatorSetpoint(units=(UnitSetpoint(0.0, 100.0), UnitSetpoint(0.0, 100.0))))
    host.poll(0.05)
    assert board.outputs == (1234, 1400, 1777, 1111)  # setpoints are ignored in RAW_PULSES mode


def test_setpoints_before_arming_and_with_the_wrong_unit_count_are_ignored():
    board, clock, host = lockstep(CFG)
    host.handshake()
    host.keepalive = lambda: ActuatorSetpoint(units=(UnitSetpoint(0.5, 400.0), UnitSetpoint(0.5, 400.0)))
    host.poll(0.3)
    assert board.outputs[1::2] == (CFG.rotor_safe_us,) * 2
    assert board.counters["ignored_setpoints"] >= 5
    host.keepalive = None
    host.request(Arm())
    host.send(ActuatorSetpoint(units=(UnitSetpoint(0.5, 400.0),)))
    host.poll(0.05)
    assert board.counters["bad_setpoints"] == 1
    assert any(isinstance(m, Log) and "setpoint for 1 units" in m.text for m in host.received)


def test_saturated_setpoint_is_flagged_clamped():
    board, clock, host = armed(
        setpoint=ActuatorSetpoint(units=(UnitSetpoint(15.0, 0.0), UnitSetpoint(0.0, 0.0)))
    )
    host.poll(0.2)
    tel = host.wait_type(Telemetry, 0.05)
    assert tel.faults & FaultFlag.SETPOINT_CLAMPED
    cal = board.calibrations[0]
    assert tel.pulses_us[0] == round(cal.gimbal_pulse_us(15.0, GimbalMode.RATE).value)


def test_dead_esc_is_detected_and_its_rotor_stays_still():
    cfg = CFG.replace(dead_esc_detect_s=0.3)
    board, clock, host = armed(
        cfg, ActuatorSetpoint(units=(UnitSetpoint(0.0, 400.0), UnitSetpoint(0.0, 400.0)))
    )
    board.faults.dead_esc(3)
    host.poll(0.2)
    tel = host.wait_type(Telemetry, 0.05)
    assert not tel.faults & FaultFlag.DEAD_ESC
    host.poll(0.3)
    tel = host.wait_type(Telemetry, 0.05)
    assert tel.faults & FaultFlag.DEAD_ESC
    assert tel.units[1].rotor_speed == 0.0 and tel.units[0].rotor_speed > 100.0
    logs = [m.text for m in host.received if isinstance(m, Log) and "not responding" in m.text]
    assert logs == ["rotor ESC on channel 3 (unit 1) not responding"]


def test_world_states_override_the_internal_model():
    board, clock, host = armed(
        setpoint=ActuatorSetpoint(units=(UnitSetpoint(0.0, 300.0), UnitSetpoint(0.0, 300.0)))
    )
    host.poll(0.3)
    world = (UnitState(0.25, -0.5, 123.0), UnitState(-1.0, 0.0, 456.0))
    board.set_unit_states(world)
    host.poll(0.05)
    tel = host.wait_type(Telemetry, 0.05)
    assert tel.units == tuple(
        UnitState(*(float(_f32(x)) for x in (s.gimbal_angle, s.gimbal_rate, s.rotor_speed))) for s in world
    )
    board.set_unit_states(None)
    host.poll(0.5)
    assert board.unit_states()[0].rotor_speed != pytest.approx(123.0, abs=1.0)  # the model runs again
    with pytest.raises(ValueError, match="set_unit_states"):
        board.set_unit_states(world[:1])


def test_world_reporting_a_stalled_rotor_trips_dead_esc_detection():
    cfg = CFG.replace(dead_esc_detect_s=0.2)
    board, clock, host = armed(
        cfg, ActuatorSetpoint(units=(UnitSetpoint(0.0, 400.0), UnitSetpoint(0.0, 0.0)))
    )
    host.poll(0.5)
    board.set_unit_states((UnitState(0.0, 0.0, 0.0), UnitState(0.0, 0.0, 0.0)))
    host.poll(0.4)
    assert board.fault_flags() & FaultFlag.DEAD_ESC
    assert board.state is BoardState.ARMED


def test_timeline_is_a_bounded_ring():
    board, clock, host = lockstep(BoardConfig(n_units=1, frame_rate_hz=100.0, timeline_frames=50))
    host.poll(2.0)
    assert len(board.timeline.frames) == 50
    assert board.timeline.total_frames >= 195
    assert board.timeline.frames[0].t == pytest.approx(clock.now() - 0.49, abs=0.011)


def _f32(x):
    import struct

    return struct.unpack("<f", struct.pack("<f", x))[0]
