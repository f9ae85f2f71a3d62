"""Inertial directions E: the WMM2025 field model against NOAA's published test values, and E measured
from a log (still window, median dip)."""

from __future__ import annotations

from datetime import date

import numpy as np
import pytest

from firmware_sim.world.models import Trajectory, simulate
from hil import so3
from hil.estimation.inertial import (
    decimal_year,
    directions_from_dip,
    directions_from_log,
    directions_from_still,
    find_still_window,
    median_inclination_deg,
    wmm2025,
)
from hil.estimation.params import EstimatorParams
from hil.scenario.phone import PhoneSpec, SensorSpec
from protocol.errors import ConfigError, InputFormatError

# NOAA WMM2025 test values: year, height km, lat, lon, X (north) nT, Y (east) nT, Z (down) nT, D deg
NOAA = [
    (2025.0, 0.0, 80.0, 0.0, 6521.6, 145.9, 54791.5, 1.28),
    (2025.0, 0.0, 0.0, 120.0, 39677.8, -109.6, -10580.2, -0.16),
    (2025.0, 0.0, -80.0, 240.0, 6117.5, 15751.9, -52022.5, 68.78),
    (2025.0, 100.0, 80.0, 0.0, 6216.0, 92.4, 52598.8, 0.85),
    (2025.0, 100.0, 0.0, 120.0, 37688.6, -96.2, -10152.1, -0.15),
    (2025.0, 100.0, -80.0, 240.0, 5907.6, 14780.3, -49540.7, 68.21),
    (2027.5, 0.0, 80.0, 0.0, 6500.8, 294.5, 54869.4, 2.59),
    (2027.5, 0.0, 0.0, 120.0, 39701.6, -167.4, -10381.8, -0.24),
    (2027.5, 0.0, -80.0, 240.0, 6200.7, 15730.3, -51783.7, 68.49),
    (2027.5, 100.0, 80.0, 0.0, 6196.7, 233.8, 52670.5, 2.16),
    (2027.5, 100.0, 0.0, 120.0, 37711.5, -148.7, -9969.8, -0.23),
    (2027.5, 100.0, -80.0, 240.0, 5984.0, 14760.1, -49317.7, 67.93),
]


@pytest.mark.parametrize(("year", "h", "lat", "lon", "x", "y", "z", "d"), NOAA)
def test_wmm2025_matches_noaa_test_values(year, h, lat, lon, x, y, z, d):
    f = wmm2025(lat, lon, year, h)
    assert (f.north_nT, f.east_nT, f.down_nT) == pytest.approx((x, y, z), abs=0.1)
    assert f.declination_deg == pytest.approx(d, abs=0.01)


def test_wmm_field_gives_a_valid_true_north_E_and_rejects_other_epochs():
    f = wmm2025(32.28, -106.75, date(2026, 3, 1))  # Las Cruces, NM
    e = f.directions
    np.testing.assert_allclose(e[:, 0], [0, 0, 1])
    np.testing.assert_allclose(e[:, 1], f.enu / f.total_nT)
    assert 55 < f.inclination_deg < 65 and 5 < f.declination_deg < 10
    EstimatorParams(E=e)  # the paper's W accepts it
    assert decimal_year(date(2025, 7, 2)) == pytest.approx(2025.5, abs=0.002)
    with pytest.raises(ConfigError, match="2030"):
        wmm2025(0.0, 0.0, 2031.0)
    with pytest.raises(ConfigError, match="place"):
        wmm2025(95.0, 0.0, 2026.0)


def test_directions_from_dip_is_the_paper_E_for_the_papers_field():
    paper = EstimatorParams.paper().E
    dip = np.degrees(np.arcsin(-paper[2, 1]))
    decl = np.degrees(np.arctan2(paper[0, 1], paper[1, 1]))
    np.testing.assert_allclose(directions_from_dip(dip, decl), paper, atol=1e-4)


def still_then_turning(seconds: float = 6.0, dip_deg: float = 60.0, seed: int = 0):
    def rate(t: float) -> np.ndarray:
        return np.zeros(3) if t < 2.0 else np.array([0.4, -0.3, 0.8]) * np.sin(t)

    traj = Trajectory.from_rate(rate, seconds, R0=so3.exp([0.2, -0.5, 1.0]), dt=2e-3)
    field = 48.0 * directions_from_dip(dip_deg, 3.0)[:, 1]
    spec = PhoneSpec(
        SensorSpec(200.0, 1e-3, 0.0),
        SensorSpec(200.0, 0.02, 0.0),
        SensorSpec(50.0, 0.3, 0.0),
        9.81,
        tuple(field),
    )
    return simulate(traj, spec, seed=seed)


