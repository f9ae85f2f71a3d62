"""A calibration file's ``version`` is the integer 1: ``version = true`` and ``version = 1.0`` were read as
version 1 (``True == 1.0 == 1`` in Python), so a file of another writer's making passed for this format."""

from __future__ import annotations

import pytest

from hil.calibration.files import VERSION, parse_calibration
from hil.scenario.paths import FIXTURES
from protocol.errors import CalibrationError

TEXT = (FIXTURES / "calibration" / "pyramid4.toml").read_text()


def _with_version(value: str) -> str:
    assert f"version = {VERSION}\n" in TEXT
    return TEXT.replace(f"version = {VERSION}\n", f"version = {value}\n", 1)


@pytest.mark.parametrize(
    "value", ["true", "false", "1.0", "1e0", "+1.0", '"1"', "[1]", "{ v = 1 }", "0", "2", "-1"]
)
def test_anything_but_the_integer_1_is_not_version_1(value):
    with pytest.raises(CalibrationError, match="is not supported") as caught:
        parse_calibration(_with_version(value), "cal.toml")
    assert caught.value.where == "cal.toml: version"


@pytest.mark.parametrize("value", ["1", "+1", "0x1", "0o1", "0b1"])
def test_the_integer_1_in_any_toml_spelling_is_version_1(value):
    assert len(parse_calibration(_with_version(value), "cal.toml").units) == 4
