"""One corrupt ``seconds_elapsed`` cell in a Sensor Logger export whose ``time`` is right throughout is no
reason to refuse the export.

``time`` is the clock; ``seconds_elapsed`` only checks its unit (and gives the recording's start epoch, a
median). The check summed ``seconds_elapsed``'s forward steps end to end: one row of 1e160 (or a day on,
or -1e160: its step back up is as long) made that span absurd and the whole export was refused — "read as
ns since the epoch, 'time' spans 8.021e-160 times what 'seconds_elapsed' does: its unit is not ns" — while
a row of 1e160 in ``time`` itself is a NaN sample, noted. Drawn: the file, the row, the stray value. A
``time`` truly in another unit is still refused.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorLog
from hil.logs import read_log
from protocol.errors import InputFormatError
from tests.log_support import REAL_FILES, REAL_LINES, needs_real_export, real_export

pytestmark = needs_real_export

STRAYS = st.sampled_from(["1e160", "-1e160", "86400.5", "1e5", "-3600", "9999999"])


def _with_stray(folder: Path, file: str, row: int, value: str) -> Path:
    def edit(name: str, lines: list[str]) -> list[str]:
        if name == file:
            cells = lines[row].split(",")
            cells[1] = value  # seconds_elapsed
            lines[row] = ",".join(cells)
        return lines

    return real_export(folder, edit)


_REFERENCE: list[SensorLog] = []


def _reference(tmp_path_factory: pytest.TempPathFactory) -> SensorLog:
    """The export without a stray, read once for every example."""
    if not _REFERENCE:
        _REFERENCE.append(read_log(real_export(tmp_path_factory.mktemp("ref"))))
    return _REFERENCE[0]


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(file=st.sampled_from(REAL_FILES), row=st.integers(1, REAL_LINES - 1), value=STRAYS)
def test_a_stray_seconds_elapsed_leaves_every_time_read(
    tmp_path_factory: pytest.TempPathFactory, file: str, row: int, value: str
) -> None:
    reference = _reference(tmp_path_factory)
    log = read_log(_with_stray(tmp_path_factory.mktemp("stray"), file, row, value))
    for kind, stream in reference.streams.items():  # every sample kept, at its own time: 'time' is the clock
        np.testing.assert_array_equal(log.streams[kind].t, stream.t)
        np.testing.assert_array_equal(log.streams[kind].xyz, stream.xyz)


def test_hil_replay_replays_it(tmp_path: Path) -> None:
    export = _with_stray(tmp_path / "log", "Gyroscope.csv", 100, "1e160")
    done = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(export), "--no-plots", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "out" / "estimates.csv").is_file()


def test_a_time_in_another_unit_is_still_refused(tmp_path: Path) -> None:
    """Every row's ``time`` a thousandth of what it should be beside ``seconds_elapsed``: no stray, a unit
    that does not agree (the check the stray once tripped)."""

    def edit(name: str, lines: list[str]) -> list[str]:
        if name != "Gyroscope.csv":
            return lines
        t0 = int(lines[1].split(",")[0])
        out = [lines[0]]
        for line in lines[1:]:
            t, rest = line.split(",", 1)
            out.append(f"{t0 + (int(t) - t0) // 1000},{rest}")
        return out

    with pytest.raises(InputFormatError, match=r"Gyroscope\.csv.*column time.*its unit is not ns"):
        read_log(real_export(tmp_path / "log", edit))
