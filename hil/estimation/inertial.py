"""Inertial reference directions ``E = [e1 e2 e1×e2]`` for the estimator, in the paper's ENU frame
(x east, y north, z up). Three sources:

1. **Given** — e.g. the paper's E (``hil.estimation.params.PAPER_E``), or any field vector through
   :func:`directions_from_field`.
2. **A local field model** — :mod:`hil.estimation.geomag`: IGRF-14 (any date 1900–2030, :func:`igrf14`)
   or WMM2025 (:func:`wmm2025`) at a user's latitude, longitude, height and date; E is then in
   *true-north* ENU.
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

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.estimation.geomag import GeomagneticField, decimal_year, igrf14, wmm2025
from hil.estimation.params import directions_matrix
from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from protocol.errors import ConfigError, InputFormatError

Array = NDArray[np.float64]
UP = np.array([0.0, 0.0, 1.0])
__all__ = ["GeomagneticField", "decimal_year", "igrf14", "wmm2025"]  # the field models, for callers here


def directions_from_field(field_enu: ArrayLike) -> Array:
    """E (3, 3) for the geomagnetic field vector ``field_enu`` (any unit) in ENU, e1 = up."""
    return directions_matrix(UP, field_enu)


def directions_from_dip(inclination_deg: float, declination_deg: float = 0.0) -> Array:
    """E for a field of inclination ``I`` (positive downward, degrees) and declination ``D`` (degrees east
    of north): ``e2 = (cos I sin D, cos I cos D, −sin I)``."""
    i, d = math.radians(inclination_deg), math.radians(declination_deg)
    return directions_from_field([math.cos(i) * math.sin(d), math.cos(i) * math.cos(d), -math.sin(i)])


# --------------------------------------------------------------------------- still window
@dataclass(frozen=True)
class StillWindow:
    """A stretch of a log where the phone lay still: ``[t0, t1]`` s, mean accelerometer (m/s²) and
    magnetometer (µT) readings in the body frame, and what they imply."""

    t0: float
    t1: float
    acc: Array
    mag: Array | None  # None for a 6-axis log

    @property
    def inclination_deg(self) -> float:
        """Field inclination (positive downward): the angle between the field and the horizontal plane."""
        if self.mag is None:
            raise InputFormatError("no magnetometer: the field's inclination is not observed", "still window")
        ua, um = self.acc / np.linalg.norm(self.acc), self.mag / np.linalg.norm(self.mag)
        return math.degrees(math.asin(float(np.clip(-ua @ um, -1.0, 1.0))))

    @property
    def field_uT(self) -> float:
        return float(np.linalg.norm(self.mag)) if self.mag is not None else math.nan

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
    least a few samples of each sensor. Accelerometer and magnetometer readings that are zero or not finite
    (a sensor not yet started writes 0, 0, 0) are no readings here: skipped, and a window needs a few
    others — their mean would be no direction (the field's inclination NaN). Raises InputFormatError
    (naming the log) if there is none, naming the sensor when it has no usable reading in the span
    searched. A 6-axis log's window has no magnetometer mean (``mag`` None).
    """
    t_start = log.start
    end = t_start + search_s + 1e-6  # no window reaches past this: only the samples before it are searched

    def head(stream: SensorStream) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        keep = stream.t <= end
        return stream.t[keep], stream.xyz[keep]

    (gyr_t, gyr_xyz), (acc_t, acc_xyz) = head(log.streams[SensorKind.GYR]), head(log.streams[SensorKind.ACC])
    mag_stream = log.streams.get(SensorKind.MAG)
    mag = None if mag_stream is None else head(mag_stream)
    acc_ok = gives_direction(acc_xyz)
    mag_ok = None if mag is None else gives_direction(mag[1])
    _require_some(acc_ok, "accelerometer", search_s, log.source)
    if mag_ok is not None:
        _require_some(mag_ok, "magnetometer", search_s, log.source)
    acc_norm = np.linalg.norm(acc_xyz, axis=1)
    gyr_norm = np.linalg.norm(gyr_xyz, axis=1)
    for t0 in np.arange(t_start, t_start + search_s - duration_s + 1e-9, duration_s / 4):
        t1 = t0 + duration_s
        g = (gyr_t >= t0) & (gyr_t <= t1)
        a = (acc_t >= t0) & (acc_t <= t1) & acc_ok
        m = (mag[0] >= t0) & (mag[0] <= t1) & mag_ok if mag is not None and mag_ok is not None else None
        if min(g.sum(), a.sum(), 5 if m is None else m.sum()) < 5:
            continue
        if (
            np.all(gyr_norm[g] < max_rate)
            and np.std(acc_norm[a]) <= max_acc_std
            and abs(np.mean(acc_norm[a]) - 9.81) < 1.0
        ):
            mag_mean = None if mag is None else mag[1][m].mean(axis=0)
            return StillWindow(float(t0), float(t1), acc_xyz[a].mean(axis=0), mag_mean)
    raise InputFormatError(
        f"no still window of {duration_s:g} s (gyro < {max_rate:g} rad/s, |acc| std <= {max_acc_std:g} m/s²) "
        f"in the first {search_s:g} s",
        log.source,
    )