def test_still_window_is_found_and_gives_the_dip():
    log = still_then_turning()
    w = find_still_window(log)
    assert w.t0 < 0.5 and w.t1 <= 2.0
    assert w.inclination_deg == pytest.approx(60.0, abs=0.5)
    assert w.field_uT == pytest.approx(48.0, abs=0.5) and w.gravity == pytest.approx(9.81, abs=0.05)
    e = directions_from_still(w)
    np.testing.assert_allclose(e[:, 1], directions_from_dip(60.0)[:, 1], atol=0.01)  # magnetic north
    assert "still window" in directions_from_log(log)[1]


def test_a_log_without_rest_falls_back_to_the_attitude_free_median_dip():
    log = still_then_turning().window(2.5, 6.0)
    with pytest.raises(InputFormatError, match="no still window"):
        find_still_window(log)
    assert median_inclination_deg(log) == pytest.approx(60.0, abs=1.0)
    e, how = directions_from_log(log)
    assert "median" in how and e[2, 1] == pytest.approx(-np.sin(np.radians(60.0)), abs=0.02)


@pytest.mark.parametrize("mag_t", [[-1.0], [-2.0, -1.5, -0.5]])
def test_a_magnetometer_with_no_reading_in_the_window_is_said_so_not_zero(mag_t):
    """A magnetometer whose readings all lie outside the first 10 s the dip is measured over (one stamped
    before the other sensors started): the error said "each is zero or not a number"
    of readings that were neither. It says the window holds none; a window of zero readings still says
    zero."""
    from hil.estimation.inertial import median_inclination_deg
    from hil.estimation.sensors import SensorKind, SensorLog, SensorStream

    t = np.arange(0.0, 30.0, 0.01)
    acc = SensorStream(SensorKind.ACC, t, np.tile([0.0, 0.0, 9.81], (len(t), 1)))
    gyr = SensorStream(SensorKind.GYR, t, np.zeros((len(t), 3)))
    mag_times = np.asarray(mag_t)
    mag = SensorStream(SensorKind.MAG, mag_times, np.tile([0.0, 20.0, -40.0], (len(mag_times), 1)))
    log = SensorLog({SensorKind.ACC: acc, SensorKind.GYR: gyr, SensorKind.MAG: mag}, "log.csv", "csv")
    with pytest.raises(InputFormatError, match="it has none there") as caught:
        median_inclination_deg(log)
    assert "each is zero" not in str(caught.value)
    zeros = SensorStream(SensorKind.MAG, t, np.zeros((len(t), 3)))
    with pytest.raises(InputFormatError, match="each is zero or not a number"):
        median_inclination_deg(SensorLog({**log.streams, SensorKind.MAG: zeros}, "log.csv", "csv"))


@pytest.mark.parametrize(("n_acc", "n_mag", "names"), [(1, 50, "accelerometer"), (50, 3, "magnetometer")])
def test_too_few_samples_for_the_median_dip_names_the_sensor_short_of_them(n_acc, n_mag, names):
    """One accelerometer reading beside plenty of magnetometer ones was said "too few magnetometer
    samples": the error names the sensor that is short, and how many it has."""
    from hil.estimation.inertial import median_inclination_deg
    from hil.estimation.sensors import SensorKind, SensorLog, SensorStream

    def stream(kind, n, xyz):
        t = np.arange(n) * 0.05
        return SensorStream(kind, t, np.tile(xyz, (n, 1)))

    log = SensorLog(
        {
            SensorKind.ACC: stream(SensorKind.ACC, n_acc, [0.0, 0.0, 9.81]),
            SensorKind.GYR: stream(SensorKind.GYR, 50, [0.0, 0.0, 0.0]),
            SensorKind.MAG: stream(SensorKind.MAG, n_mag, [0.0, 20.0, -40.0]),
        },
        "log.csv",
        "csv",
    )
    with pytest.raises(InputFormatError, match=f"too few {names} samples") as caught:
        median_inclination_deg(log)
    assert f"({min(n_acc, n_mag)}, at least" in str(caught.value)
