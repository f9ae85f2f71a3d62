"""A scenario's ``[scenario] name`` and ``description`` that are not printable text. TOML escapes let a file
hold any character, and both are printed as a run starts (``hil run``: ``scenario NAME: DESCRIPTION``) and
written into every run's summary: ``name = "x\\u001b]0;owned\\u0007"`` retitled the user's terminal,
``"\\u001b[2J"`` cleared it, and a name of millions of characters went whole into each. Refused as the file
is read, naming the file and the key, with the characters as code points (never echoed raw)."""

from __future__ import annotations

import subprocess
import sys
import unicodedata
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.scenario import load_scenario
from hil.scenario.reader import MAX_NAME_CHARS
from protocol.errors import ConfigError

HIL = [sys.executable, "-c", "import sys; from hil.cli import main; sys.exit(main(sys.argv[1:]))"]


def toml_string(text: str) -> str:
    """``text`` as a TOML basic string: quotes, backslashes and control characters escaped."""
    out = []
    for c in text:
        if c in '"\\':
            out.append("\\" + c)
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append(f"\\u{ord(c):04X}")
        else:
            out.append(c)
    return '"' + "".join(out) + '"'


def _write(folder: Path, name: str = "my", description: str = "") -> Path:
    path = folder / "my.toml"
    path.write_text(
        f"[scenario]\nname = {toml_string(name)}\ndescription = {toml_string(description)}\nduration_s = 3\n",
        encoding="utf-8",
    )
    return path


def _is_printable(text: str, also: str = "") -> bool:
    """Printable characters and spaces (a no-break space is text), and those of ``also``."""
    return all(c.isprintable() or c in also or unicodedata.category(c) == "Zs" for c in text)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.text(min_size=1, max_size=40))
def test_a_name_is_one_printable_line_or_an_error_naming_the_key(tmp_path, name):
    try:
        scenario = load_scenario(_write(tmp_path, name=name))
    except ConfigError as exc:
        assert exc.where == "my.toml: scenario.name"
        assert _is_printable(exc.detail), exc.detail  # the offending characters as code points
        return
    assert scenario.name == name
    assert name.strip() and _is_printable(name)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(description=st.text(max_size=40))
def test_a_description_is_printable_lines_or_an_error_naming_the_key(tmp_path, description):
    try:
        scenario = load_scenario(_write(tmp_path, description=description))
    except ConfigError as exc:
        assert exc.where == "my.toml: scenario.description"
        assert _is_printable(exc.detail), exc.detail
        return
    assert scenario.description == description
    assert _is_printable(description, also="\n\t")


def test_a_multi_line_description_and_a_unicode_name_are_taken(tmp_path):
    scenario = load_scenario(_write(tmp_path, name="cubesat-ü\u00a0𝐀", description="first line\n\tsecond"))
    assert scenario.name == "cubesat-ü\u00a0𝐀"
    assert scenario.description == "first line\n\tsecond"


@pytest.mark.parametrize("length", [MAX_NAME_CHARS + 1, 1_000_000])
def test_a_name_longer_than_a_line_is_refused(tmp_path, length):
    with pytest.raises(ConfigError) as caught:
        load_scenario(_write(tmp_path, name="n" * length))
    assert caught.value.where == "my.toml: scenario.name"
    assert f"at most {MAX_NAME_CHARS} characters" in caught.value.detail


def test_hil_run_prints_no_terminal_command_from_a_scenario(tmp_path):
    path = _write(tmp_path, name="x\x1b]0;owned\x07", description="\x1b[2J")
    done = subprocess.run(
        [*HIL, "run", "--scenario", str(path), "--out", str(tmp_path / "runs"), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert "\x1b" not in done.stdout + done.stderr and "\x07" not in done.stdout + done.stderr
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "my.toml: scenario.name" in lines[0] and "U+001B" in lines[0], lines
