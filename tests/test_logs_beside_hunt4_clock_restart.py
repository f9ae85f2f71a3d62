"""``hil replay`` (batch, no board) of an export one of whose files has its clock go back mid-file: a
recording restarted and appended, or a file shifted by a tool, from a drawn row, by a drawn step back.

Before: the merge dropped the samples after the restart as out of order only up to where the first
stretch ended; those stamped beyond it were taken as readings of those times — another moment's motion
replayed as this one's — and the run said nothing of a restart. ``hil replay --port`` cut the log at the
restart already (:func:`hil.logs.replay.before_clock_restart`): the batch replay now does the same, says
so, and counts what it left out. The exports are the shared recording cut short (read, never copied)."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main
from tests.log_support import REAL_LINES, needs_real_export, real_export

KINDS = {"Gyroscope.csv": "gyr", "TotalAcceleration.csv": "acc", "Magnetometer.csv": "mag"}


def shifted_back(name: str, at: int, back_s: float):
    """An edit for :func:`real_export`: file ``name``'s rows from row ``at`` on stamped ``back_s`` earlier
    (both clocks, as a restarted recording's are)."""

    def edit(file: str, lines: list[str]) -> list[str]:
        if file != name:
            return lines
        out = lines[: at + 1]
        for row in lines[at + 1 :]:
            time, elapsed, *axes = row.split(",")
            out.append(",".join([str(int(time) - round(back_s * 1e9)), repr(float(elapsed) - back_s), *axes]))
        return out

    return edit


@needs_real_export
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    name=st.sampled_from(sorted(KINDS)),
    at=st.integers(REAL_LINES // 3, REAL_LINES - 60),
    back_s=st.floats(1.5, 4.0),
)
def test_a_file_whose_clock_goes_back_is_replayed_up_to_there_said_and_counted(tmp_path, name, at, back_s):
    out = Path(tempfile.mkdtemp(dir=tmp_path))
    log = real_export(out / "log", shifted_back(name, at, back_s))
    assert main(["replay", str(log), "--out", str(out / "run"), "--no-plots"]) == 0
    summary = json.loads((out / "run" / "summary.json").read_text())
    said = [w for w in summary["warnings"] if "the log's clock goes back" in w]
    assert len(said) == 1 and "replaying the stretch before it" in said[0], summary["warnings"]
    after = REAL_LINES - 1 - at  # the rows after the restart, each left out and counted
    assert summary["merge"]["dropped_skipped_part"][KINDS[name]] >= after
    assert summary["merge"]["dropped_out_of_order"][KINDS[name]] == 0
