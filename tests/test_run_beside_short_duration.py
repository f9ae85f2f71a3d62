"""``hil run --duration`` shorter than the scenario's slew needs to settle (:meth:`Scenario.time_to_judge`):
the run's settle time is "NOT met" whatever the system does. A campaign said so in its summary; ``hil run``
said nothing, and a user read a failure of the system. It says so before it runs, with the duration that
judges it, and says nothing of a run long enough."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.cli.run import too_short_to_judge
from hil.scenario import load_scenario

SCENARIOS = ["cubesat-1u", "paper-testbed"]


@settings(max_examples=60, deadline=None)
@given(name=st.sampled_from(SCENARIOS), duration=st.floats(0.0, 200.0))
def test_a_duration_is_said_too_short_exactly_when_the_slew_cannot_settle_in_it(name, duration):
    scenario = load_scenario(name)
    needed = scenario.time_to_judge().total_s
    said = too_short_to_judge(scenario, duration)
    assert (said is not None) == (duration < needed)
    if said is not None:
        assert f"--duration {math.ceil(needed)} or more" in said and f"{duration:g} s" in said


@pytest.mark.parametrize("name", SCENARIOS)
def test_the_scenarios_own_duration_is_long_enough_to_judge(name):
    assert too_short_to_judge(load_scenario(name), None) is None


def test_hil_run_says_a_short_duration_before_it_runs(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--duration", "1", "--no-plots", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    note = [line for line in done.stderr.splitlines() if line.startswith("note: the run's 1 s is shorter")]
    assert len(note) == 1 and "--duration 26 or more judges it" in note[0], done.stderr[-2000:]
    assert done.stderr.index(note[0]) < done.stderr.index(" t    0.0 s")  # before the run's first line
