"""A Sensor Logger export with a second recording appended to the first (a hunt's finding): the real export
of ``../shared/data``, its first rows and then rows recorded again after a pause — ``time`` (ns since the
epoch) going on from the pause, ``seconds_elapsed`` from the new recording's start again.

The reader told ``time``'s unit from its span end to end against ``seconds_elapsed``'s: across the restart
the two disagree, and the export was refused, "'time' spans 6 times what 'seconds_elapsed' does: its unit
is not ns" — though its ``time`` is in ns throughout and says exactly when each sample was taken. The unit
is now told over the steps on which ``seconds_elapsed`` goes on: the export reads, every sample at its
``time``, and the replay splits at the pause, saying so. A ``time`` in another unit throughout is still
refused (tests/test_phone_exports.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import needs_real_export, real_export

from hil.logs import read_log
from hil.logs.replay import ReplayOptions, replay

pytestmark = needs_real_export


def appended(first_rows: int, again_rows: int, pause_ns: int):
    """An edit for :func:`real_export`: the first ``first_rows`` rows, then the first ``again_rows`` rows
    recorded again ``pause_ns`` after the first stretch's last ``time``, their ``seconds_elapsed`` as
    recorded (from the start again)."""

    def edit(name: str, lines: list[str]) -> list[str]:
        rows = lines[1:]
        first = rows[:first_rows]
        shift = int(first[-1].split(",")[0]) - int(rows[0].split(",")[0]) + pause_ns
        again = []
        for line in rows[:again_rows]:
            time, rest = line.split(",", 1)
            again.append(f"{int(time) + shift},{rest}")
        return [lines[0], *first, *again]

    return edit


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    first_rows=st.integers(min_value=60, max_value=390),
    again_rows=st.integers(min_value=60, max_value=399),
    pause_s=st.floats(min_value=2.0, max_value=86_400.0),
)
def test_a_recording_appended_to_another_reads_at_its_time(
    tmp_path: Path, first_rows: int, again_rows: int, pause_s: float
) -> None:
    reference = read_log(real_export(tmp_path / "whole"))
    pause_ns = int(pause_s * 1e9)
    folder = real_export(
        tmp_path / f"two-{first_rows}-{again_rows}-{pause_ns}", appended(first_rows, again_rows, pause_ns)
    )
    log = read_log(folder)
    for kind, whole in reference.streams.items():
        stream = log.streams[kind]
        assert len(stream) == first_rows + again_rows  # nothing lost
        np.testing.assert_array_equal(stream.xyz[:first_rows], whole.xyz[:first_rows])
        np.testing.assert_array_equal(stream.xyz[first_rows:], whole.xyz[:again_rows])
        # the second stretch at its own time: after the first, the pause between
        np.testing.assert_allclose(stream.t[:first_rows], whole.t[:first_rows], atol=1e-6)
        later = stream.t[first_rows:] - stream.t[first_rows]
        np.testing.assert_allclose(later, whole.t[:again_rows] - whole.t[0], atol=1e-6)
        assert stream.t[first_rows] - stream.t[first_rows - 1] > pause_s - 1e-3


def test_the_replay_splits_at_the_pause_and_says_so(tmp_path: Path) -> None:
    folder = real_export(tmp_path / "two", appended(300, 399, 30 * 10**9))
    result = replay(folder, ReplayOptions(out_dir=tmp_path / "out"))
    assert len(result.segments) == 2
    said = [w for w in result.warnings if "the log's clock jumps by" in w]  # 30 s less the sensors' offsets
    assert len(said) == 1 and float(said[0].split("jumps by ")[1].split()[0]) > 29.0, result.warnings
