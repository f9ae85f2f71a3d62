"""A scenario's manoeuvre axis given with no angle to turn about it.

What broke: ``initial_axis`` (and ``axis``) were read only when their angle was non-zero, so a file with
``initial_axis = "north"``, ``[nan, 0, 1]`` or ``[[1], 0, 0]`` and no ``initial_angle_deg`` (its default
0) — the user's start attitude silently the identity — loaded without a word. An axis given is now held
to what every axis is (three finite numbers within bounds) whether or not it turns anything; an error
names the file and the key. A zero axis with no angle stays allowed: it turns nothing and says nothing
wrong.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.scenario import SCENARIO_DIR, load_scenario
from protocol.errors import ConfigError

BASE = (SCENARIO_DIR / "paper-testbed.toml").read_text()

_not_a_vector = st.one_of(
    st.text(max_size=8).map(lambda s: '"' + s.replace("\\", "").replace('"', "") + '"'),
    st.sampled_from(
        [
            "[nan, 0.0, 1.0]",
            "[inf, 0.0, 0.0]",
            "[1.0, 0.0]",
            "[[1.0], 0.0, 0.0]",
            "[1e160, 0.0, 0.0]",
            "[]",
            "true",
            "{ x = 1.0 }",
            "[1.0, 0.0, 0.0, 0.0]",
            '["1", 0, 0]',
        ]
    ),  # fmt: skip
)


@settings(max_examples=40, deadline=None)
@given(
    value=_not_a_vector,
    key=st.sampled_from(["initial_axis", "axis"]),
    angle=st.sampled_from([None, 0.0, -0.0]),
)
def test_an_axis_that_is_no_vector_is_refused_naming_it_whatever_its_angle(
    tmp_path_factory, value, key, angle
):
    angle_key = {"initial_axis": "initial_angle_deg", "axis": "angle_deg"}[key]
    text = BASE.replace(
        "axis = [0.0, 0.0, 1.0]\nangle_deg = 60.0\n", ""
    )  # the manoeuvre's own axis and angle
    lines = [f"{key} = {value}"] + ([] if angle is None else [f"{angle_key} = {angle!r}"])
    text = text.replace("[manoeuvre]\n", "[manoeuvre]\n" + "\n".join(lines) + "\n")
    path = tmp_path_factory.mktemp("sc") / "bad-axis.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    assert info.value.where.startswith("bad-axis.toml"), info.value
    assert key in info.value.where or "not valid TOML" in str(info.value), info.value


def test_a_zero_axis_with_no_angle_still_loads(tmp_path):
    path = tmp_path / "zero.toml"
    path.write_text(BASE.replace("[manoeuvre]\n", "[manoeuvre]\ninitial_axis = [0.0, 0.0, 0.0]\n"))
    assert load_scenario(path).slew.R0.tolist() == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
