"""Recorded logs whose times parse but are absurd, and exports laid out a little differently: a replay
ends with its data accounted for, or with a typed error naming the file — never a crash, a run-away
allocation, or samples lost or made up without a word.

Each case was a defect of the readers and the replay, found beside the tested path:

- one stray row far on (a corrupt timestamp at 1e8 s) made the gyroscope-unit check window the whole
  span every half second: 24 GB; at 1e308 a ``ValueError``. The windows are now only where samples are;
- times that are no number: a sensor all ``inf`` crashed the still window's search (``np.arange`` from
  inf), a phyphox ``meta/time.csv`` whose system time overflowed made every time of its export ``inf``;
- a part of the log not replayed (a sensor silent in it) left its samples out uncounted, and the warning
  said the filter restarts there;
- ``Gravity.csv`` cut short was held (``np.interp``) over the whole recording: 15 % of the accelerometer
  more than 10° wrong, silently;
- a tyrex ``qualisys.mat`` of one frame (squeezed to (9,)) or of another shape crashed the reader;
- phyphox's ``"Time (ms)","Gyroscope x (rad/s)"`` was taken for a Sensor Logger export and refused;
- the project CSV's ``t_s`` written in ns was read as seconds, every sample a part of its own.
"""

from __future__ import annotations

import json
import math
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io as sio
from hypothesis import given, settings
from hypothesis import strategies as st
from log_support import REAL_SENSORLOGGER, needs_real_export, real_lines

from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from hil.logs.gyro_units import WINDOW_S, _window_starts
from hil.logs.replay import ReplayOptions, replay
from hil.logs.sensorlogger import GRAVITY_GAP_S, GRAVITY_HOLD_S
from hil.scenario.paths import SHARED_DATA
from protocol.errors import InputFormatError

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "fixtures" / "logs" / "simulated_testbed_4s.csv"
TYREX_TRIAL = SHARED_DATA / "tyrex-nexus5" / "Guillaume_Nexus5_NoDist_Texting"


def _with_rows(tmp_path: Path, rows: str, name: str = "log.csv") -> Path:
    path = tmp_path / name
    path.write_text(FIXTURE.read_text() + rows)
    return path


def _accounted(summary: dict) -> int:
    """Every sample the replay's summary accounts for: merged, or dropped for a reason it names."""
    merge = summary["merge"]
    counts = [
        merge["accepted"],
        merge["dropped_nan"],
        merge["dropped_duplicate"],
        merge["dropped_out_of_order"],
    ]
    counts += [merge["dropped_out_of_range"], merge["dropped_skipped_part"]]
    return sum(sum(c.values()) for c in counts)


# ---------------------------------------------------------------------------------------- far times


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.floats(min_value=-1e308, max_value=1e308, allow_nan=False, allow_infinity=False)
        | st.floats(min_value=0.0, max_value=20.0),
        min_size=0,
        max_size=60,
    ).map(sorted)
)
def test_the_unit_checks_windows_are_never_more_than_the_samples_wherever_they_lie(times):
    """However far apart a log's times lie (a stray row at 1e308 among seconds), the gyroscope-unit check
    windows no more than the samples there are, each window within the span, on the half-window grid."""
    gt = np.unique(np.asarray(times, float))
    if len(gt) < 2:
        return
    start, end = float(gt[0]), float(gt[-1])
    t0 = _window_starts(gt, start, end)
    assert len(t0) <= len(gt)
    assert np.all(np.isfinite(t0)) and np.all(t0 >= start) and np.all(t0 < end - WINDOW_S)


