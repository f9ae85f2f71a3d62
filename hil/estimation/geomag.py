"""Main geomagnetic field models: the field's direction at a place and time, for the inertial directions.

- :func:`igrf14` — the International Geomagnetic Reference Field, 14th generation (IAGA, December 2024):
  definitive/main-field models every 5 years from 1900 to 2025 and the secular variation to 2030, degree
  10 to 1995 and 13 from 2000. Any recording date from 1900.0 to 2030.0; between epochs the coefficients
  are interpolated linearly, as IGRF prescribes. Coefficients in :mod:`hil.estimation.igrf14_coefficients`
  (generated from IAGA's ``IGRF14.shc`` by ``tools/igrf14_coefficients.py``).
- :func:`wmm2025` — the World Magnetic Model 2025 (NOAA/BGS, degree 12, 2025.0–2030.0, coefficients from
  NOAA's ``WMM.COF`` of 2024-11-13, public domain).

Both are checked against published values (tests/test_estimator_inertial.py). Geodetic latitude and
height above the WGS-84 ellipsoid in, the field in the local geodetic north/east/down frame out. Pure
math, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import date, datetime

import numpy as np
from numpy.typing import NDArray

from hil.estimation import igrf14_coefficients as igrf
from hil.estimation.params import directions_matrix
from protocol.errors import ConfigError

Array = NDArray[np.float64]
UP = np.array([0.0, 0.0, 1.0])


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
        return directions_matrix(UP, self.enu)


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
IGRF_FIRST, IGRF_LAST = igrf.EPOCHS[0], igrf.EPOCHS[-1]
_A_KM = 6378.137  # WGS-84 semi-major axis
_F = 1.0 / 298.257223563  # WGS-84 flattening
_RE_KM = 6371.2  # geomagnetic reference radius


def _wmm_coefficients() -> tuple[Array, Array, Array, Array]:
    g, h, gd, hd = (np.zeros((13, 13)) for _ in range(4))
    for row in _WMM2025.replace("\n", "|").split("|"):
        if row.strip():
            n, m, *vals = row.split()
            g[int(n), int(m)], h[int(n), int(m)], gd[int(n), int(m)], hd[int(n), int(m)] = map(float, vals)
    return g, h, gd, hd


def _igrf_coefficients() -> tuple[Array, Array]:
    """g and h, shape (epochs, n_max + 1, n_max + 1), nT."""
    n_ep = len(igrf.EPOCHS)
    g = np.zeros((n_ep, igrf.N_MAX + 1, igrf.N_MAX + 1))
    h = np.zeros_like(g)
    for row in igrf.TABLE.strip().splitlines():
        n, m, *vals = row.split()
        target = g if int(m) >= 0 else h
        target[:, int(n), abs(int(m))] = [float(v) for v in vals]
    return g, h


_WMM = _wmm_coefficients()
_IGRF = _igrf_coefficients()


def decimal_year(when: date | datetime | float) -> float:
    """``2025.5``-style year of a date (UTC midnight) or datetime; a float passes through."""
    if isinstance(when, int | float):
        return float(when)
    if not isinstance(when, datetime):
        when = datetime(when.year, when.month, when.day)
    start = datetime(when.year, 1, 1, tzinfo=when.tzinfo)
    end = datetime(when.year + 1, 1, 1, tzinfo=when.tzinfo)
    return when.year + (when - start).total_seconds() / (end - start).total_seconds()


def _check_place(lat_deg: float, lon_deg: float, height_km: float) -> None:
    if not (-90.0 <= lat_deg <= 90.0 and math.isfinite(lon_deg) and -10.0 < height_km < 1000.0):
        place = f"latitude {lat_deg!r}, longitude {lon_deg!r}, height {height_km!r} km"
        raise ConfigError(f"not a place on Earth: {place}", "field model")


def wmm2025(
    lat_deg: float, lon_deg: float, when: date | datetime | float, height_km: float = 0.0
) -> GeomagneticField:
    """The WMM2025 main field at geodetic latitude/longitude (degrees, WGS-84), height above the ellipsoid
    (km) and date. Outside 2025.0–2030.0 the model does not apply: ConfigError."""
    year = decimal_year(when)
    if not (WMM_EPOCH <= year < WMM_VALID_UNTIL):
        raise ConfigError(f"WMM2025 is valid for 2025.0 <= year < 2030.0, got {year:.3f}", "field model date")
    _check_place(lat_deg, lon_deg, height_km)
    g0, h0, gd, hd = _WMM
    dt = year - WMM_EPOCH
    return _synthesis(g0 + dt * gd, h0 + dt * hd, lat_deg, lon_deg, height_km)


def igrf14(
    lat_deg: float, lon_deg: float, when: date | datetime | float, height_km: float = 0.0
) -> GeomagneticField:
    """The IGRF-14 main field at geodetic latitude/longitude (degrees, WGS-84), height above the ellipsoid
    (km) and date (1900.0–2030.0, else ConfigError)."""
    year = decimal_year(when)
    if not (IGRF_FIRST <= year <= IGRF_LAST):
        raise ConfigError(
            f"IGRF-14 covers {IGRF_FIRST:g} <= year <= {IGRF_LAST:g}, got {year:.3f}", "field model date"
        )
    _check_place(lat_deg, lon_deg, height_km)
    epochs = igrf.EPOCHS
    i = min(int((year - epochs[0]) // 5.0), len(epochs) - 2)
    w = (year - epochs[i]) / (epochs[i + 1] - epochs[i])
    g_all, h_all = _IGRF
    g = (1.0 - w) * g_all[i] + w * g_all[i + 1]
    h = (1.0 - w) * h_all[i] + w * h_all[i + 1]
    return _synthesis(g, h, lat_deg, lon_deg, height_km)


def _synthesis(g: Array, h: Array, lat_deg: float, lon_deg: float, height_km: float) -> GeomagneticField:
    """The field of Gauss coefficients ``g``, ``h`` (nT, (N+1, N+1)) at a geodetic place."""
    degree = g.shape[0] - 1
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    e2 = _F * (2.0 - _F)
    rc = _A_KM / math.sqrt(1.0 - e2 * math.sin(lat) ** 2)
    xp = (rc + height_km) * math.cos(lat)
    zp = (rc * (1.0 - e2) + height_km) * math.sin(lat)
    r = math.hypot(xp, zp)
    lat_c = math.asin(zp / r)
    sin_c, cos_c = math.sin(lat_c), math.cos(lat_c)
    p, dp = _schmidt_legendre(sin_c, cos_c, degree)
    p_over_cos = _legendre_over_cos(p, dp, sin_c, cos_c)
    bx = by = bz = 0.0  # geocentric north, east, down
    for n in range(1, degree + 1):
        scale = (_RE_KM / r) ** (n + 2)
        for m in range(n + 1):
            cm, sm = math.cos(m * lon), math.sin(m * lon)
            along = g[n, m] * cm + h[n, m] * sm
            bx -= scale * along * dp[n, m]
            by += scale * m * (g[n, m] * sm - h[n, m] * cm) * p_over_cos[n, m]
            bz -= scale * (n + 1) * along * p[n, m]
    tilt = lat_c - lat  # geocentric → geodetic (ellipsoidal) frame
    north = bx * math.cos(tilt) - bz * math.sin(tilt)
    down = bx * math.sin(tilt) + bz * math.cos(tilt)
    return GeomagneticField(north, by, down)


POLE_COS = 1e-8
"""Below this cosine of the geocentric latitude (within ~6 cm of a geographic pole) the east component's
``P_n^m / cos φ`` is taken as its limit at the pole, ``−(dP_n^m/dφ) / sin φ`` (every ``P_n^m`` with m ≥ 1
has a factor ``cos^m φ``; the limit's relative error there is ~cos² φ, 1e-16). Dividing by the cosine
itself, clamped, lost the east component at ``--lat 90``: the field at the pole came out up to 30° of
declination and 2.4° of inclination from the field a step away."""


def _legendre_over_cos(p: Array, dp: Array, sin_c: float, cos_c: float) -> Array:
    """``P_n^m(sin φ) / cos φ`` for the east component (m ≥ 1; the m = 0 column, which that component
    multiplies by m = 0, is left 0): divided where the cosine is not tiny, its limit at a pole (see
    :data:`POLE_COS`)."""
    out = np.zeros_like(p)
    if cos_c >= POLE_COS:
        out[:, 1:] = p[:, 1:] / cos_c
    else:
        out[:, 1:] = -dp[:, 1:] / sin_c
    return out


def _schmidt_legendre(x: float, c: float, degree: int) -> tuple[Array, Array]:
    """Schmidt semi-normalised associated Legendre functions P_n^m(sin φ) and dP/dφ, n ≤ ``degree``."""
    p = np.zeros((degree + 1, degree + 1))
    dp = np.zeros_like(p)
    p[0, 0] = 1.0
    for n in range(1, degree + 1):
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
