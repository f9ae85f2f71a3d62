"""Bad log input at bounded cost: a timestamp far off splits the replay instead of hanging it; readers
stream (memory bounded by the samples kept, a bad line fails at once); a disturbed or unsteady field is
warned about."""

from __future__ import annotations

import json
import subprocess
import sys
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.world.models import Trajectory, simulate
from hil import so3
from hil.estimation.geomag import GeomagneticField
from hil.estimation.inertial import directions_from_dip, field_warnings
from hil.estimation.sensors import SensorKind, SensorLog, SensorStream, StepFlag
from hil.logs import project_csv, read_log
from hil.logs.replay import ReplayOptions, replay
from hil.scenario.paths import FIXTURES, SHARED_DATA
from hil.scenario.phone import PhoneSpec, SensorSpec
from protocol.errors import InputFormatError

SIMULATED = FIXTURES / "logs" / "simulated_testbed_4s.csv"


def test_one_timestamp_a_million_seconds_off_splits_the_replay_and_does_not_hang(tmp_path):
    lines = SIMULATED.read_text().splitlines()
    gyr_rows = [i for i, line in enumerate(lines) if ",gyr," in line]
    k = gyr_rows[len(gyr_rows) // 2]
    lines[k] = "1000000.0" + lines[k][lines[k].index(",") :]
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    run = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(bad), "--out", str(out), "--no-plots"],
        capture_output=True,
        text=True,
        timeout=300,
    )  # fmt: skip  (a hang fails here)
    assert run.returncode == 0, run.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    parts = summary["segments"]
    assert len(parts) == 2 and parts[1]["gap_before_s"] > 9e5 and "skipped" in parts[1]
    said = [w for w in summary["warnings"] if "not replayed" in w]  # the filter does not restart: it ends
    assert len(said) == 1 and "1 sample is left out" in said[0] and "not replayed" in run.stdout
    assert summary["merge"]["dropped_skipped_part"]["gyr"] == 1
    assert summary["merge"]["dropped_out_of_order"]["gyr"] == 0  # the split keeps the rest of the gyro
    est = np.loadtxt(out / "estimates.csv", delimiter=",", skiprows=2)
    assert est[:, 0].max() < 5.0


def test_a_gap_within_the_log_restarts_the_filter_on_each_side(tmp_path):
    log = read_log(SIMULATED)
    shifted = SensorLog(
        {k: SensorStream(k, np.where(s.t > 2.0, s.t + 30.0, s.t), s.xyz) for k, s in log.streams.items()},
        "gap",
        "csv",
        None,  # fmt: skip
    )
    path = project_csv.write(shifted, tmp_path / "gap.csv")
    result = replay(path, ReplayOptions(tmp_path / "o", max_gap_s=10.0))
    assert [("skipped" in p) for p in result.segments] == [False, False]
    assert result.segments[1]["gap_before_s"] == pytest.approx(30.0, abs=0.02)
    est = result.estimates
    after = int(np.argmax(est.t > 20.0))
    assert est.t[after] - est.t[after - 1] > 30.0  # the split ...
    assert not est.flags[after] & int(StepFlag.SUBSTEPPED)  # ... is not integrated across: a fresh start
    assert result.merge_stats.gaps == 0  # no merged step spans the gap
    with pytest.raises(Exception, match="max_gap_s"):
        replay(path, ReplayOptions(tmp_path / "o", max_gap_s=float("nan")))


def _big_csv(path, rows: int, bad_line: int | None = None) -> int:
    """A project CSV of ``rows`` gyro/acc/mag rows (about 45 bytes each), written in blocks."""
    with path.open("w") as f:
        f.write("# vscmg-hil sensor log v1\nt_s,sensor,x,y,z,w\n")
        line_no = 2
        block = []
        for i in range(rows):
            line_no += 1
            kind = ("gyr", "acc", "mag")[i % 3]
            block.append(
                f"{i * 0.001:.6f},{kind},0.5\n"
                if line_no == bad_line
                else f"{i * 0.001:.6f},{kind},0.01,0.02,9.81,\n"
            )
            if len(block) == 100_000:
                f.write("".join(block))
                block = []
        f.write("".join(block))
    return path.stat().st_size


def test_a_bad_line_in_a_large_file_fails_at_once_in_bounded_memory(tmp_path):
    size = _big_csv(tmp_path / "big.csv", 1_500_000, bad_line=2194)
    assert size > 40e6
    tracemalloc.start()
    try:
        with pytest.raises(InputFormatError) as info:
            read_log(tmp_path / "big.csv")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert info.value.line == 2194 and "3 values, expected 6" in str(info.value)
    assert peak < 20e6, f"{peak / 1e6:.1f} MB traced to fail on line 2194 of a {size / 1e6:.0f} MB file"


def test_reading_a_large_file_holds_the_samples_not_the_text(tmp_path):
    rows = 600_000
    _big_csv(tmp_path / "big.csv", rows)
    tracemalloc.start()
    try:
        log = read_log(tmp_path / "big.csv")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    kept = rows * 6 * 8  # the parsed table, float64
    assert log.n_samples == rows
    assert peak < 3 * kept + 10e6, f"{peak / 1e6:.0f} MB for {kept / 1e6:.0f} MB of samples"