@pytest.mark.parametrize("far", [1e3, 1e6, 1e12, 1e308, -1e308])  # 1e8: below, memory capped
def test_a_stray_row_far_off_is_a_part_left_out_counted_and_said(tmp_path, far):
    """A gyroscope and an accelerometer row at a time far from the 4 s log: the log is replayed, the stray
    part is not, and its two samples are counted (``merge.dropped_skipped_part``) and named in a warning."""
    path = _with_rows(tmp_path, f"{far!r},gyr,0.01,0.02,0.03,\n{far!r},acc,0.1,0.2,9.8,\n")
    result = replay(path, ReplayOptions(out_dir=tmp_path / "out"))
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["merge"]["dropped_skipped_part"] == {"gyr": 1, "acc": 1, "mag": 0}
    assert [s for s in summary["segments"] if "skipped" in s] and len(result.estimates) > 700
    assert any("not replayed" in w and "2 samples are left out" in w for w in result.warnings)
    if far > 0:  # the filter does not restart after the log: it stops (before it, it starts there)
        assert not any("restarts" in w for w in result.warnings)
    assert _accounted(summary) == summary["samples"]
    assert all(len(w) < 600 for w in result.warnings)  # 1e308 s printed as 1e+308, not 300 digits


def test_a_stray_row_1e8_s_on_replays_in_bounded_memory(tmp_path):
    """The reproduction itself, through ``hil replay`` in a process allowed 4 GB of address space: it took
    24 GB before."""
    path = _with_rows(tmp_path, "1e8,gyr,0.01,0.02,0.03,\n1e8,acc,0.1,0.2,9.8,\n")

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))

    done = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(path), "--no-plots", "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=cap,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "not replayed" in done.stdout


# ---------------------------------------------------------------------------------- times no number


@pytest.mark.parametrize("bad", ["inf", "-inf", "nan"])
def test_a_sensor_with_no_finite_time_is_an_error_naming_it(tmp_path, bad):
    lines = FIXTURE.read_text().splitlines()
    edited = [f"{bad},{line.split(',', 1)[1]}" if ",gyr," in line else line for line in lines]
    path = tmp_path / "log.csv"
    path.write_text("\n".join(edited) + "\n")
    with pytest.raises(InputFormatError, match="no GYR sample has a finite time") as err:
        replay(path, ReplayOptions(out_dir=tmp_path / "out"))
    assert "log.csv" in str(err.value)


def test_infinite_times_among_finite_ones_are_dropped_and_counted(tmp_path):
    """A few rows at ±inf among a log's own: the log is replayed, those rows counted as NaN samples."""
    path = _with_rows(tmp_path, "inf,gyr,0.01,0.02,0.03,\n-inf,acc,0.1,0.2,9.8,\n-inf,gyr,0,0,0,\n")
    replay(path, ReplayOptions(out_dir=tmp_path / "out"))
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["merge"]["dropped_nan"]["gyr"] == 2 and summary["merge"]["dropped_nan"]["acc"] == 1
    assert _accounted(summary) == summary["samples"]


def _phyphox_export(folder: Path, name: str, label: str, unit: str, source: str, system_time: str) -> None:
    """One phyphox built-in export (``Raw Data.csv`` and ``meta/time.csv``) of the first 3 s of the real
    recording's ``source`` file, its START at ``system_time``."""
    rows = [line.split(",") for line in real_lines(source, 151)[1:]]
    t0 = int(rows[0][0])
    data = [f"{(int(r[0]) - t0) * 1e-9:.9E},{r[4]},{r[3]},{r[2]}" for r in rows]
    (folder / name / "meta").mkdir(parents=True)
    header = ",".join(f'"{label} {axis} ({unit})"' for axis in "xyz")
    (folder / name / "Raw Data.csv").write_text(f'"Time (s)",{header}\n' + "\n".join(data) + "\n")
    (folder / name / "meta" / "time.csv").write_text(
        '"event","experiment time","system time","system time text"\n'
        f'START,0.000000000E0,{system_time},"2023-03-17 15:50:47.609 UTC+00:00"\n'
    )


