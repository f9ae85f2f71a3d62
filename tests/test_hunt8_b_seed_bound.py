"""``[scenario] seed`` had no upper bound where ``hil montecarlo --seed`` stops at 2⁶³−1: a scenario file took
``seed = 18446744073709551616`` that the command line refuses. Now the same bound, in the same words."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.cli.montecarlo import MAX_SEED as CLI_MAX_SEED  # the one bound, imported there
from hil.scenario import parse_scenario
from hil.scenario.reader import MAX_SEED
from protocol.errors import ConfigError

HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]


def test_the_bound_is_the_command_lines():
    assert MAX_SEED == CLI_MAX_SEED == 2**63 - 1


@settings(max_examples=40, deadline=None)
@given(seed=st.one_of(st.integers(MAX_SEED + 1, 2**200), st.integers(max_value=-1)))
def test_a_seed_beyond_the_bound_is_refused_in_the_command_lines_words(seed):
    with pytest.raises(ConfigError) as caught:
        parse_scenario(f"[scenario]\nname = 's'\nseed = {seed}\n", Path("s.toml"))
    assert caught.value.where == "s.toml: scenario.seed"
    assert caught.value.detail == f"must be an integer in 0..{MAX_SEED}, got {seed}"


@pytest.mark.parametrize("seed", [0, 1, MAX_SEED])
def test_a_seed_within_is_taken(seed):
    assert parse_scenario(f"[scenario]\nname = 's'\nseed = {seed}\n", Path("s.toml")).seed == seed


def test_hil_run_and_montecarlo_say_the_same(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(f"[scenario]\nname = 's'\nduration_s = 3\nseed = {MAX_SEED + 1}\n")
    outs = []
    for argv in (
        ["run", "--scenario", str(path), "--no-plots", "--out", str(tmp_path / "runs")],
        ["montecarlo", str(path), "--runs", "1", "--out", str(tmp_path / "mc")],
    ):
        done = subprocess.run([*HIL, *argv], capture_output=True, text=True, timeout=120)
        assert done.returncode == 2, done.stdout + done.stderr
        outs.append(done.stderr.strip())
    assert all(f"s.toml: scenario.seed: must be an integer in 0..{MAX_SEED}" in o for o in outs), outs
