"""A scenario value far too long for its key, said back in the error in full. The reader refused it — the
right key, the right reason — but quoted the value whole with ``!r``: ``duration_s = "xxx…"`` of 3 MB, a
``gimbal_angles_deg`` list of 400 000 numbers, a ``preset`` of 3 MB or a fault spec of 2 MB made ``hil
run`` print an error line of 1-3 MB to the terminal. Every caller's value in a scenario error is now shown
through ``protocol.errors.value_repr`` (at most ~80 characters), as the rest of the project shows one."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.scenario import SCENARIO_DIR, parse_scenario
from protocol.errors import ConfigError

BASE = (SCENARIO_DIR / "cubesat-1u.toml").read_text()
BIG = 2_000_000


def _sub(old: str, new: str) -> str:
    assert old in BASE, old
    return BASE.replace(old, new, 1)


HUGE = {
    "scenario.duration_s": _sub("duration_s = 35.0", f"duration_s = '{'x' * BIG}'"),
    "manoeuvre.gimbal_angles_deg": _sub(
        "settle_deg = 0.5", "settle_deg = 0.5\ngimbal_angles_deg = [" + ", ".join(["0.0"] * (BIG // 5)) + "]"
    ),
    "spacecraft.preset": _sub('preset = "cubesat_1u"', f'preset = "{"c" * BIG}"'),
    "faults.stall": _sub("[faults]", f'[faults]\nstall = ["1:1", "{"9" * BIG}"]'),
    "faults.corrupt": _sub("[faults]", "[faults]\ncorrupt = [" + ",".join(["true"] * (BIG // 5)) + "]"),
    "board.cells": _sub("[board]", f"[board]\ncells = '{'3' * BIG}'"),
    "sensors.field_enu_uT": _sub(
        "[sensors]", "[sensors]\nfield_enu_uT = [" + ",".join(["1.0"] * (BIG // 4)) + "]"
    ),
}


@pytest.mark.parametrize("key", sorted(HUGE))
def test_hil_run_says_a_huge_value_in_one_short_line(tmp_path, key):
    path = tmp_path / "huge.toml"
    path.write_text(HUGE[key])
    result = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert result.returncode == 2, result.stderr[-500:]
    assert f"huge.toml: {key}:" in result.stderr
    assert len(result.stderr) < 1_000, f"{len(result.stderr)} characters of error"  # was 1-3 MB
    assert "Traceback" not in result.stderr


NEW_KEYS = {
    "manoeuvre": "initial_axis",
    "controller": "mu",
    "board": "heartbeat_rate",
    "faults": "drop",
    "spacecraft": "bus_inertia",
    "sensors": "gravity",
    "estimator": "kind",
}
"""A key of each table that the shipped scenario does not set (so the file stays valid TOML)."""

printable = st.characters(exclude_categories=("Cc", "Cs"))  # what a TOML string holds unescaped
long_values = st.one_of(
    st.text(printable, min_size=1_000, max_size=5_000),
    st.lists(st.integers(-(2**63), 2**63 - 1), min_size=500, max_size=2_000),
    st.lists(st.text(printable, min_size=50, max_size=100), min_size=50, max_size=100),
    st.lists(st.lists(st.floats(-1e300, 1e300), min_size=3, max_size=3), min_size=300, max_size=600),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(table=st.sampled_from(sorted(NEW_KEYS)), value=long_values)
def test_any_long_value_under_any_table_is_taken_or_refused_in_a_short_message(table, value):
    """Taken when it is a value of the key (a fault's ``"000…0"`` is the number 0), else refused naming
    the key, in a message of bounded length whatever the value's."""
    key = NEW_KEYS[table]
    text = _sub(f"[{table}]", f"[{table}]\n{key} = {json.dumps(value, ensure_ascii=False)}")
    try:
        parse_scenario(text)
    except ConfigError as exc:
        assert exc.where.startswith(f"<scenario>: {table}"), exc.where
        assert len(str(exc)) < 2_000, f"{len(str(exc))} characters: {str(exc)[:300]}"


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    table=st.sampled_from([*sorted(NEW_KEYS), "array", "a_table_of_its_own"]),
    key=st.text(st.characters(min_codepoint=ord("a"), max_codepoint=ord("z")), min_size=300, max_size=20_000),
)
def test_a_long_unknown_key_or_table_is_said_briefly(table, key):
    """An unknown key of any length (or an unknown table) is refused naming it, in a short message: a key
    of megabytes was the message's ``where`` whole."""
    if table in BASE:
        text = _sub(f"[{table}]", f"[{table}]\n{key} = 1")
    else:
        text = BASE + f"\n[{table}]\n{key} = 1\n[{key}]\n"
    with pytest.raises(ConfigError) as caught:
        parse_scenario(text)
    assert len(str(caught.value)) < 1_000, f"{len(str(caught.value))} characters"