@needs_real_export
@pytest.mark.parametrize(
    ("acc_start", "gyr_start", "message"),
    [
        ("1e308", "-1e308", "no time since the epoch"),
        ("inf", "1679068247.6", "no time since the epoch"),
        ("nan", "1679068247.6", "no time since the epoch"),
        ("1679068247.6", "1e12", "no time since the epoch"),
        ("1679068247.6", "1779068247.6", "within 31 days"),
    ],
)  # two exports: the one farther from the median is either; three are below
def test_phyphox_exports_whose_start_times_cannot_align_them_are_an_error_naming_meta_time(
    tmp_path, acc_start, gyr_start, message
):
    _phyphox_export(tmp_path, "acc", "Acceleration", "m/s^2", "TotalAcceleration.csv", acc_start)
    _phyphox_export(tmp_path, "gyr", "Gyroscope", "rad/s", "Gyroscope.csv", gyr_start)
    with pytest.raises(InputFormatError, match=message) as err:
        read_log(tmp_path)
    assert "time.csv" in str(err.value)


@needs_real_export
def test_of_three_phyphox_exports_the_one_started_far_from_the_others_is_named(tmp_path):
    """Two exports started 3 s apart and a third whose start is corrupt (5 s: within the epoch bound,
    decades from the others): the error names the third's ``meta/time.csv``, not the first's."""
    _phyphox_export(tmp_path, "acc", "Acceleration", "m/s^2", "TotalAcceleration.csv", "1679068247.6")
    _phyphox_export(tmp_path, "gyr", "Gyroscope", "rad/s", "Gyroscope.csv", "1679068250.6")
    _phyphox_export(tmp_path, "mag", "Magnetic field", "µT", "Magnetometer.csv", "5.0")
    with pytest.raises(InputFormatError, match="within 31 days") as err:
        read_log(tmp_path)
    assert str(tmp_path / "mag" / "meta" / "time.csv") in str(err.value)


@needs_real_export
def test_phyphox_exports_with_sane_start_times_align(tmp_path):
    _phyphox_export(tmp_path, "acc", "Acceleration", "m/s^2", "TotalAcceleration.csv", "1679068247.6")
    _phyphox_export(tmp_path, "gyr", "Gyroscope", "rad/s", "Gyroscope.csv", "1679068247.8")
    log = read_log(tmp_path)
    assert log.format == "phyphox" and log.six_axis
    gyr, acc = log.streams[SensorKind.GYR], log.streams[SensorKind.ACC]
    assert gyr.t[0] - acc.t[0] == pytest.approx(0.2, abs=1e-6)


# --------------------------------------------------------------------------- parts not replayed


@needs_real_export
def test_a_part_where_a_sensor_is_silent_is_counted_and_said_not_restarted(tmp_path):
    """The magnetometer stops at 3 s, then every sensor pauses 2 s: the part after the pause is not
    replayed (no magnetometer in it); its samples are counted and the warning says so."""
    lines = 601

    def keep(name: str, line: str) -> bool:
        if line.startswith("time"):
            return True
        elapsed = float(line.split(",")[1])
        return not (3.0 <= elapsed < 5.0) and not (name == "Magnetometer.csv" and elapsed >= 3.0)

    for name in ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv"):
        kept = [line for line in real_lines(name, lines) if keep(name, line)]
        (tmp_path / name).write_text("\n".join(kept) + "\n")
    result = replay(tmp_path, ReplayOptions(out_dir=tmp_path / "out"))
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    skipped = summary["merge"]["dropped_skipped_part"]
    assert skipped["gyr"] > 200 and skipped["acc"] > 200 and skipped["mag"] == 0
    assert _accounted(summary) == summary["samples"]
    said = [w for w in result.warnings if "not replayed" in w]
    assert len(said) == 1 and f"{sum(skipped.values())} samples are left out" in said[0]
    assert not any("restarts" in w for w in result.warnings)


# ------------------------------------------------------------------------------------- gravity


