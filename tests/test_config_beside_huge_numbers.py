"""An integer beyond any float in a file the project reads: TOML and JSON read ``1`` followed by 400 zeros as
an exact ``int``, and every reader's first ``math.isfinite`` or ``float()`` of it was an ``OverflowError``
traceback (``hil run --scenario``, ``hil montecarlo --dispersions``, ``hil calibrate show``,
``firmware-sim --world``, ``hil report`` of a run's ``summary.json``). Refused where every such document is
loaded (:mod:`hil.files.bounded`): a typed error naming the file and the key, exit status 2 at a command.

The class is covered by putting a huge integer in place of every number of every shipped scenario,
dispersion and calibration file in turn (Hypothesis picks which), through each file's own reader.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.calibration.files import parse_calibration
from hil.files.bounded import load_json, load_toml
from hil.montecarlo.dispersions import DISPERSION_DIR, parse_dispersions
from hil.scenario import SCENARIO_DIR, load_scenario, parse_scenario
from hil.scenario.paths import FIXTURES
from protocol.errors import CalibrationError, ConfigError, InputFormatError

BIG = "1" + "0" * 400
NUMBER = re.compile(r"(?<![\w.\"'-])[-+]?\d[\d_]*(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w.\"'-])")
"""A number of a TOML document's text (a date or a word with digits in it is not one; one in a comment or
a string is found too, and left out: replacing it changes nothing the parser reads)."""

CUBESAT = load_scenario("cubesat-1u")


def _holds_huge(value: object) -> bool:
    """Whether a parsed document holds an integer of 310 digits or more (the huge one put in its text)."""
    if isinstance(value, dict):
        return any(_holds_huge(v) for v in value.values())
    if isinstance(value, list):
        return any(_holds_huge(v) for v in value)
    return isinstance(value, int) and abs(value) >= 10**309


def _read_scenario(text: str, name: str) -> object:
    return parse_scenario(text, Path(name))


def _read_dispersions(text: str, name: str) -> object:
    return parse_dispersions(text, CUBESAT, name)


def _read_calibration(text: str, name: str) -> object:
    return parse_calibration(text, name)


VQF = "[scenario]\nname = 'x'\nduration_s = 3\n[estimator]\nkind = 'vqf'\ntau_acc_s = 3.0\ntau_mag_s = 9.0\n"
DOCUMENTS = [
    *((p.name, p.read_text(), _read_scenario) for p in sorted(SCENARIO_DIR.glob("*.toml"))),
    ("vqf.toml", VQF, _read_scenario),
    *((p.name, p.read_text(), _read_dispersions) for p in sorted(DISPERSION_DIR.glob("*.toml"))),
    ("pyramid4.toml", (FIXTURES / "calibration" / "pyramid4.toml").read_text(), _read_calibration),
]


@pytest.mark.parametrize(("name", "text", "read"), DOCUMENTS, ids=[d[0] for d in DOCUMENTS])
def test_the_shipped_documents_read_as_they_are(name, text, read):
    read(text, name)  # the base every property below changes one number of


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    document=st.sampled_from(DOCUMENTS),
    pick=st.integers(min_value=0),
    digits=st.integers(min_value=310, max_value=4300),
    sign=st.sampled_from(["", "-", "+"]),
)
def test_any_number_of_any_document_beyond_a_float_is_an_error_naming_the_file_and_key(
    document, pick, digits, sign
):
    name, text, read = document
    numbers = list(NUMBER.finditer(text))
    assert numbers, name
    match = numbers[pick % len(numbers)]
    huge = "1" + "0" * (digits - 1)
    changed = text[: match.start()] + sign + huge + text[match.end() :]
    try:
        parsed = tomllib.loads(changed)
    except tomllib.TOMLDecodeError:
        return  # a number in a spot where a huge one is not TOML: nothing to read
    if not _holds_huge(parsed):
        return  # a number in a comment or a string
    with pytest.raises(ConfigError) as caught:
        read(changed, name)
    assert "beyond the range of any number hil reads" in caught.value.detail
    assert caught.value.where.startswith(f"{name}: ")  # the file, then the key
    assert caught.value.where != f"{name}: "
    if read is _read_calibration:
        assert isinstance(caught.value, CalibrationError)


@pytest.mark.parametrize(
    ("read", "text", "key"),
    [
        (_read_scenario, f"[scenario]\nname='x'\nduration_s={BIG}\n", "scenario.duration_s"),
        (_read_scenario, f"[scenario]\nname='x'\n[board]\ncells={BIG}\n", "board.cells"),
        (_read_scenario, f"[scenario]\nname='x'\n[spacecraft]\nbus_inertia=[{BIG},1,1]\n", "bus_inertia[0]"),
        (_read_scenario, f"[scenario]\nname='x'\n[manoeuvre]\naxis=[1,-{BIG},1]\n", "manoeuvre.axis[1]"),
        (_read_scenario, f"[scenario]\nname='x'\n[estimator]\nkind='vqf'\ntau_acc_s={BIG}\n", "tau_acc_s"),
        (_read_dispersions, f"[spacecraft]\ninertia_scale={BIG}\n", "spacecraft.inertia_scale"),
        (_read_dispersions, f"[spacecraft]\ninertia_scale={{dist='normal', sigma={BIG}}}\n", "sigma"),
        (_read_dispersions, f"[spacecraft]\ninertia_scale={{dist='choice', values=[{BIG}]}}\n", "values[0]"),
        (_read_dispersions, f"[faults]\nstall={{count=1, duration_s={BIG}}}\n", "stall.duration_s"),
        (_read_dispersions, f"[faults]\nphone_jump={{count=1, offset_s={BIG}}}\n", "phone_jump.offset_s"),
        (_read_dispersions, f"[faults]\nstall={{count={BIG}, duration_s=1}}\n", "faults.stall.count"),
    ],
)
def test_the_reviewers_examples(read, text, key):
    with pytest.raises(ConfigError, match="an integer of 401 digits") as caught:
        read(text, "f.toml")
    assert key in caught.value.where


def test_an_integer_too_long_for_python_to_read_is_not_valid_toml():
    """Past 4300 digits ``int()`` itself refuses, and tomllib let its ValueError through."""
    with pytest.raises(ConfigError, match="not valid TOML: Exceeds the limit") as caught:
        load_toml("a = " + "1" * 5000, "f.toml")
    assert caught.value.where == "f.toml"
    assert "set_int_max_str_digits" not in str(caught.value)  # Python's advice to a programmer, left out


@pytest.mark.parametrize(
    ("value", "where"),
    [
        pytest.param(1 << 1024, "", id="top-level"),
        ({"a": [1, 2, {"b": -(10**400)}]}, "a[2].b"),
        ({"a": 2**1023, "b": True, "c": 1e308, "d": "1" * 500, "e": None}, None),
        ([{}, [], [[0, 10**309]]], "[2][0][1]"),
    ],
)
def test_beyond_float_names_the_key(value, where):
    from hil.files.bounded import beyond_float

    found = beyond_float(value)
    assert (found[0] if found else None) == where


def test_beyond_float_is_exactly_where_float_overflows():
    from hil.files.bounded import beyond_float

    top = int(sys.float_info.max)
    assert beyond_float(top) is None
    for n in range(top, top + (1 << 971) + 2, 1 << 969):
        try:
            float(n)
            overflows = False
        except OverflowError:
            overflows = True
        assert (beyond_float(n) is not None) == overflows


def test_json_is_held_to_the_same_bound():
    with pytest.raises(InputFormatError, match="an integer of 401 digits") as caught:
        load_json(f'{{"wall_s": {BIG}}}', "summary.json", 3)
    assert "at wall_s" in str(caught.value)
    assert caught.value.path == "summary.json" and caught.value.line == 3


def _cli(argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, capture_output=True, text=True, timeout=120, cwd=cwd)


@pytest.mark.parametrize(
    ("command", "body", "key"),
    [
        (
            ["-m", "hil", "run", "--no-plots", "--scenario"],
            f"[scenario]\nname='x'\nduration_s={BIG}\n",
            "duration_s",
        ),
        (
            ["-m", "hil", "montecarlo", "cubesat-1u", "--runs", "1", "--dispersions"],
            f"[spacecraft]\ninertia_scale={BIG}\n",
            "spacecraft.inertia_scale",
        ),
        (
            ["-m", "hil", "calibrate", "show"],
            (FIXTURES / "calibration" / "pyramid4.toml")
            .read_text()
            .replace("low_us = 1000.0", f"low_us = {BIG}"),
            "esc.low_us",
        ),
        (
            ["-m", "firmware_sim", "--duration", "0.5", "--world"],
            f"[scenario]\nname='x'\nduration_s={BIG}\n",
            "duration_s",
        ),
    ],
    ids=["hil-run", "hil-montecarlo", "hil-calibrate-show", "firmware-sim"],
)
def test_every_command_reading_toml_exits_2_naming_file_and_key(tmp_path, command, body, key):
    path = tmp_path / "f.toml"
    path.write_text(body)
    out = ["--out", "out"] if command[1] == "hil" and command[2] != "calibrate" else []
    done = _cli([sys.executable, *command, str(path), *out], tmp_path)
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "an integer of 401 digits" in done.stderr
    assert "f.toml" in done.stderr and key in done.stderr
    assert not (tmp_path / "out").exists()


def test_hil_report_of_a_summary_with_a_huge_number_says_so(tmp_path):
    """``hil report RUN_DIR``: its ``summary.json`` read by :func:`load_json`; ``wall_s`` of 401 digits was
    an OverflowError traceback (exit 1), now a damaged summary, named."""
    run = tmp_path / "run"
    run.mkdir()
    rows = "".join(f"{k / 50},1,{30 - k}\n" for k in range(20))
    (run / "telemetry.csv").write_text("t,phase,point_err_deg\n" + rows)
    (run / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n')
    (run / "summary.json").write_text(f'{{"exit": "completed", "mode": "lockstep", "wall_s": {BIG}}}')
    done = _cli([sys.executable, "-m", "hil", "report", str(run), "--no-plots"], tmp_path)
    assert done.returncode == 2 and "damaged" in done.stderr, done.stderr
    assert "summary.json damaged (an integer of 401 digits" in done.stdout
    assert "at wall_s" in done.stdout
