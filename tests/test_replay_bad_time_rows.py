"""A Sensor Logger row whose ``time`` is unusable (``nan``, 1e18 ns — 2001 in a recording of 2023 —, no
number, beyond int64) is a NaN sample: NaN time, dropped and counted the same by ``hil replay`` and by
``hil replay --port``.

Before, the reader gave such a row its file's median time (``np.where(usable, times, typical)``), and
``--port`` released each stream at the running maximum of its times: the gyro samples after the bad row
were held back until the middle of the recording (1375 of them for up to 28 s against firmware-sim: the
phone lost, exit 3); the batch replay dropped one. And one stamp far ahead of its neighbours (a usable
time, a second on) held back every later sample of its stream until then.

Variants of the real export (``../shared/data``, read, never copied) built in tmp_path: which file,
which row and what bad cell drawn.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_logs_layouts_beside import REAL, REAL_FILES, real_lines

from hil.cli import main
from hil.estimation.admission import JUMP_S
from hil.estimation.sensors import SensorKind
from hil.link.sources.recorded import release_times
from hil.logs import read_log

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")

KIND_OF = {
    "Gyroscope.csv": SensorKind.GYR,
    "TotalAcceleration.csv": SensorKind.ACC,
    "Magnetometer.csv": SensorKind.MAG,
}
LINES = 601  # the header and 12 s of each 50 Hz file
BAD_CELLS = ("nan", "NaN", "inf", "1000000000000000000", "0", "-1679068247609296600", "99999999999999999999")
SETTINGS = settings(
    max_examples=12,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
EMU = "emu://?units=4&telemetry_rate=50"


def export(folder, name: str | None = None, row: int = 0, cell: str = "") -> object:
    """The real export's first :data:`LINES` lines of each file in ``folder``; data row ``row`` (1-based)
    of ``name`` with ``cell`` as its time."""
    folder.mkdir(parents=True, exist_ok=True)
    for other in REAL_FILES:
        lines = real_lines(other, LINES)
        if other == name:
            cells = lines[row].split(",")
            cells[0] = cell
            lines[row] = ",".join(cells)
        (folder / other).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return read_log(export(tmp_path_factory.mktemp("ref") / "export"))


def _summary(out) -> dict:
    (run_dir,) = out.iterdir()
    return json.loads((run_dir / "summary.json").read_text())


@SETTINGS
@given(name=st.sampled_from(REAL_FILES), row=st.integers(30, LINES - 2), cell=st.sampled_from(BAD_CELLS))
def test_an_unusable_time_is_a_nan_sample_never_another_rows_time(tmp_path, reference, name, row, cell):
    out = tmp_path / f"{name}-{row}-{cell or 'empty'}"
    if out.exists():
        return
    log = read_log(export(out, name, row, cell))
    kind = KIND_OF[name]
    t = log.streams[kind].t
    assert np.isnan(t[row - 1]) and np.all(np.isnan(log.streams[kind].xyz[row - 1]))
    assert np.count_nonzero(np.isnan(t)) == 1  # that row only; every other time as it was
    np.testing.assert_array_equal(np.delete(t, row - 1), np.delete(reference.streams[kind].t, row - 1))
    assert any("NaN samples, dropped and counted" in n and name in n for n in log.notes)


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(100, LINES - 100), cell=st.sampled_from(("nan", "1000000000000000000")))
def test_a_bad_time_is_one_drop_in_batch_and_under_port_alike(tmp_path, row, cell):
    """The same row dropped and counted once both ways; under --port (lockstep against the in-process
    board) no gyroscope gap: the samples after it are released at their own times."""
    out = tmp_path / f"{row}-{cell}"
    if out.exists():
        return
    log = export(out / "log", "Gyroscope.csv", row, cell)
    assert main(["replay", str(log), "--out", str(out / "batch"), "--no-plots"]) == 0
    batch = json.loads((out / "batch" / "summary.json").read_text())
    assert batch["merge"]["dropped_nan"]["gyr"] == 1, batch["merge"]
    assert main(["replay", str(log), "--port", EMU, "--out", str(out / "port"), "--no-plots"]) == 0
    s = _summary(out / "port")
    assert s["exit"] == "completed" and s["phone_gaps"] == 0 and s["phone_gap_list"] == []
    assert s["phone_admission"]["dropped"]["bad_time"] == 1
    assert s["phone_admission"]["accepted"] == s["phone_samples"] - 1


def test_a_bad_time_does_not_lose_the_phone_against_firmware_sim_on_a_pty(tmp_path):
    """The reviewer's run: a 1e18 time early in Gyroscope.csv, the log driving firmware-sim over a real pty
    in real time (before: the gyro held back ~5 s, a phone gap; over a longer log the phone lost)."""
    log = export(tmp_path / "log", "Gyroscope.csv", 60, "1000000000000000000")
    out = tmp_path / "runs"
    args = ["replay", str(log), "--port", "spawn://firmware-sim?units=4&telemetry_rate=50",
            "--out", str(out), "--no-plots"]  # fmt: skip
    assert main(args) == 0
    s = _summary(out)
    assert s["exit"] == "completed" and s["mode"] == "port"
    assert s["phone_gaps"] == 0 and s["lost"] in (0, False, None), (s["phone_gap_list"], s["lost"])
    assert s["phone_admission"]["dropped"]["bad_time"] == 1


@given(n=st.integers(3, 200), data=st.data(), ahead=st.floats(0.05, 1e6))
def test_one_stamp_far_ahead_does_not_hold_its_stream_back(n, data, ahead):
    """Farther ahead of the next sample than the host's admission takes as one stream (JUMP_S): released
    with that sample (the host drops it as a future stray); nearer, at its own time, never early."""
    t = np.arange(n) * 0.02
    at = data.draw(st.integers(0, n - 2))
    t[at] += ahead
    release = release_times(t)
    assert np.all(np.diff(release) >= 0)  # in the stream's order
    if t[at] - t[at + 1] > JUMP_S:
        others = np.delete(np.arange(n), at)
        np.testing.assert_array_equal(release[others], t[others])  # every other sample due at its own time
        assert release[at] <= t[at + 1]
    else:
        assert np.all(release >= t)


def test_a_time_going_back_is_still_held_until_the_stream_passes_it():
    """A clock that jumped back (a resumed recording): the second stretch goes out after the first, as a
    live phone sends it; a NaN time at once, or with the last finite one."""
    t = np.array([0.0, 0.02, 0.04, 0.06, 0.01, 0.03, 0.05, 0.07, 0.09])
    np.testing.assert_array_equal(release_times(t), [0.0, 0.02, 0.04, 0.06, 0.06, 0.06, 0.06, 0.07, 0.09])
    t = np.array([np.nan, 0.0, np.nan, 0.02])
    np.testing.assert_array_equal(release_times(t), [-np.inf, 0.0, 0.0, 0.02])


def test_a_stamp_seconds_ahead_does_not_lose_its_stream_under_port(tmp_path):
    """5 s ahead in the middle of the log (no gap of the log's clock: the other sensors fill it): before,
    the gyroscope's later samples were held 5 s (a phone gap); now the stray is dropped as ``future``."""
    first = int(real_lines("Gyroscope.csv", 200)[150].split(",")[0])
    log = export(tmp_path / "log", "Gyroscope.csv", 150, str(first + 5 * 10**9))
    assert main(["replay", str(log), "--port", EMU, "--out", str(tmp_path / "port"), "--no-plots"]) == 0
    s = _summary(tmp_path / "port")
    assert s["exit"] == "completed" and s["phone_gaps"] == 0, s["phone_gap_list"]
    assert s["phone_admission"]["dropped"]["future"] == 1


def test_a_usable_stamp_days_ahead_is_its_own_part_in_batch_and_left_out_under_port(tmp_path):
    """11 days on (a usable epoch, within the month a recording may span): the batch replay splits there
    and cannot run a part of one sample (reported); --port drives the longest part, without it."""
    first = int(real_lines("Gyroscope.csv", 200)[150].split(",")[0])
    log = export(tmp_path / "log", "Gyroscope.csv", 150, str(first + 11 * 86400 * 10**9))
    assert main(["replay", str(log), "--out", str(tmp_path / "batch"), "--no-plots"]) == 0
    batch = json.loads((tmp_path / "batch" / "summary.json").read_text())
    assert len(batch["segments"]) == 2, batch["segments"]
    assert main(["replay", str(log), "--port", EMU, "--out", str(tmp_path / "port"), "--no-plots"]) == 0
    s = _summary(tmp_path / "port")
    assert s["exit"] == "completed" and s["phone_gaps"] == 0
    assert s["phone_samples"] == 3 * (LINES - 1) - 1  # every sample but the far one
