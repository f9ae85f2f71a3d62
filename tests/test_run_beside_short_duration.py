"""``hil run --duration`` shorter than the scenario's slew needs to settle (:meth:`Scenario.time_to_judge`):
the run's settle time is "NOT met" whatever the system does. A campaign said so in its summary; ``hil run``
said nothing, and a user read a failure of the system. It says so before it runs, with the duration that
judges it, and says nothing of a run long enough."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace

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


@settings(max_examples=40, deadline=None)
@given(at=st.floats(0.0, 86_400.0), duration=st.none() | st.floats(0.5, 1000.0))
def test_a_fault_after_the_runs_planned_end_is_said_exactly_then(at, duration):
    """A ``[faults]`` entry for a board time past the run's planned end never happened, unsaid."""
    from hil.cli.run import faults_after_the_run

    base = load_scenario()
    scenario = base.with_changes(fault_options={"stall": [f"{at!r}:0.5"], "corrupt": 0.001})
    said = faults_after_the_run(scenario, duration)
    planned = scenario.with_changes(
        slew=replace(scenario.slew, duration_s=duration if duration is not None else scenario.slew.duration_s)
    ).planned_length_s()
    assert (len(said) == 1) == (at > planned)
    if said:
        assert said[0].startswith(f"[faults] stall = '{at!r}:0.5' comes at {at:g} s")


def test_hil_run_says_a_fault_it_will_not_reach(tmp_path):
    from montecarlo_support import write_quick_scenario

    path = write_quick_scenario(tmp_path)
    text = path.read_text()
    assert "[faults]\n" in text
    path.write_text(text.replace("[faults]\n", '[faults]\nstall = ["80000:1"]\n', 1))
    out = str(tmp_path / "r")
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--scenario", str(path), "--no-plots", "--out", out],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert "note: [faults] stall = '80000:1' comes at 80000 s, after the run's planned end" in done.stderr
