"""A negative number in any spelling ``float`` reads is an option's value, judged by the option's own check
(hil.cli._parser). argparse took ``-1e300`` or ``-1e-3`` for an option: ``hil replay log --window -1e300 5``
ended "expected 2 arguments", ``hil run --pace -1e-3`` "expected one argument", never naming what was
wrong with the value."""

from __future__ import annotations

import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.cli import main
from hil.cli._parser import NEGATIVE_NUMBER
from hil.scenario.paths import FIXTURES

LOG = FIXTURES / "logs" / "simulated_testbed_4s.csv"


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["run", "--pace", "-1e-3"], "run --pace: must be a factor of the wall clock of at least 0.001"),
        (["run", "--pace", "-inf"], "run --pace: must be a factor of the wall clock of at least 0.001"),
        (["replay", str(LOG), "--max-gap", "-1E3"], "hil replay: error: --max-gap: must be a finite number"),
        (
            ["replay", str(LOG), "--window", "5", "-1e300"],
            "hil replay: error: --window: must be two finite times",
        ),
        (["montecarlo", "cubesat-1u", "--runs", "-2e1"], "argument --runs: invalid int value: '-2e1'"),
    ],
)
def test_a_negative_number_with_an_exponent_is_judged_by_its_option(capsys, tmp_path, argv, said):
    try:
        status = main([*argv, "--out", str(tmp_path / "out")])
    except SystemExit as exc:  # argparse's own checks (a type) end it so
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err.strip()
    assert said in err.splitlines()[-1]
    assert not err.startswith("scenario")  # the refusal alone, not after the scenario was announced
    assert not (tmp_path / "out").exists()


def test_a_window_from_far_before_the_log_is_read_from_its_start(tmp_path):
    """``--window -1e300 2``: everything up to 2 s (the log starts later than -1e300 s)."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "hil", "replay", str(LOG), "--window", "-1e300", "2", "--no-plots"]
    done = subprocess.run([*cmd, "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert (out / "estimates.csv").is_file()


def test_firmware_sim_judges_a_negative_duration_itself():
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--duration", "-1e3"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert "argument --duration: must be a finite number of seconds > 0, got '-1e3'" in done.stderr


@given(
    st.floats(max_value=-0.0, allow_nan=False), st.sampled_from(["{!r}", "{:e}", "{:E}", "{:.3g}", "{:f}"])
)
def test_every_spelling_of_a_negative_float_is_a_value(x, spelling):
    text = spelling.format(x)
    if not text.startswith("-"):  # -0.0 and the like, spelled without a sign by some formats
        return
    assert NEGATIVE_NUMBER.match(text), text
    assert float(text) <= 0.0


@pytest.mark.parametrize(
    "option", ["-v", "-vv", "--verbose", "-h", "--help", "-e5", "-1e", "-1e+", "--1", "-"]
)
def test_options_and_non_numbers_are_not_values(option):
    assert not NEGATIVE_NUMBER.match(option)
