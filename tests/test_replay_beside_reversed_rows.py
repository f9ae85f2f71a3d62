"""A log no part of which can be replayed says why, part by part — a file in reverse time order (a tool that
exports newest first, a spreadsheet sorted descending) included.

The merge takes each sensor's rows in file order and drops a row not later than the one before it (docs/
formats.md): a file sorted newest first keeps one sample per sensor, and the replay refused it with "no part
of the log has every sensor speaking for long enough" — every sensor spoke throughout; the reason (every
row but the first dropped as out of order) was in a warning never printed. The error now carries each
part's reason (at most :data:`~hil.logs.replay.SAID_PARTS` of them, and how many more).
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main
from hil.logs.replay import SAID_PARTS, ReplayOptions, replay
from protocol.errors import InputFormatError
from tests.log_support import needs_real_export, real_export


def newest_first(name: str, lines: list[str]) -> list[str]:
    return [lines[0], *reversed(lines[1:])]


@needs_real_export
@given(tail=st.integers(0, 40))
@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_an_export_newest_first_is_refused_saying_its_rows_are_out_of_time_order(tmp_path_factory, tail):
    """Every file newest first, its last ``tail`` rows (the oldest) cut off as a drawn export length."""
    folder = real_export(
        tmp_path_factory.mktemp("rev") / "export",
        lambda name, lines: newest_first(name, lines[: len(lines) - tail]),
    )
    with pytest.raises(InputFormatError) as info:
        replay(folder, ReplayOptions(folder.parent / "out"))
    message = str(info.value)
    assert "not in time order" in message, message
    for label in ("gyr", "acc", "mag"):  # each sensor's drops named
        assert f"{label}: " in message and "out of order" in message, message


@needs_real_export
def test_the_cli_prints_the_reason_and_a_part_of_every_sample_is_listed_bounded(tmp_path, capsys):
    folder = real_export(tmp_path / "export", newest_first)
    assert main(["replay", str(folder), "--no-plots", "--out", str(tmp_path / "o")]) == 2
    assert "out of order" in capsys.readouterr().err
    plain = real_export(tmp_path / "plain")
    assert main(["replay", str(plain), "--no-plots", "--out", str(tmp_path / "o"), "--max-gap", "1e-4"]) == 2
    err = capsys.readouterr().err
    assert "not every sensor speaks in it" in err
    assert err.count("is not replayed") == SAID_PARTS
    assert "more parts" in err and len(err) < 2000
