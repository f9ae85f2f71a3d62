"""The project's own CSV re-saved by a spreadsheet — semicolons or tabs, decimal commas, every cell quoted,
its comment lines kept or not — reads as the file it was saved from.

Every other CSV reader takes the file's own dialect (``hil.logs.table.sniff_dialect``: docs/formats.md);
the project's CSV split at commas only, so a European spreadsheet's re-save was refused ("expected header
't_s,sensor,x,y,z,w', found 't_s;sensor;x;y;z;w'") or, without its first comment line, "not a recognised
log". A truth row's ``w`` with a decimal comma in a quoted cell (parsed a cell at a time) is read as its
neighbours are, and a ``w`` that makes no unit quaternion stays an error naming its line and column.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main
from hil.logs import read_log
from protocol.errors import InputFormatError
from tests.log_support import assert_same_samples

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"
LINES = FIXTURE.read_text(encoding="utf-8").splitlines()
HEADER_AT = next(i for i, line in enumerate(LINES) if line.startswith("t_s,"))


def resaved(delimiter: str, decimal_comma: bool, quoted: bool, comments: bool) -> str:
    """The fixture as a spreadsheet saves it: cells joined by ``delimiter``, decimal commas, quoted."""
    out = LINES[:HEADER_AT] if comments else []
    for line in LINES[HEADER_AT:]:
        cells = [cell.replace(".", ",") if decimal_comma else cell for cell in line.split(",")]
        out.append(delimiter.join(f'"{cell}"' if quoted else cell for cell in cells))
    return "\n".join(out) + "\n"


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    dialect=st.sampled_from([(";", True), (";", False), ("\t", True), ("\t", False), (",", False)]),
    quoted=st.booleans(),
    comments=st.booleans(),
)
def test_the_projects_csv_in_any_spreadsheet_dialect_reads_as_the_file(
    tmp_path_factory, dialect, quoted, comments
):
    path = tmp_path_factory.mktemp("dialect") / "log.csv"
    path.write_text(resaved(*dialect, quoted=quoted, comments=comments), encoding="utf-8")
    reference = read_log(FIXTURE)
    log = read_log(path)
    assert log.format == "csv"
    assert_same_samples(log, reference)
    assert log.truth is not None and reference.truth is not None
    np.testing.assert_array_equal(log.truth.t, reference.truth.t)
    np.testing.assert_array_equal(log.truth.R, reference.truth.R)


def test_a_semicolon_resave_replays_through_the_cli(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text(resaved(";", True, quoted=False, comments=True), encoding="utf-8")
    assert main(["replay", str(path), "--no-plots", "--out", str(tmp_path / "out")]) == 0


def test_a_truth_row_that_is_no_unit_quaternion_names_its_line_in_any_dialect(tmp_path):
    path = tmp_path / "log.csv"
    text = resaved(";", True, quoted=True, comments=True)
    path.write_text(text + '"5,0";"truth";"0";"0";"0";"0,5"\n', encoding="utf-8")
    with pytest.raises(InputFormatError, match="unit norm") as info:
        read_log(path)
    assert f"log.csv:{len(text.splitlines()) + 1} (column w)" in str(info.value)
