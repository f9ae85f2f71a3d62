"""Calibration plans given values that parse but are no plan.

Found by the sixth hunt:

- ``VerifyPlan`` took any verification point: a NaN fraction reached the armed board as a NaN setpoint
  after the points before it had run, and a point past the map's range (a rotor at 3× full speed, a gimbal
  at twice its top rate or past its angle span) was clamped by the map, so a unit that tracked every
  command it could take FAILed it; an empty tuple verified nothing of that map;
- ``FitOptions`` took 3.5 knots and the fit then failed with numpy's bare TypeError; ``"x"`` or None knots
  failed with Python's.

Now each is refused with the plan, a ConfigError (CalibrationError for the fit) naming the field.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hil.calibration.bench import BenchKind, read_bench_csv
from hil.calibration.fit import FitOptions, fit_bench
from hil.calibration.verify import VerifyPlan, _targets
from protocol.calibration import default_unit_calibration
from protocol.errors import CalibrationError, ConfigError

FIELDS = {"rotor_fractions": 0.0, "gimbal_rate_fractions": -1.0, "gimbal_angle_fractions": -1.0}
absurd_fraction = st.one_of(
    st.sampled_from([math.nan, math.inf, -math.inf, 1e160, -1e160, "0.5", None, True]),
    st.floats(1.0, 1e300, exclude_min=True),
    st.floats(-1e300, -1.0, exclude_max=True),
)


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(sorted(FIELDS)), st.integers(0, 3), absurd_fraction)
@example("rotor_fractions", 0, math.nan)
@example("rotor_fractions", 1, 3.0)
@example("gimbal_angle_fractions", 2, 1.5)
def test_a_verification_point_outside_the_maps_range_is_refused_with_the_plan(field, index, bad):
    fractions: list[object] = [0.2, 0.4, 0.6, 0.8]
    fractions[index] = bad
    with pytest.raises(ConfigError) as caught:
        VerifyPlan(**{field: tuple(fractions)})
    assert caught.value.where == f"VerifyPlan.{field}[{index}]"


@settings(max_examples=30, deadline=None)
@given(st.sampled_from(sorted(FIELDS)), st.floats(-0.999, -1e-9))
def test_a_negative_rotor_point_is_refused_and_a_negative_gimbal_point_taken(field, negative):
    if field == "rotor_fractions":  # the ESC cannot reverse: a negative speed is clamped to rest
        with pytest.raises(ConfigError, match=r"rotor_fractions\[0\]"):
            VerifyPlan(rotor_fractions=(negative,))
    else:
        VerifyPlan(**{field: (negative, 0.5)})


@pytest.mark.parametrize("field", sorted(FIELDS))
def test_a_plan_without_points_for_a_map_is_refused(field):
    with pytest.raises(ConfigError, match=field):
        VerifyPlan(**{field: ()})


@settings(max_examples=100, deadline=None)
@given(
    # rotor points at rest or above the default rotor tolerance (a point within it is refused, hunt 4)
    st.lists(st.one_of(st.just(0.0), st.floats(0.05, 1.0)), min_size=1, max_size=5),
    st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=5),
)
def test_every_point_in_range_is_taken_and_commands_within_the_map(rotor, angle):
    plan = VerifyPlan(rotor_fractions=tuple(rotor), gimbal_angle_fractions=tuple(angle))
    units = {0: default_unit_calibration()}
    for f in plan.rotor_fractions:
        targets, _ = _targets(BenchKind.ROTOR, f, units, plan, 12.0)
        assert 0.0 <= targets[0] <= units[0].rotor.kv_rad_s_per_v * 12.0
    ys = units[0].gimbal_angle.curve.y
    for f in plan.gimbal_angle_fractions:
        targets, _ = _targets(BenchKind.GIMBAL_ANGLE, f, units, plan, 12.0)
        assert min(ys) - 1e-12 <= targets[0] <= max(ys) + 1e-12


# --------------------------------------------------------------------------- fit options
@pytest.mark.parametrize("field", ["rotor_knots", "gimbal_rate_knots_per_side", "gimbal_angle_knots"])
@pytest.mark.parametrize("bad", [3.5, 4.0, "x", None, True, math.nan, np.float64(5.0)])
def test_a_knot_count_that_is_no_whole_number_is_refused_naming_it(field, bad):
    with pytest.raises(CalibrationError, match=rf"FitOptions\.{field}"):
        FitOptions(**{field: bad})


def test_a_bench_csv_fitted_with_fractional_knots_is_refused_before_the_fit(tmp_path: Path):
    """The user's path: a real rotor bench CSV on disk, fitted with 3.5 knots (it failed inside the fit
    with numpy's "'float' object cannot be interpreted as an integer")."""
    rows = [f"{1000 + i * 25:.1f},12.0,{0 if i < 3 else (i - 3) * 20}" for i in range(41)]
    csv = tmp_path / "rotor.csv"
    csv.write_text("pulse_us,battery_v,rotor_speed_rad_s\n" + "\n".join(rows) + "\n")
    data = read_bench_csv(csv)
    assert fit_bench(data, FitOptions(rotor_knots=np.int64(5))).report.knots == 5  # numpy ints are whole
    with pytest.raises(CalibrationError, match=r"FitOptions\.rotor_knots: 3\.5; need a whole number"):
        fit_bench(data, FitOptions(rotor_knots=3.5))  # type: ignore[arg-type]