def _user_and_gravity(folder: Path, gravity_rows: list[str]) -> Path:
    """A Sensor Logger export of user acceleration (zeros) and ``gravity_rows`` of ``Gravity.csv`` (the
    real total acceleration standing in for gravity), with the real gyroscope and magnetometer."""
    folder.mkdir(parents=True, exist_ok=True)
    total = real_lines("TotalAcceleration.csv", 1001)
    user = [total[0]] + [",".join([*line.split(",")[:2], "0", "0", "0"]) for line in total[1:]]
    (folder / "Accelerometer.csv").write_text("\n".join(user) + "\n")
    (folder / "Gravity.csv").write_text("\n".join([total[0], *gravity_rows]) + "\n")
    for name in ("Gyroscope.csv", "Magnetometer.csv"):
        (folder / name).write_text("\n".join(real_lines(name, 1001)) + "\n")
    return folder


@needs_real_export
def test_whole_gravity_is_added_to_every_accelerometer_row(tmp_path):
    total = real_lines("TotalAcceleration.csv", 1001)
    log = read_log(_user_and_gravity(tmp_path / "whole", total[1:]))
    acc = log.streams[SensorKind.ACC]
    assert np.all(np.isfinite(acc.xyz))
    assert not any("no Gravity.csv row near" in n for n in log.notes)


@needs_real_export
def test_gravity_cut_short_is_an_error_naming_it(tmp_path):
    total = real_lines("TotalAcceleration.csv", 1001)
    with pytest.raises(InputFormatError, match="give gravity to only") as err:
        read_log(_user_and_gravity(tmp_path / "short", total[1:11]))
    assert "Gravity.csv" in str(err.value)


@needs_real_export
@pytest.mark.parametrize("gap_rows", [(300, 400), (500, 520), (0, 50), (950, 1000)])
def test_accelerometer_rows_without_gravity_near_are_nan_samples_noted(tmp_path, gap_rows):
    """Gravity rows missing for a stretch: inside, across more than :data:`GRAVITY_GAP_S` the accelerometer
    rows get no gravity made up (NaN samples, dropped and counted by the merge, noted by the reader), a
    shorter one is interpolated across; at either end, rows beyond :data:`GRAVITY_HOLD_S` get none. The
    rows the gap is not beside are as with the whole file."""
    total = real_lines("TotalAcceleration.csv", 1001)
    a, b = gap_rows
    log = read_log(_user_and_gravity(tmp_path / "gap", total[1 : 1 + a] + total[1 + b :]))
    whole = read_log(_user_and_gravity(tmp_path / "whole", total[1:])).streams[SensorKind.ACC]
    acc = log.streams[SensorKind.ACC]
    bad = ~np.all(np.isfinite(acc.xyz), axis=1)
    period = float(np.median(np.diff(whole.t)))
    if a == 0 or b == len(whole):  # at an end: held GRAVITY_HOLD_S, no farther
        expected = (b - a) - round(GRAVITY_HOLD_S / period)
        assert abs(int(bad.sum()) - expected) <= 2, (bad.sum(), expected)
    elif (b - a + 1) * period > GRAVITY_GAP_S:
        assert bad.sum() == b - a
    else:
        assert not bad.any()
    assert bad.any() == any("no Gravity.csv row near" in n for n in log.notes)
    outside = np.r_[0 : max(a - 1, 0), min(b + 1, len(whole)) : len(whole)]  # rows the gap is not beside
    np.testing.assert_array_equal(acc.xyz[outside], whole.xyz[outside])
    assert not bad[outside].any()


# --------------------------------------------------------------------------------------- tyrex


