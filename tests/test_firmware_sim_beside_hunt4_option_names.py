"""``firmware-sim``'s refused option values name the option the user typed.

Beside the tested path (``--sag 3x`` naming ``--sag``): a board option whose value parses but is absurd
(nan, inf, 1e160, negative zero where zero is too small, a probability of 1.5) was refused by the board's
own check, which named a field of the code — ``BoardConfig.power.battery.initial_soc``,
``faults.link.corrupt`` — that appears nowhere in ``firmware-sim --help``.
"""

from __future__ import annotations

import subprocess
import sys

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.cli import main

ABSURD_NUMBERS = st.sampled_from(["nan", "inf", "-inf", "1e160", "-1e160", "-0.0", "-1", "1e9"])
FLOAT_OPTIONS = [
    "--frame-rate",
    "--telemetry-rate",
    "--heartbeat-rate",
    "--link-timeout",
    "--mcu-watchdog",
    "--capacity",
    "--soc",
    "--corrupt",
    "--drop",
]
"""Options read as floats whose every absurd value above (all outside their ranges, or not finite) is
refused — ``--soc``, ``--corrupt`` and ``--drop`` take 0, so their ``-0.0`` is filtered out below."""
TAKE_ZERO = {"--soc", "--corrupt", "--drop"}
INT_OPTIONS = {
    "--units": ["0", "9", "-3", "100000"],
    "--cells": ["0", "1", "13"],
    "--rotor-safe-us": ["0", "99999"],
}


def refused(argv: list[str], capsys) -> str:  # type: ignore[no-untyped-def]
    """``main(argv)``'s stderr, its status 2 checked (capsys is read, so cleared, on every call)."""
    capsys.readouterr()
    assert main([*argv, "--duration", "0.01"]) == 2
    return capsys.readouterr().err


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(option=st.sampled_from(FLOAT_OPTIONS), value=ABSURD_NUMBERS)
def test_an_absurd_float_is_refused_naming_the_option_typed(option, value, capsys):
    if option in TAKE_ZERO and value == "-0.0":
        return  # a valid probability / state of charge: 0
    err = refused([option, value], capsys)
    assert f"firmware-sim: error: {option}: " in err, err
    assert "BoardConfig" not in err and "faults.link" not in err and "Traceback" not in err


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_an_absurd_integer_is_refused_naming_the_option_typed(data, capsys):
    option = data.draw(st.sampled_from(sorted(INT_OPTIONS)))
    value = data.draw(st.sampled_from(INT_OPTIONS[option]))
    err = refused([option, value], capsys)
    assert f"firmware-sim: error: {option}: " in err, err
    assert "BoardConfig" not in err


def test_every_named_setting_is_an_option_of_the_command():
    from firmware_sim.cli import OPTION_OF_SETTING, build_parser

    spelled = {s for a in build_parser()._actions for s in a.option_strings}
    assert set(OPTION_OF_SETTING.values()) <= spelled


def test_the_command_says_the_option_through_a_real_process():
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--corrupt", "1.5", "--duration", "1"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2 and done.stdout == ""
    assert (
        done.stderr.strip().splitlines()[-1]
        == "firmware-sim: error: --corrupt: 1.5 is not a probability in 0..1"
    )
