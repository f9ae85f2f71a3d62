"""``TenMillivolts`` is ``round(v, 2)``: the same float, sign of zero and NaN included, whatever the
sequence of voltages it is asked for (slow drifts, jumps, band edges)."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.board.volts import TenMillivolts

EDGES = [x + d for x in (0.0, 0.005, 0.015, 12.345, 12.355, 16.8) for d in (-1e-12, 0.0, 1e-12)]
VOLTS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-30.0, 30.0),
    st.sampled_from(EDGES + [-x for x in EDGES]),
)


def _same(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


@settings(max_examples=300, deadline=None)
@given(start=VOLTS, steps=st.lists(st.one_of(st.floats(-0.02, 0.02), VOLTS), max_size=40))
def test_ten_millivolts_is_round_to_two_digits(start, steps):
    """Drifting by up to 20 mV a step (inside and across bands) or jumping anywhere."""
    volts = TenMillivolts()
    v = start
    assert _same(volts(v), round(v, 2))
    for step in steps:
        v = v + step if abs(step) <= 0.02 else step
        assert _same(volts(v), round(v, 2)), v


def test_a_slow_discharge_through_many_bands():
    volts = TenMillivolts()
    v = 16.8
    while v > 14.0:
        assert _same(volts(v), round(v, 2))
        v -= 1.37e-4