@pytest.mark.skipif(not TYREX_TRIAL.is_dir(), reason="the shared tyrex recordings are not here")
@pytest.mark.parametrize(
    ("rotations", "reads"),
    [
        (np.eye(3).reshape(9, 1), True),  # one frame: squeezed to (9,) by the loader
        (np.tile(np.eye(3).reshape(9, 1), (2, 1, 30)), True),  # two rigid bodies: the first
        (np.float64(1.0), False),
        (np.zeros((2, 4, 5)), False),
        (np.zeros((4, 9)), False),
        (np.zeros((9, 3, 2, 2)), False),
    ],
    ids=["one-frame", "two-bodies", "scalar", "3d-not-9", "transposed", "4d"],
)
def test_a_tyrex_truth_of_any_shape_reads_or_is_an_error_naming_rotations(tmp_path, rotations, reads):
    trial = tmp_path / TYREX_TRIAL.name
    trial.mkdir()
    for f in TYREX_TRIAL.iterdir():
        if f.name != "qualisys.mat":
            shutil.copy(f, trial / f.name)
    sio.savemat(trial / "qualisys.mat", {"qtm": {"FrameRate": 60.0, "RigidBodies": {"Rotations": rotations}}})
    if reads:
        log = read_log(trial)
        assert log.truth is not None and log.truth.R.shape[1:] == (3, 3)
    else:
        with pytest.raises(InputFormatError, match="Rotations") as err:
            read_log(trial)
        assert "qualisys.mat" in str(err.value)


# ------------------------------------------------------------------------------- phyphox in ms


def test_a_phyphox_export_with_its_clock_in_ms_is_read_as_phyphox(tmp_path):
    for name, label, unit, z in (("Accelerometer.csv", "Acceleration", "m/s^2", 9.81),
                                 ("Gyroscope.csv", "Gyroscope", "rad/s", 0.0)):  # fmt: skip
        header = ",".join(f'"{label} {axis} ({unit})"' for axis in "xyz")
        rows = [f"{i * 20.0:.9E},1.0E-2,2.0E-2,{z:.9E}" for i in range(500)]
        (tmp_path / name).write_text(f'"Time (ms)",{header}\n' + "\n".join(rows) + "\n")
    log = read_log(tmp_path)
    assert log.format == "phyphox"
    assert np.median(np.diff(log.streams[SensorKind.GYR].t)) == pytest.approx(0.02)


# ------------------------------------------------------------------------------ t_s in ns or ms


@pytest.mark.parametrize(("scale", "offset"), [(1e9, 1679068247609296600), (1e3, 0), (1e6, 0)])
def test_a_project_csv_whose_t_s_is_not_seconds_is_an_error_naming_t_s(tmp_path, scale, offset):
    rows = ["t_s,sensor,x,y,z,w"]
    for i in range(300):
        t = offset + i * 0.01 * scale
        rows += [f"{t!r},gyr,0.1,0.2,0.3,", f"{t!r},acc,0.1,0.2,9.8,"]
    path = tmp_path / "log.csv"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(InputFormatError, match="t_s is in seconds") as err:
        read_log(path)
    assert "log.csv" in str(err.value) and "t_s" in str(err.value)


@pytest.mark.parametrize("seed", range(5))
def test_a_project_csv_with_a_1_hz_sensor_reads(tmp_path, seed):
    """The path's other side: a sensor at 1 Hz (the slowest a phone's is), its times jittered by 50 ms, is
    read (a bound at exactly 1 s refused half of such logs)."""
    rng = np.random.default_rng(seed)
    rows = ["t_s,sensor,x,y,z,w"]
    for i in range(60):
        rows.append(f"{i + rng.uniform(-0.05, 0.05)!r},mag,1.0,28.0,-37.0,")
        rows += [f"{i + k / 50!r},{s},0.1,0.2,9.8," for k in range(50) for s in ("gyr", "acc")]
    path = tmp_path / "log.csv"
    path.write_text("\n".join(rows) + "\n")
    log = read_log(path)
    assert len(log.streams[SensorKind.MAG]) == 60


def test_the_shared_recordings_still_read(tmp_path):
    """The rules above leave every real recording as it was read: none refused, none with NaN added."""
    for path in [REAL_SENSORLOGGER, *sorted((SHARED_DATA / "tyrex-nexus5").glob("*/"))[:3]]:
        if not path.exists():
            continue
        log = read_log(path)
        assert math.isfinite(log.start) and math.isfinite(log.end) and log.end > log.start


