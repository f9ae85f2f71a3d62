"""Rows of a Sensor Logger export that were read silently wrong, or broke the replay with a message that
named nothing, built from the real export (``../shared/data``, read, never copied) in tmp_path:

* Gravity.csv rows out of time order: ``np.interp`` assumes increasing times and interpolated between
  them as if sorted (silently wrong gravity). Now only rows later than every earlier one are kept, the
  others counted and noted.
* Magnetometer (or accelerometer) readings of zero — a sensor not yet started — in the start-up still
  window: their mean was no direction, and the replay aborted with a numpy RuntimeWarning and
  ``e_mag: needs a non-zero finite 3-vector, got [nan, nan, nan]``. Now they are no readings for the still
  window; with none usable at all, an InputFormatError naming the log and the sensor.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_logs_layouts_beside import REAL, real_lines

from hil.cli import main
from hil.estimation.sensors import SensorKind
from hil.logs import read_log
from protocol.errors import InputFormatError

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")

LINES = 1001  # the header and 20 s of each 50 Hz file
SETTINGS = settings(
    max_examples=15,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


def gravity_export(folder, edit=lambda rows: rows):
    """Gyroscope, Magnetometer, Accelerometer.csv (user acceleration: zero) and Gravity.csv (the total
    acceleration's rows through ``edit``)."""
    folder.mkdir(parents=True)
    for name in ("Gyroscope.csv", "Magnetometer.csv"):
        (folder / name).write_text("\n".join(real_lines(name, LINES)) + "\n", encoding="utf-8")
    head, *rows = real_lines("TotalAcceleration.csv", LINES)
    user = [",".join(r.split(",")[:2] + ["0", "0", "0"]) for r in rows]
    (folder / "Accelerometer.csv").write_text("\n".join([head, *user]) + "\n", encoding="utf-8")
    (folder / "Gravity.csv").write_text("\n".join([head, *edit(list(rows))]) + "\n", encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def in_order(tmp_path_factory):
    return read_log(gravity_export(tmp_path_factory.mktemp("grav") / "export"))


@SETTINGS
# at most 40 rows (0.8 s at the export's 50 Hz): a longer stretch of gravity left out is no longer
# interpolated across (GRAVITY_GAP_S); and from the second row on: rows out of order at the very start
# leave the accelerometer's first rows before gravity's first, which are held 0.1 s and no longer
# (GRAVITY_HOLD_S). Both rules: tests/test_logs_beside_absurd_times.py
@given(start=st.integers(1, LINES - 60), length=st.integers(2, 40), how=st.sampled_from(["reverse", "swap"]))
def test_gravity_rows_out_of_order_are_dropped_and_counted_never_interpolated(
    tmp_path, in_order, start, length, how
):
    def edit(rows):
        if how == "reverse":
            rows[start : start + length] = rows[start : start + length][::-1]
        else:
            rows[start], rows[start + length] = rows[start + length], rows[start]
        return rows

    out = tmp_path / f"{start}-{length}-{how}"
    if out.exists():
        return
    log = read_log(gravity_export(out, edit))
    said = [n for n in log.notes if "Gravity.csv" in n and "not after every earlier" in n]
    dropped = length - 1 if how == "reverse" else length  # a reversed run keeps its latest; a swap, one row
    assert len(said) == 1 and said[0].split(": ")[1].startswith(f"{dropped} rows"), said
    # the acceleration at every gyro-clock sample is gravity interpolated between rows in order: the
    # same as the file in order (to the interpolation across the rows left out)
    got, ref = log.streams[SensorKind.ACC].xyz, in_order.streams[SensorKind.ACC].xyz
    assert np.all(np.isfinite(got))
    assert np.max(np.abs(got - ref)) < 1.0  # before: up to the span of the motion between the rows swapped
    assert np.mean(np.all(got == ref, axis=1)) > 0.9


def _zeros(folder, name: str, rows: range, lines: int = LINES):
    folder.mkdir(parents=True, exist_ok=True)
    for other in ("Gyroscope.csv", "Magnetometer.csv", "TotalAcceleration.csv"):
        head, *data = real_lines(other, lines)
        if other == name:
            for i in rows:
                data[i] = ",".join(data[i].split(",")[:2] + ["0", "0", "0"])
        (folder / other).write_text("\n".join([head, *data]) + "\n", encoding="utf-8")
    return folder


@SETTINGS
@given(
    name=st.sampled_from(["Magnetometer.csv", "TotalAcceleration.csv"]),
    first=st.integers(0, 5),
    n=st.integers(60, 150),
)
def test_zero_readings_in_the_still_window_are_skipped(tmp_path, capsys, name, first, n):
    out = tmp_path / f"{name}-{first}-{n}"
    if out.exists():
        return
    log = _zeros(out / "log", name, range(first, first + n))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # before: "invalid value encountered in divide"
        assert main(["replay", str(log), "--out", str(out / "run"), "--no-plots"]) == 0
    said = capsys.readouterr().out
    assert "inertial directions from the log: inclination -2" in said, said  # ~-28 deg, a number


@pytest.mark.parametrize(
    ("name", "sensor"), [("Magnetometer.csv", "magnetometer"), ("TotalAcceleration.csv", "accelerometer")]
)
def test_a_sensor_all_zero_is_an_error_naming_it(tmp_path, capsys, name, sensor):
    log = _zeros(tmp_path / "log", name, range(LINES - 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert main(["replay", str(log), "--out", str(tmp_path / "run"), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert f"no {sensor} reading in the first 10 s gives a direction" in err and str(log) in err, err
    assert "e_mag" not in err
    with pytest.raises(InputFormatError, match=sensor):
        from hil.estimation.inertial import directions_from_log

        directions_from_log(read_log(log))
