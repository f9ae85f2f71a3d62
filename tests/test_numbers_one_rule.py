"""One rule for a number a user or another program wrote (``hil.numbers.finite_number``), where there were
five copies: the ground station's requests, the printed summary, the plots' markers, the campaigns'
dispersions and the scenario reader. Three of them called ``math.isfinite`` on a JSON or TOML integer,
which raises OverflowError past ±1.8e308: an event whose time was an integer of 400 digits crashed the
plots' markers (``hil report``, the ground station's page) where a dropped line was due.
"""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.montecarlo.dispersions import parse_dispersions
from hil.numbers import finite_number, is_finite_number
from hil.plots.markers import run_markers
from hil.scenario import load_scenario
from protocol.errors import ConfigError

HUGE = 10**400


@given(
    st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(),
        st.integers(min_value=10**300, max_value=10**500),
        st.booleans(),
        st.none(),
        st.text(max_size=5),
        st.lists(st.integers(), max_size=2),
    )
)
def test_a_finite_number_is_a_finite_float_or_int_within_a_floats_range_never_a_bool(value):
    got = finite_number(value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        assert got is None
    elif isinstance(value, int) and abs(value) > 1.7976931348623157e308:
        assert got is None  # float() would raise: never a traceback
    elif isinstance(value, float) and not math.isfinite(value):
        assert got is None
    else:
        assert got == float(value) and math.isfinite(got)
    assert is_finite_number(value) is (got is not None)


def test_an_events_time_of_400_digits_is_left_out_of_the_markers_not_a_traceback():
    events = [
        {"t": HUGE, "kind": "slew_start"},
        {"t": 1.0, "kind": "slew_start"},
        {"t": HUGE, "kind": "command", "origin": "gcs", "id": 1, "command": "slew"},
        {
            "t": 2.0,
            "kind": "command",
            "origin": "gcs",
            "id": 2,
            "command": "slew",
            "target_euler_deg": [HUGE, 0, 0],
        },
    ]
    events = json.loads(json.dumps(events))  # as read back from events.jsonl
    markers = run_markers(events)
    assert [m.t for m in markers] == [1.0, 2.0]
    assert markers.malformed == 1
    assert "slew to" not in markers[1].label  # its target is no number a run writes: not drawn as one


@pytest.mark.parametrize(
    "value", ["inf", str(HUGE), "true", "nan", f"{{ dist = 'uniform', low = 0, high = {HUGE} }}"]
)
def test_a_dispersions_value_that_is_no_finite_number_is_refused_naming_it(value):
    with pytest.raises(ConfigError) as caught:
        parse_dispersions(f"[spacecraft]\ninertia_scale = {value}\n", load_scenario("cubesat-1u"))
    assert "inertia_scale" in str(caught.value)