@pytest.mark.parametrize("before", ["# a\n" * 5, "\n" * 3, "# exported by a tool\n\n" * 20, "   \n# x\n" * 7])
def test_the_project_csv_is_found_past_the_comment_and_blank_lines_before_its_header(tmp_path, before):
    """The format's own files are told by their header past the comment and blank lines before it (as far
    as the detectors look: 64 lines, 4 KiB; the detector read the first five lines only: a sixth-line
    header was "not a recognised log")."""
    own = [line for line in FIXTURE.read_text().splitlines() if not line.startswith("#")]
    path = tmp_path / "log.csv"
    path.write_text(before + "\n".join(own) + "\n")
    log = read_log(path)
    assert log.format == "csv" and log.n_samples == read_log(FIXTURE).n_samples


def test_a_6_axis_start_from_gravity_passes_over_a_first_time_that_is_no_number():
    """A 6-axis log's start attitude is its first half second's gravity when it has no still window: a NaN
    first accelerometer time (a stray row a reader made a NaN sample) selected no reading, and the start
    was the identity, without a word."""
    from hil.estimation.inertial import tilt_attitude
    from hil.estimation.sensors import SensorLog, SensorStream

    t = np.r_[np.nan, np.arange(1, 100) * 0.01]
    tilt = 0.3
    acc = SensorStream(SensorKind.ACC, t, np.tile([0.0, 9.81 * np.sin(tilt), 9.81 * np.cos(tilt)], (100, 1)))
    gyr = SensorStream(SensorKind.GYR, t, np.tile([0.5, 0.0, 0.0], (100, 1)))  # turning: no still window
    R = tilt_attitude(SensorLog({SensorKind.GYR: gyr, SensorKind.ACC: acc}, "x", "csv"))
    np.testing.assert_allclose(R @ acc.xyz[1] / 9.81, [0.0, 0.0, 1.0], atol=1e-9)  # gravity to up


def test_the_truth_is_scored_only_where_the_filter_ran_never_across_a_gap(tmp_path):
    """The 4 s simulated log split by a 30 s gap after 2 s, its truth going on through the gap (turning
    there): the truth inside the gap is not scored — the estimate there would be two parts' ends joined by
    interpolation, no estimate the filter made — and the score is the parts' own."""
    from hil import so3
    from hil.estimation.sensors import SensorLog, SensorStream, Truth
    from hil.logs import project_csv

    log = read_log(FIXTURE)
    assert log.truth is not None
    shift = lambda t: np.where(t > 2.0, t + 30.0, t)  # noqa: E731
    streams = {k: SensorStream(k, shift(s.t), s.xyz) for k, s in log.streams.items()}
    gap_t = np.arange(2.1, 31.9, 0.1)  # the truth turns 180° about z, and back, in the gap
    gap_r = np.stack([so3.exp(np.array([0.0, 0.0, np.pi * np.sin(np.pi * (t - 2.0) / 30.0)])) for t in gap_t])
    t_all = np.r_[shift(log.truth.t), gap_t]
    order = np.argsort(t_all, kind="stable")
    truth = Truth(t_all[order], np.concatenate([log.truth.R, gap_r])[order])
    gapped = project_csv.write(SensorLog(streams, "gap", "csv", truth), tmp_path / "gap.csv")
    result = replay(gapped, ReplayOptions(tmp_path / "o", max_gap_s=10.0))
    whole = replay(FIXTURE, ReplayOptions(tmp_path / "w"))
    assert result.comparison is not None and whole.comparison is not None
    scored = result.comparison.rmse.n
    assert scored <= whole.comparison.rmse.n  # none of the gap's 298 truth samples
    assert result.comparison.rmse.total < 3 * whole.comparison.rmse.total + 1.0, result.comparison.rmse
