"""An accelerometer or magnetometer none of whose readings gives a direction — every one 0, 0, 0 or no
number (the phone has no such sensor, or it never started) — is refused naming its file, the inertial
directions given or not.

Measured from the log, the inertial directions refuse such a sensor already
(tests/test_replay_sensor_edge_rows.py), and their error's hint is "give --inclination or
--lat/--lon/--date". Given them, an all-zero magnetometer replayed every step with the magnetometer left out
as disturbed, exit 0, ``summary.json`` saying the heading was "observed (magnetometer)" and warning of
nothing; an all-zero accelerometer replayed with no gravity at all, warned of only as a unit in g.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main
from tests.log_support import needs_real_export, real_export

DIRECTIONS = (["--inclination", "-28"], ["--lat", "45", "--lon", "7", "--date", "2023-03-17"])
FILES = {"Magnetometer.csv": "MAG", "TotalAcceleration.csv": "ACC"}


def no_direction(file: str, cells: list[str]):
    """An edit for :func:`real_export`: ``file``'s readings (z, y, x) drawn from ``cells`` row by row."""

    def edit(name: str, lines: list[str]) -> list[str]:
        if name != file:
            return lines
        rows = [line.split(",") for line in lines[1:]]
        return [lines[0]] + [",".join(row[:2] + [cells[i % len(cells)]] * 3) for i, row in enumerate(rows)]

    return edit


@needs_real_export
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    file=st.sampled_from(sorted(FILES)),
    cells=st.lists(st.sampled_from(["0", "0.0", "-0", "nan", "0e5"]), min_size=1, max_size=4),
    given_directions=st.sampled_from(DIRECTIONS),
)
def test_a_sensor_with_no_direction_is_refused_naming_its_file_with_the_directions_given(
    tmp_path_factory, capsys, file, cells, given_directions
):
    folder = real_export(tmp_path_factory.mktemp("nodir") / "export", no_direction(file, cells))
    out = folder.parent / "out"
    assert main(["replay", str(folder), "--no-plots", "--out", str(out), *given_directions]) == 2
    err = capsys.readouterr().err
    assert f"every {FILES[file]} reading" in err and "zero or no number" in err, err
    assert file in err, err
    assert not (out / "summary.json").exists()


@needs_real_export
@pytest.mark.parametrize("file", sorted(FILES))
def test_driving_a_board_with_it_is_refused_before_the_board_is_armed(tmp_path, capsys, file):
    folder = real_export(tmp_path / "export", no_direction(file, ["0"]))
    args = ["replay", str(folder), "--no-plots", "--out", str(tmp_path / "runs"), *DIRECTIONS[0]]
    assert main([*args, "--window", "0", "7.9", "--port", "emu://?units=4"]) == 2
    err = capsys.readouterr().err
    assert "zero or no number" in err and file in err, err
    assert not (tmp_path / "runs").exists()  # no run directory: nothing armed