def _still_then_turning(disturbed_first_s: float = 0.0):
    traj = Trajectory.from_rate(
        lambda t: np.zeros(3) if t < 2.0 else np.array([0.4, -0.3, 0.8]) * np.sin(t),
        30.0,
        R0=so3.exp([0.2, -0.5, 1.0]),
        dt=5e-3,  # fmt: skip
    )
    field = 48.0 * directions_from_dip(69.0, 3.0)[:, 1]
    spec = PhoneSpec(SensorSpec(100.0, 1e-3, 0.0), SensorSpec(100.0, 0.02, 0.0), SensorSpec(50.0, 0.3, 0.0),
                     9.81, tuple(field))  # fmt: skip
    log = simulate(traj, spec, seed=1)
    if disturbed_first_s:
        mag = log.streams[SensorKind.MAG]
        xyz = mag.xyz.copy()
        xyz[mag.t < disturbed_first_s] += [0.0, 0.0, 110.0]  # a magnet near the phone: dip far off
        log = SensorLog({**log.streams, SensorKind.MAG: SensorStream(SensorKind.MAG, mag.t, xyz)},
                        "disturbed", "simulated", log.truth)  # fmt: skip
    return log


def test_a_disturbed_start_and_a_model_that_disagrees_are_warned_about():
    assert field_warnings(_still_then_turning()) == []
    warnings = field_warnings(_still_then_turning(disturbed_first_s=5.0))
    assert any("disturbed start" in w for w in warnings), warnings
    model = GeomagneticField(north_nT=30000.0, east_nT=0.0, down_nT=10000.0)  # dip 18 deg, not 69
    assert any("field model" in w for w in field_warnings(_still_then_turning(), model))


def test_no_warning_without_a_magnetometer():
    log = _still_then_turning()
    six = SensorLog({k: s for k, s in log.streams.items() if k != SensorKind.MAG}, "6", "simulated")
    assert six.six_axis and field_warnings(six) == []


SENSORLOGGER = SHARED_DATA / "sensorlogger-android"
ABSURD = st.one_of(st.floats(min_value=200.0, max_value=1e300), st.floats(min_value=-1e300, max_value=-200.0))
"""A value that parses but no phone's gyroscope (±40 rad/s) or accelerometer (±172.6 m/s²) measures."""


@pytest.fixture(scope="module")
def real_window(tmp_path_factory):
    """30 s of the real Sensor Logger export, as the project's CSV (replayed as a file), and its replay."""
    log = read_log(SENSORLOGGER).window(100.0, 130.0)
    folder = tmp_path_factory.mktemp("window")
    path = project_csv.write(log, folder / "window.csv")
    clean = replay(path, ReplayOptions(out_dir=folder / "out"))
    return log, clean


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_readings_beyond_range_in_a_real_log_are_dropped_counted_and_leave_the_rest_as_it_was(
    tmp_path, real_window, data
):
    """Absurd-but-finite readings (a gyro of 1e300 rad/s, an accelerometer of -1e160 m/s²) added to a real
    recording at drawn times are dropped and counted, as the live path's admission drops them: the
    estimates stay finite, and the replay equals the clean one's wherever no reading was added (before the
    first one it is the same run; the filter never sees them at all)."""
    log, clean = real_window
    streams = dict(log.streams)
    added = {"gyr": 0, "acc": 0}
    for kind in (SensorKind.GYR, SensorKind.ACC):
        stream = streams[kind]
        rows = data.draw(st.lists(st.integers(0, len(stream) - 2), max_size=3, unique=True), label=kind.label)
        t, xyz = list(stream.t), [list(r) for r in stream.xyz]
        for row in sorted(rows, reverse=True):  # a new reading between two of the stream's own
            value = data.draw(ABSURD, label=f"{kind.label} value")
            axis = data.draw(st.integers(0, 2), label="axis")
            reading = [0.0, 0.0, 0.0]
            reading[axis] = value
            t.insert(row + 1, (t[row] + t[row + 1]) / 2.0)
            xyz.insert(row + 1, reading)
        added[kind.label] = len(rows)
        streams[kind] = SensorStream(kind, np.array(t), np.array(xyz))
    path = project_csv.write(replace(log, streams=streams), tmp_path / "absurd.csv")
    result = replay(path, ReplayOptions(out_dir=tmp_path / "out"))
    assert result.out_of_range == {**added, "mag": 0}
    assert result.samples_read == log.n_samples + sum(added.values())
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["merge"]["dropped_out_of_range"] == {**added, "mag": 0}
    assert any("beyond their sensor's range" in w for w in summary["warnings"]) == bool(sum(added.values()))
    est = result.estimates
    assert np.all(np.isfinite(est.R)) and np.all(np.isfinite(est.omega))
    np.testing.assert_array_equal(est.t, clean.estimates.t)  # the added readings make no steps of their own
    np.testing.assert_array_equal(est.R, clean.estimates.R)


def test_a_sensor_whose_every_reading_is_beyond_range_is_a_typed_error_naming_the_log(tmp_path):
    log = read_log(SIMULATED)
    acc = log.streams[SensorKind.ACC]
    absurd = SensorStream(SensorKind.ACC, acc.t, np.full_like(acc.xyz, 1e160))
    path = project_csv.write(
        replace(log, streams={**log.streams, SensorKind.ACC: absurd}), tmp_path / "a.csv"
    )
    with pytest.raises(InputFormatError, match="every ACC reading .* beyond the sensor's range") as err:
        replay(path, ReplayOptions(out_dir=tmp_path / "out"))
    assert str(path) in str(err.value)
