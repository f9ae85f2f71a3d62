"""Inertial reference directions ``E = [e1 e2 e1×e2]`` for the estimator, in the paper's ENU frame
(x east, y north, z up). Three sources:

1. **Given** — e.g. the paper's E (``hil.estimation.params.PAPER_E``), or any field vector through
   :func:`directions_from_field`.
2. **A local field model** — :func:`wmm2025`: the World Magnetic Model 2025 (NOAA/BGS, degree and order
   12, epoch 2025.0, valid 2025.0–2030.0, coefficients from NOAA's ``WMM.COF`` of 2024-11-13, public
   domain) evaluated at a user's latitude, longitude, height and date; E is then in *true-north* ENU.
   Checked against NOAA's published test values.
3. **An initial still window of a log** — :func:`find_still_window` then :func:`directions_from_still`:
   gravity gives "up"; the angle between the mean accelerometer and magnetometer readings gives the field's
   inclination (dip). Heading cannot be observed from the phone alone, so this E is in *magnetic-north*
   ENU (y along the field's horizontal part, declination 0); add a declination (e.g. from :func:`wmm2025`)
   to get true north.

``e1`` is always up: an accelerometer at rest measures the specific force, +g along the upward vertical.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import date, datetime

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation.params import directions_matrix
from hil.estimation.sensors import SensorKind, SensorLog
from protocol.errors import ConfigError, InputFormatError

Array = NDArray[np.float64]
UP = np.array([0.0, 0.0, 1.0])


def directions_from_field(field_enu: ArrayLike) -> Array:
    """E (3, 3) for the geomagnetic field vector ``field_enu`` (any unit) in ENU, e1 = up."""
    return directions_matrix(UP, field_enu)


def directions_from_dip(inclination_deg: float, declination_deg: float = 0.0) -> Array:
    """E for a field of inclination ``I`` (positive downward, degrees) and declination ``D`` (degrees east
    of north): ``e2 = (cos I sin D, cos I cos D, −sin I)``."""
    i, d = math.radians(inclination_deg), math.radians(declination_deg)
    return directions_from_field([math.cos(i) * math.sin(d), math.cos(i) * math.cos(d), -math.sin(i)])


# --------------------------------------------------------------------------- WMM2025
@dataclass(frozen=True)
class GeomagneticField:
    """The main field at a place and time: north/east/down components (nT), declination (degrees east of
    true north), inclination (degrees, positive downward) and total intensity (nT)."""

    north_nT: float
    east_nT: float
    down_nT: float

    @property
    def declination_deg(self) -> float:
        return math.degrees(math.atan2(self.east_nT, self.north_nT))

    @property
    def inclination_deg(self) -> float:
        return math.degrees(math.atan2(self.down_nT, math.hypot(self.north_nT, self.east_nT)))

    @property
    def total_nT(self) -> float:
        return math.sqrt(self.north_nT**2 + self.east_nT**2 + self.down_nT**2)

    @property
    def enu(self) -> Array:
        """The field in ENU (nT): (east, north, up)."""
        return np.array([self.east_nT, self.north_nT, -self.down_nT])

    @property
    def directions(self) -> Array:
        """E in true-north ENU."""
        return directions_from_field(self.enu)


# n, m, g (nT), h (nT), dg/dt (nT/yr), dh/dt (nT/yr): NOAA WMM.COF, WMM-2025, released 2024-11-13
_WMM2025 = """
1 0 -29351.8 0.0 12.0 0.0|1 1 -1410.8 4545.4 9.7 -21.5|2 0 -2556.6 0.0 -11.6 0.0|2 1 2951.1 -3133.6 -5.2 -27.7
2 2 1649.3 -815.1 -8.0 -12.1|3 0 1361.0 0.0 -1.3 0.0|3 1 -2404.1 -56.6 -4.2 4.0|3 2 1243.8 237.5 0.4 -0.3
3 3 453.6 -549.5 -15.6 -4.1|4 0 895.0 0.0 -1.6 0.0|4 1 799.5 278.6 -2.4 -1.1|4 2 55.7 -133.9 -6.0 4.1
4 3 -281.1 212.0 5.6 1.6|4 4 12.1 -375.6 -7.0 -4.4|5 0 -233.2 0.0 0.6 0.0|5 1 368.9 45.4 1.4 -0.5
5 2 187.2 220.2 0.0 2.2|5 3 -138.7 -122.9 0.6 0.4|5 4 -142.0 43.0 2.2 1.7|5 5 20.9 106.1 0.9 1.9
6 0 64.4 0.0 -0.2 0.0|6 1 63.8 -18.4 -0.4 0.3|6 2 76.9 16.8 0.9 -1.6|6 3 -115.7 48.8 1.2 -0.4
6 4 -40.9 -59.8 -0.9 0.9|6 5 14.9 10.9 0.3 0.7|6 6 -60.7 72.7 0.9 0.9|7 0 79.5 0.0 -0.0 0.0
7 1 -77.0 -48.9 -0.1 0.6|7 2 -8.8 -14.4 -0.1 0.5|7 3 59.3 -1.0 0.5 -0.8|7 4 15.8 23.4 -0.1 0.0
7 5 2.5 -7.4 -0.8 -1.0|7 6 -11.1 -25.1 -0.8 0.6|7 7 14.2 -2.3 0.8 -0.2|8 0 23.2 0.0 -0.1 0.0
8 1 10.8 7.1 0.2 -0.2|8 2 -17.5 -12.6 0.0 0.5|8 3 2.0 11.4 0.5 -0.4|8 4 -21.7 -9.7 -0.1 0.4
8 5 16.9 12.7 0.3 -0.5|8 6 15.0 0.7 0.2 -0.6|8 7 -16.8 -5.2 -0.0 0.3|8 8 0.9 3.9 0.2 0.2
9 0 4.6 0.0 -0.0 0.0|9 1 7.8 -24.8 -0.1 -0.3|9 2 3.0 12.2 0.1 0.3|9 3 -0.2 8.3 0.3 -0.3
9 4 -2.5 -3.3 -0.3 0.3|9 5 -13.1 -5.2 0.0 0.2|9 6 2.4 7.2 0.3 -0.1|9 7 8.6 -0.6 -0.1 -0.2
9 8 -8.7 0.8 0.1 0.4|9 9 -12.9 10.0 -0.1 0.1|10 0 -1.3 0.0 0.1 0.0|10 1 -6.4 3.3 0.0 0.0
10 2 0.2 0.0 0.1 -0.0|10 3 2.0 2.4 0.1 -0.2|10 4 -1.0 5.3 -0.0 0.1|10 5 -0.6 -9.1 -0.3 -0.1
10 6 -0.9 0.4 0.0 0.1|10 7 1.5 -4.2 -0.1 0.0|10 8 0.9 -3.8 -0.1 -0.1|10 9 -2.7 0.9 -0.0 0.2
10 10 -3.9 -9.1 -0.0 -0.0|11 0 2.9 0.0 0.0 0.0|11 1 -1.5 0.0 -0.0 -0.0|11 2 -2.5 2.9 0.0 0.1
11 3 2.4 -0.6 0.0 -0.0|11 4 -0.6 0.2 0.0 0.1|11 5 -0.1 0.5 -0.1 -0.0|11 6 -0.6 -0.3 0.0 -0.0
11 7 -0.1 -1.2 -0.0 0.1|11 8 1.1 -1.7 -0.1 -0.0|11 9 -1.0 -2.9 -0.1 0.0|11 10 -0.2 -1.8 -0.1 0.0
11 11 2.6 -2.3 -0.1 0.0|12 0 -2.0 0.0 0.0 0.0|12 1 -0.2 -1.3 0.0 -0.0|12 2 0.3 0.7 -0.0 0.0
12 3 1.2 1.0 -0.0 -0.1|12 4 -1.3 -1.4 -0.0 0.1|12 5 0.6 -0.0 -0.0 -0.0|12 6 0.6 0.6 0.1 -0.0
12 7 0.5 -0.1 -0.0 -0.0|12 8 -0.1 0.8 0.0 0.0|12 9 -0.4 0.1 0.0 -0.0|12 10 -0.2 -1.0 -0.1 -0.0
12 11 -1.3 0.1 -0.0 0.0|12 12 -0.7 0.2 -0.1 -0.1
"""
WMM_EPOCH = 2025.0
WMM_VALID_UNTIL = 2030.0
_DEGREE = 12
_A_KM = 6378.137  # WGS-84 semi-major axis
_F = 1.0 / 298.257223563  # WGS-84 flattening
_RE_KM = 6371.2  # geomagnetic reference radius


def _coefficients() -> tuple[Array, Array, Array, Array]:
    g, h, gd, hd = (np.zeros((_DEGREE + 1, _DEGREE + 1)) for _ in range(4))
    for row in _WMM2025.replace("\n", "|").split("|"):
        if row.strip():
            n, m, *vals = row.split()
            g[int(n), int(m)], h[int(n), int(m)], gd[int(n), int(m)], hd[int(n), int(m)] = map(float, vals)
    return g, h, gd, hd


_G, _H, _GD, _HD = _coefficients()


def decimal_year(when: date | datetime | float) -> float:
    """``2025.5``-style year of a date (UTC midnight) or datetime; a float passes through."""
    if isinstance(when, int | float):
        return float(when)
    if not isinstance(when, datetime):
        when = datetime(when.year, when.month, when.day)
    start = datetime(when.year, 1, 1, tzinfo=when.tzinfo)
    end = datetime(when.year + 1, 1, 1, tzinfo=when.tzinfo)
    return when.year + (when - start).total_seconds() / (end - start).total_seconds()


def wmm2025(
    lat_deg: float, lon_deg: float, when: date | datetime | float, height_km: float = 0.0
) -> GeomagneticField:
    """The WMM2025 main field at geodetic latitude/longitude (degrees, WGS-84), height above the ellipsoid
    (km) and date. Outside 2025.0–2030.0 the model does not apply: ConfigError."""
    year = decimal_year(when)
    if not (WMM_EPOCH <= year < WMM_VALID_UNTIL):
        raise ConfigError(f"WMM2025 is valid for 2025.0 <= year < 2030.0, got {year:.3f}", "field model date")
    if not (-90.0 <= lat_deg <= 90.0 and math.isfinite(lon_deg) and math.isfinite(height_km)):
        place = f"latitude {lat_deg!r}, longitude {lon_deg!r}, height {height_km!r} km"
        raise ConfigError(f"not a place on Earth: {place}", "field model")
    dt = year - WMM_EPOCH
    g, h = _G + dt * _GD, _H + dt * _HD
    # geodetic → geocentric spherical
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    e2 = _F * (2.0 - _F)
    rc = _A_KM / math.sqrt(1.0 - e2 * math.sin(lat) ** 2)
    xp = (rc + height_km) * math.cos(lat)
    zp = (rc * (1.0 - e2) + height_km) * math.sin(lat)
    r = math.hypot(xp, zp)
    lat_c = math.asin(zp / r)
    p, dp = _schmidt_legendre(math.sin(lat_c), math.cos(lat_c))
    cos_c = max(math.cos(lat_c), 1e-12)  # the east component's 1/cos is finite at the pole limit
    bx = by = bz = 0.0  # geocentric north, east, down
    for n in range(1, _DEGREE + 1):
        scale = (_RE_KM / r) ** (n + 2)
        for m in range(n + 1):
            cm, sm = math.cos(m * lon), math.sin(m * lon)
            along = g[n, m] * cm + h[n, m] * sm
            bx -= scale * along * dp[n, m]
            by += scale * m * (g[n, m] * sm - h[n, m] * cm) * p[n, m] / cos_c
            bz -= scale * (n + 1) * along * p[n, m]
    tilt = lat_c - lat  # geocentric → geodetic (ellipsoidal) frame
    north = bx * math.cos(tilt) - bz * math.sin(tilt)
    down = bx * math.sin(tilt) + bz * math.cos(tilt)
    return GeomagneticField(north, by, down)


def _schmidt_legendre(x: float, c: float) -> tuple[Array, Array]:
    """Schmidt semi-normalised associated Legendre functions P_n^m(sin φ) and dP/dφ, n ≤ 12."""
    p = np.zeros((_DEGREE + 1, _DEGREE + 1))
    dp = np.zeros_like(p)
    p[0, 0] = 1.0
    for n in range(1, _DEGREE + 1):
        for m in range(n + 1):
            if n == m:
                k = math.sqrt(1.0 - 1.0 / (2 * n)) if n > 1 else 1.0
                p[n, n] = k * c * p[n - 1, n - 1]
                dp[n, n] = k * (c * dp[n - 1, n - 1] - x * p[n - 1, n - 1])
            else:
                a = math.sqrt((n - m) * (n + m))
                b = (2 * n - 1) / a
                d = math.sqrt((n - m - 1) * (n + m - 1)) / a if n - 2 >= m else 0.0
                p2 = p[n - 2, m] if n - 2 >= m else 0.0
                dp2 = dp[n - 2, m] if n - 2 >= m else 0.0
                p[n, m] = b * x * p[n - 1, m] - d * p2
                dp[n, m] = b * (x * dp[n - 1, m] + c * p[n - 1, m]) - d * dp2
    return p, dp


# --------------------------------------------------------------------------- still window
@dataclass(frozen=True)
class StillWindow:
    """A stretch of a log where the phone lay still: ``[t0, t1]`` s, mean accelerometer (m/s²) and
    magnetometer (µT) readings in the body frame, and what they imply."""

    t0: float
    t1: float
    acc: Array
    mag: Array

    @property
    def inclination_deg(self) -> float:
        """Field inclination (positive downward): the angle between the field and the horizontal plane."""
        ua, um = self.acc / np.linalg.norm(self.acc), self.mag / np.linalg.norm(self.mag)
        return math.degrees(math.asin(float(np.clip(-ua @ um, -1.0, 1.0))))

    @property
    def field_uT(self) -> float:
        return float(np.linalg.norm(self.mag))

    @property
    def gravity(self) -> float:
        return float(np.linalg.norm(self.acc))


def find_still_window(
    log: SensorLog,
    duration_s: float = 1.0,
    search_s: float = 30.0,
    max_rate: float = 0.05,
    max_acc_std: float = 0.15,
) -> StillWindow:
    """The first window of ``duration_s`` within ``search_s`` of the log's start in which the phone is still.

    Still means: every gyroscope sample below ``max_rate`` rad/s in norm, the accelerometer's norm varying
    by at most ``max_acc_std`` m/s² (standard deviation) around a value within 1 m/s² of 9.81, and at
    least a few samples of each sensor. Raises InputFormatError (naming the log) if there is none.
    """
    gyr, acc, mag = (log.streams[k] for k in (SensorKind.GYR, SensorKind.ACC, SensorKind.MAG))
    t_start = log.start
    acc_norm = np.linalg.norm(acc.xyz, axis=1)
    gyr_norm = np.linalg.norm(gyr.xyz, axis=1)
    for t0 in np.arange(t_start, t_start + search_s - duration_s + 1e-9, duration_s / 4):
        t1 = t0 + duration_s
        g = (gyr.t >= t0) & (gyr.t <= t1)
        a = (acc.t >= t0) & (acc.t <= t1)
        m = (mag.t >= t0) & (mag.t <= t1)
        if min(g.sum(), a.sum(), m.sum()) < 5:
            continue
        if (
            np.all(gyr_norm[g] < max_rate)
            and np.std(acc_norm[a]) <= max_acc_std
            and abs(np.mean(acc_norm[a]) - 9.81) < 1.0
            and np.all(np.isfinite(mag.xyz[m]))
        ):
            return StillWindow(float(t0), float(t1), acc.xyz[a].mean(axis=0), mag.xyz[m].mean(axis=0))
    raise InputFormatError(
        f"no still window of {duration_s:g} s (gyro < {max_rate:g} rad/s, |acc| std <= {max_acc_std:g} m/s²) "
        f"in the first {search_s:g} s",
        log.source,
    )


def directions_from_still(window: StillWindow, declination_deg: float = 0.0) -> Array:
    """E from a still window: magnetic-north ENU unless a declination is given (see module docstring)."""
    return directions_from_dip(window.inclination_deg, declination_deg)


def median_inclination_deg(log: SensorLog, window_s: float = 10.0) -> float:
    """The field inclination from the first ``window_s`` of a log, moving or not: the angle between the
    accelerometer and magnetometer readings does not depend on the attitude, so its median over the window
    (acceleration and disturbances are outliers) estimates the dip. Samples are paired by nearest time."""
    acc, mag = log.streams[SensorKind.ACC], log.streams[SensorKind.MAG]
    sel = (mag.t >= log.start) & (mag.t <= log.start + window_s) & np.all(np.isfinite(mag.xyz), axis=1)
    if sel.sum() < 5 or len(acc) < 2:
        raise InputFormatError(f"too few magnetometer samples in the first {window_s:g} s", log.source)
    idx = np.clip(np.searchsorted(acc.t, mag.t[sel]), 0, len(acc) - 1)
    a, m = acc.xyz[idx], mag.xyz[sel]
    dots = np.sum(a * m, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(m, axis=1))
    dots = dots[np.isfinite(dots)]
    if dots.size < 5:
        raise InputFormatError(
            f"no finite accelerometer/magnetometer pairs in the first {window_s:g} s", log.source
        )
    return math.degrees(math.asin(float(np.clip(-np.median(dots), -1.0, 1.0))))


def directions_from_log(log: SensorLog, window_s: float = 10.0) -> tuple[Array, str]:
    """E in magnetic-north ENU measured from the log itself: from its initial still window if it has one,
    else from the median inclination over its first ``window_s``. Returns ``(E, how)``."""
    try:
        still = find_still_window(log, search_s=window_s)
    except InputFormatError:
        dip = median_inclination_deg(log, window_s)
        return directions_from_dip(dip), f"inclination {dip:.1f} deg (median over the first {window_s:g} s)"
    return directions_from_still(still), (
        f"inclination {still.inclination_deg:.1f} deg (still window {still.t0:.2f}-{still.t1:.2f} s)"
    )
