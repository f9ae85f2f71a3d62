"""A verification tolerance as large as a point's target away from rest passes a unit that never moves:
``--rotor-tolerance 1`` passed every rotor point of a stopped rotor, ``--rate-tolerance 1e160`` every
gimbal point; an angle tolerance of half the gap between two angle points passes a gimbal stuck at one.
Refused before anything moves, naming the option; tolerances below those pass."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.calibration.bench import BenchKind
from hil.calibration.verify import VerifyPlan, _targets, check_tolerances_tell_motion
from protocol.calibration import default_unit_calibration
from protocol.errors import ConfigError

UNITS = {0: default_unit_calibration(), 3: default_unit_calibration()}


def _smallest_motion(kind: BenchKind, plan: VerifyPlan) -> float:
    """What a unit that follows its commands moves by between points (rad/s or rad): a rate point's rate,
    half the gap between two angle points."""
    if kind is BenchKind.GIMBAL_RATE:
        rates = [_targets(kind, f, UNITS, plan, 1.0)[0][0] for f in plan.gimbal_rate_fractions]
        return min(abs(r) for r in rates if r != 0)
    angles = sorted({_targets(kind, f, UNITS, plan, 1.0)[0][0] for f in plan.gimbal_angle_fractions})
    return min(b - a for a, b in zip(angles, angles[1:], strict=False)) / 2


@settings(max_examples=60, deadline=None)
@given(kind=st.sampled_from([BenchKind.GIMBAL_RATE, BenchKind.GIMBAL_ANGLE]), scale=st.floats(0.01, 1e160))
def test_a_gimbal_tolerance_is_refused_exactly_when_a_unit_not_following_would_pass(kind, scale):
    tolerance = scale * _smallest_motion(kind, VerifyPlan())
    field = "gimbal_rate_tolerance_rad_s" if kind is BenchKind.GIMBAL_RATE else "gimbal_angle_tolerance_rad"
    plan = VerifyPlan(**{field: tolerance})
    option = "--rate-tolerance" if kind is BenchKind.GIMBAL_RATE else "--angle-tolerance"
    if scale >= 1.0:
        with pytest.raises(ConfigError) as caught:
            check_tolerances_tell_motion((kind,), UNITS, plan)
        assert caught.value.where == option and "would pass" in str(caught.value)
    else:
        check_tolerances_tell_motion((kind,), UNITS, plan)


@given(tolerance=st.floats(0.0, 2.0, exclude_min=True))
def test_a_rotor_tolerance_is_refused_at_the_plan_exactly_when_a_still_rotor_would_pass(tolerance):
    if tolerance >= 0.2:
        with pytest.raises(ConfigError) as caught:
            VerifyPlan(rotor_tolerance=tolerance)
        assert caught.value.where == "--rotor-tolerance"
    else:
        VerifyPlan(rotor_tolerance=tolerance)