def gives_direction(xyz: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which readings (N, 3) give a direction: finite and not zero."""
    return np.all(np.isfinite(xyz), axis=1) & np.any(xyz != 0.0, axis=1)


def _require_some(
    ok: NDArray[np.bool_],
    sensor: str,
    window_s: float,
    source: str,
    early: NDArray[np.bool_] | None = None,
) -> None:
    """An InputFormatError naming ``sensor`` when none of its readings in the window (``early``; None: all
    of them) gives a direction (``ok``): said as none there at all when the window holds none (a
    magnetometer's one reading, stamped before the other sensors started, was said "each is zero or not a
    number")."""
    inside = np.ones(len(ok), bool) if early is None else early
    if ok[inside].any():
        return
    why = (
        f"each is zero or not a number: the {sensor} not started, or its file broken"
        if inside.any()
        else "it has none there: its readings are all outside it"
    )
    raise InputFormatError(
        f"no {sensor} reading in the first {window_s:g} s gives a direction ({why}): the inertial directions "
        "cannot be measured; give --inclination or --lat/--lon/--date",
        source,
    )


def directions_from_still(window: StillWindow, declination_deg: float = 0.0) -> Array:
    """E from a still window: magnetic-north ENU unless a declination is given (see module docstring)."""
    return directions_from_dip(window.inclination_deg, declination_deg)


def median_inclination_deg(log: SensorLog, window_s: float = 10.0) -> float:
    """The field inclination from the first ``window_s`` of a log, moving or not: the angle between the
    accelerometer and magnetometer readings does not depend on the attitude, so its median over the window
    (acceleration and disturbances are outliers) estimates the dip. Samples are paired by nearest time."""
    acc, mag = log.streams[SensorKind.ACC], log.streams.get(SensorKind.MAG)
    if mag is None:
        raise InputFormatError("no magnetometer: the field's inclination is not observed", log.source)
    early = (mag.t >= log.start) & (mag.t <= log.start + window_s)
    _require_some(gives_direction(mag.xyz), "magnetometer", window_s, log.source, early)
    acc_early = acc.t <= log.start + window_s
    _require_some(gives_direction(acc.xyz), "accelerometer", window_s, log.source, acc_early)
    sel = early & gives_direction(mag.xyz)
    if sel.sum() < 5:
        raise InputFormatError(
            f"too few magnetometer samples in the first {window_s:g} s ({int(sel.sum())}, at least 5 needed)",
            log.source,
        )
    if len(acc) < 2:  # it was said of the magnetometer, whose samples were plenty
        raise InputFormatError(
            f"too few accelerometer samples ({len(acc)}, at least 2 needed) to pair with the magnetometer's",
            log.source,
        )
    idx = np.clip(np.searchsorted(acc.t, mag.t[sel]), 0, len(acc) - 1)
    a, m = acc.xyz[idx], mag.xyz[sel]
    pair = gives_direction(a)  # an accelerometer reading of zero beside it: no angle
    a, m = a[pair], m[pair]
    dots = np.sum(a * m, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(m, axis=1))
    dots = dots[np.isfinite(dots)]
    if dots.size < 5:
        raise InputFormatError(
            f"no finite accelerometer/magnetometer pairs in the first {window_s:g} s", log.source
        )
    return math.degrees(math.asin(float(np.clip(-np.median(dots), -1.0, 1.0))))


def directions_from_log(log: SensorLog, window_s: float = 10.0) -> tuple[Array, str]:
    """E in magnetic-north ENU measured from the log itself: from its initial still window if it has one,
    else from the median inclination over its first ``window_s``. Returns ``(E, how)``; a field measured
    vertical (parallel to gravity) is an InputFormatError naming the log (:func:`_measured_directions`)."""
    try:
        still = find_still_window(log, search_s=window_s)
    except InputFormatError:
        dip = median_inclination_deg(log, window_s)
        how = f"inclination {dip:.1f} deg (median over the first {window_s:g} s)"
    else:
        dip = still.inclination_deg
        how = f"inclination {dip:.1f} deg (still window {still.t0:.2f}-{still.t1:.2f} s)"
    return _measured_directions(dip, how, log.source), how


def _measured_directions(dip_deg: float, how: str, source: str) -> Array:
    """E for the inclination ``dip_deg`` measured from the log ``source`` (``how``: where from). A field
    within ~0.06° of vertical is parallel to gravity (:func:`~hil.estimation.params.directions_matrix`
    refuses it): the magnetometer then gives no heading — a magnet or steel under the phone, not the
    Earth's field, whose dip is below 89.94° everywhere farther than ~15 km from a dip pole. Refused as the
    log's fault, naming it and what to give instead (it was a ConfigError naming ``E``, an internal
    matrix, with the default preset too, which uses the field's horizontal part only)."""
    try:
        return directions_from_dip(dip_deg)
    except ConfigError as exc:
        raise InputFormatError(
            f"its magnetometer measures a vertical field ({how}), parallel to gravity: it gives no heading "
            "(a magnet or steel near the phone?); give the site's field instead (--lat/--lon/--date, or "
            "--inclination)",
            source,
        ) from exc


# --------------------------------------------------------------------------- 6-axis start, field checks
def tilt_attitude(log: SensorLog, window_s: float = 0.5) -> Array:
    """A body → ENU attitude (3, 3) from gravity alone, heading 0: the smallest rotation taking the mean
    accelerometer reading (the still window's, else the first ``window_s``'s) to "up". For a log without a
    magnetometer, whose heading is not observed."""
    acc = log.streams[SensorKind.ACC]
    try:
        a = find_still_window(log).acc
    except InputFormatError:
        start = float(np.min(acc.t[np.isfinite(acc.t)], initial=np.inf))  # a NaN first time is no start
        sel = (acc.t >= start) & (acc.t <= start + window_s) & np.all(np.isfinite(acc.xyz), axis=1)
        a = np.median(acc.xyz[sel], axis=0) if sel.any() else UP
    n = float(np.linalg.norm(a))
    if not (math.isfinite(n) and n > 0):
        return np.eye(3)
    u = a / n
    axis = np.cross(u, UP)
    s, c = float(np.linalg.norm(axis)), float(u @ UP)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3.exp(axis / s * math.atan2(s, c))


FIELD_DIP_TOL_DEG = 10.0
"""Inclination disagreement (deg) that is warned about: start vs rest of the log, log vs model."""
EARTH_FIELD_UT = (20.0, 70.0)
"""The geomagnetic field's strength at the surface, µT (about 22–67): outside it the magnetometer is
disturbed or not calibrated."""


def field_warnings(log: SensorLog, model: GeomagneticField | None = None, start_s: float = 10.0) -> list[str]:
    """What is wrong with the measured field, in words: its inclination (the angle between gravity and the
    field, which does not depend on the attitude) at the start against the rest of the log and against
    ``model``; its steadiness at the start; its strength. Empty when all is well or there is no
    magnetometer. The estimator's inertial directions come from the start (the still window), so a
    disturbed start gives a wrong inclination — this says so."""
    mag = log.streams.get(SensorKind.MAG)
    acc = log.streams[SensorKind.ACC]
    if mag is None or len(mag) < 10 or len(acc) < 2:
        return []
    ok = np.all(np.isfinite(mag.xyz), axis=1) & np.isfinite(mag.t)
    t, m = mag.t[ok], mag.xyz[ok]
    idx = np.clip(np.searchsorted(acc.t, t), 0, len(acc) - 1)
    a = acc.xyz[idx]
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.linalg.norm(m, axis=1)
        dots = np.sum(a * m, axis=1) / (np.linalg.norm(a, axis=1) * norm)
    dip = np.degrees(np.arcsin(np.clip(-dots, -1.0, 1.0)))
    good = np.isfinite(dip)
    t, dip, norm = t[good], dip[good], norm[good]
    if dip.size < 10:
        return []
    start = t <= t[0] + start_s
    rest = ~start
    out = []
    d_start = float(np.median(dip[start]))
    spread = float(np.percentile(dip[start], 90) - np.percentile(dip[start], 10))
    if spread > 2 * FIELD_DIP_TOL_DEG:
        out.append(
            f"the magnetic field is unsteady over the first {start_s:g} s: its inclination spans "
            f"{spread:.0f} deg (disturbed? a magnet, metal or a charger near the phone)"
        )
    if rest.sum() >= 10:
        d_rest = float(np.median(dip[rest]))
        if abs(d_start - d_rest) > FIELD_DIP_TOL_DEG:
            out.append(
                f"the field's inclination over the first {start_s:g} s ({d_start:.1f} deg) disagrees with "
                f"the rest of the log ({d_rest:.1f} deg): a disturbed start? the inertial directions come "
                "from the start; give --inclination or --lat/--lon/--date"
            )
    if model is not None:
        d_model = model.inclination_deg
        d_all = float(np.median(dip))
        if abs(d_all - d_model) > FIELD_DIP_TOL_DEG:
            out.append(
                f"the measured inclination ({d_all:.1f} deg) disagrees with the field model's "
                f"({d_model:.1f} deg) by {abs(d_all - d_model):.0f} deg: disturbed magnetometer, or the "
                "wrong place/date?"
            )
        strength = float(np.median(norm))
        if abs(strength - model.total_nT / 1000.0) > 0.25 * model.total_nT / 1000.0:
            out.append(
                f"the measured field strength ({strength:.1f} uT) disagrees with the model's "
                f"({model.total_nT / 1000:.1f} uT): magnetometer not calibrated or disturbed"
            )
    strength = float(np.median(norm))
    lo, hi = EARTH_FIELD_UT
    if model is None and not lo <= strength <= hi:
        out.append(
            f"the measured field strength ({strength:.1f} uT) is outside the Earth's ({lo:g}-{hi:g} uT): "
            "magnetometer not calibrated (an uncalibrated file?) or disturbed"
        )
    return out
