"""Setpoint generation (rates, anti-windup, wire message) and the plant-side servo models."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from firmware_sim.world.models import Plant, ServoModel
from hil.control.motor_loops import ServoParams, SetpointGenerator
from hil.control.steering import SteeringOutput
from hil.vscmg import cubesat_1u
from protocol.errors import ConfigError
from protocol.frame import decode_frame, encode_frame
from protocol.messages import ActuatorSetpoint, GimbalMode

PARAMS = cubesat_1u()


def _command(gimbal_rate, rotor_accel):
    g = np.atleast_2d(np.asarray(gimbal_rate, float))
    z = np.zeros(1)
    return SteeringOutput(
        g, np.atleast_2d(np.asarray(rotor_accel, float)), np.zeros((1, 3)), z, g * 0, z + 1, z
    )


def test_control_rate_may_not_exceed_the_pulse_frame_rate():
    SetpointGenerator(PARAMS, 50.0, frame_rate_hz=50.0)
    with pytest.raises(ConfigError, match="faster than the pulse frame rate"):
        SetpointGenerator(PARAMS, 100.0, frame_rate_hz=50.0)


def test_rotor_speed_integrates_acceleration_with_anti_windup():
    gen = SetpointGenerator(PARAMS, 50.0, max_lead=20.0)
    gen.reset(np.full(4, 400.0))
    sp = gen.update(_command([0.1, -0.2, 0.0, 0.3], [10.0, -10.0, 0.0, 0.0]), np.full(4, 400.0))
    np.testing.assert_allclose(sp.rotor_speed[0], [400.2, 399.8, 400.0, 400.0])
    assert not sp.clamped[0]
    # an ESC that does not follow: the setpoint stops max_lead ahead of the measured speed
    for _ in range(200):
        sp = gen.update(_command([0.0] * 4, [100.0, 0.0, 0.0, 0.0]), np.full(4, 400.0))
    assert sp.rotor_speed[0, 0] == pytest.approx(420.0)
    assert sp.clamped[0]
    # and never past the speed limit, nor a gimbal rate past its limit
    sp = gen.update(_command([9.0, 0, 0, 0], [0.0] * 4), np.full(4, PARAMS.limits.max_rotor_speed))
    assert sp.gimbal_rate[0, 0] == PARAMS.limits.max_gimbal_rate


def test_one_run_on_floats_gives_the_batch_paths_bits():
    """The control tick's path (B = 1, Python floats) and the batch path (numpy, B = 2: the run and a
    companion) give the same bits over many ticks, through both limits, the anti-windup, NaN and ±0."""
    rng = np.random.default_rng(7)
    lim = PARAMS.limits
    specials = [np.nan, 0.0, -0.0, lim.max_gimbal_rate, -lim.max_gimbal_rate, 1e3, -1e3]
    one, batch = (
        SetpointGenerator(PARAMS, 50.0, max_lead=20.0),
        SetpointGenerator(PARAMS, 50.0, max_lead=20.0),
    )
    start = np.array([0.0, -0.0, 400.0, lim.max_rotor_speed])
    one.reset(start)
    batch.reset(np.stack([start, start[::-1]]))
    # a rotor at rest against a speed floor of 0: -0.0 meets 0.0 in the clamp (numpy keeps the second)
    floor0 = dataclasses.replace(PARAMS, limits=dataclasses.replace(lim, min_rotor_speed=0.0))
    rest_one, rest_batch = SetpointGenerator(floor0, 50.0), SetpointGenerator(floor0, 50.0)
    rest_one.reset(np.full(4, -0.0))
    rest_batch.reset(np.full((2, 4), -0.0))
    got = rest_one.update(_command([0.0] * 4, [-0.0] * 4), np.zeros(4))
    want = rest_batch.update(_command(np.zeros((2, 4)), np.full((2, 4), -0.0)), np.zeros((2, 4)))
    assert repr(got.rotor_speed[0].tolist()) == repr(want.rotor_speed[0].tolist()) == repr([0.0] * 4)
    for tick in range(300):
        rate = rng.normal(0.0, 2.0 * lim.max_gimbal_rate, 4)
        accel = rng.normal(0.0, 3000.0, 4)
        measured = rng.uniform(-50.0, lim.max_rotor_speed + 50.0, 4)
        if tick % 5 == 0:
            rate[tick % 4], accel[(tick + 1) % 4] = specials[tick % 7], specials[(tick + 3) % 7]
        if tick % 11 == 0:
            measured[tick % 4] = specials[tick % 3]
        got = one.update(_command(rate, accel), measured)
        cmd = SteeringOutput(
            np.stack([rate, rate[::-1]]),
            np.stack([accel, accel[::-1]]),
            np.zeros((2, 3)),
            np.zeros(2),
            np.zeros((2, 4)),
            np.ones(2),
            np.zeros(2),
        )
        want = batch.update(cmd, np.stack([measured, measured[::-1]]))
        assert got.gimbal_rate.shape == got.rotor_speed.shape == (1, 4) and got.clamped.shape == (1,)
        assert repr(got.gimbal_rate[0].tolist()) == repr(want.gimbal_rate[0].tolist())
        assert repr(got.rotor_speed[0].tolist()) == repr(want.rotor_speed[0].tolist())
        assert bool(got.clamped[0]) == bool(want.clamped[0])
        if tick % 13 == 0:  # keep NaN from sticking in the integrators for the rest of the run
            one.reset(start)
            batch.reset(np.stack([start, start[::-1]]))


def test_setpoints_become_a_wire_message_that_round_trips():
    gen = SetpointGenerator(PARAMS, 50.0)
    sp = gen.update(_command([0.1, -0.2, 0.05, 0.0], [0.0] * 4), np.full(4, 400.0))
    msg = sp.message()
    assert isinstance(msg, ActuatorSetpoint) and msg.gimbal_mode == GimbalMode.RATE
    frame = decode_frame(encode_frame(msg, seq=3)[:-1])  # without the 0x00 delimiter
    assert frame.message.units[1].gimbal == pytest.approx(-0.2, rel=1e-6)
    assert frame.message.units[3].rotor_speed == pytest.approx(400.0)


def test_servos_follow_their_setpoints_with_their_time_constants():
    plant = Plant(PARAMS)
    servo = ServoModel(PARAMS, ServoParams())
    s = plant.state(rotor_rate=400.0)
    gen = SetpointGenerator(PARAMS, 50.0, max_lead=1e3)
    gen.reset(s.rotor_rate)
    servo.hold(gen.update(_command([0.2, 0.0, -0.2, 0.0], [0.0] * 4), s.rotor_rate))
    s = plant.run(s, 1e-3, 50, servo)  # one gimbal time constant
    # gimbal rate reaches 1 − 1/e of its setpoint despite the gyroscopic load (rejected by the drive);
    # 5 %: the body's reaction to the gimbals (its rate about g) is coupling the drive does not cancel
    assert s.gimbal_rate[0, 0] == pytest.approx(0.2 * (1 - np.exp(-1)), rel=0.05)
    assert s.gimbal_rate[0, 2] == pytest.approx(-0.2 * (1 - np.exp(-1)), rel=0.05)
    hold = s.gimbal_rate.copy()
    sp = gen.update(_command(hold, [0.0, 2500.0, 0.0, 0.0]), s.rotor_rate)  # rotor 1: +50 rad/s
    servo.hold(sp)
    start = s.rotor_rate[0, 1]
    s = plant.run(s, 1e-3, 150, servo)  # one rotor time constant
    assert s.rotor_rate[0, 1] - start == pytest.approx(
        (sp.rotor_speed[0, 1] - start) * (1 - np.exp(-1)), rel=0.03
    )
    assert s.rotor_rate[0, 0] == pytest.approx(400.0, abs=0.5)


def test_servo_torques_respect_the_motor_limits_and_coasting_esc():
    servo = ServoModel(PARAMS, ServoParams(coast_time_constant_s=1.5))
    gen = SetpointGenerator(PARAMS, 50.0, max_lead=1e3)
    gen.reset(np.full(4, 400.0))
    servo.hold(gen.update(_command([1.5, 0, 0, 0], [0.0, -5000.0, 5000.0, 0.0]), np.full(4, 400.0)))
    zero = np.zeros((1, 4))
    ug, us = servo(0.0, zero, zero, np.full((1, 4), 400.0), zero, zero)
    assert abs(ug[0, 0]) <= PARAMS.limits.max_gimbal_torque
    assert us[0, 2] == pytest.approx(PARAMS.units[2].rotor_spin_inertia * 100.0 / 0.15)  # 100 rad/s lead
    assert -us[0, 1] == pytest.approx(us[0, 2] / 10.0)  # slowing down without brakes: ten times gentler
    servo.hold(gen.update(_command([1.5, 0, 0, 0], [0.0, 0.0, 5000.0, 0.0]), np.full(4, 200.0)))
    _, us = servo(0.0, zero, zero, np.full((1, 4), 200.0), zero, zero)
    assert us[0, 2] == PARAMS.limits.max_rotor_torque  # far below its setpoint: stall torque
    with pytest.raises(ConfigError, match="load_rejection"):
        ServoParams(load_rejection=1.5)
