"""Hypothesis strategies for the calibration tests (no tests here): random, physically sensible units."""

from __future__ import annotations

from hypothesis import strategies as st

from protocol.calibration import EscMotorModel, GimbalServoModel, UnitCalibration

FINITE = {"allow_nan": False, "allow_infinity": False}


@st.composite
def motor_models(draw) -> EscMotorModel:
    low = draw(st.floats(900.0, 1100.0))
    high = draw(st.floats(1800.0, 2100.0))
    return EscMotorModel(
        low_us=low,
        high_us=high,
        deadband_us=draw(st.floats(0.0, 0.2 * (high - low))),
        kv_rad_s_per_v=draw(st.floats(10.0, 200.0)),
        curvature=draw(st.floats(-0.6, 2.0)),
    )


@st.composite
def gimbal_models(draw) -> GimbalServoModel:
    return GimbalServoModel(
        center_us=draw(st.floats(1450.0, 1550.0)),
        deadband_us=draw(st.floats(0.5, 30.0)),
        half_span_us=draw(st.floats(300.0, 600.0)),
        max_rate_rad_s=draw(st.floats(0.2, 10.0)),
        rate_shape=draw(st.floats(-0.5, 2.0)),
        angle_range_rad=draw(st.floats(0.2, 3.0)),
        angle_cubic=draw(st.floats(-0.2, 0.3)),
        direction=draw(st.sampled_from([1, -1])),
    )


@st.composite
def unit_calibrations(draw) -> UnitCalibration:
    """A unit sampled from random models with random knot counts (2..16 per table)."""
    motor, gimbal = draw(motor_models()), draw(gimbal_models())
    return UnitCalibration(
        motor.rotor_map(draw(st.integers(2, 16))),
        gimbal.rate_map(draw(st.integers(2, 16))),
        gimbal.angle_map(draw(st.integers(2, 16))),
    )
