"""Sensor Logger (Kelvin Choi's app, Android/iOS) CSV export: a folder or its zip of per-sensor CSVs.

Each CSV has the header ``time,seconds_elapsed,z,y,x`` — note the **z, y, x** column order (columns are
read by name here, never by position). ``time`` is Unix epoch in ns (shared by all sensors), converted to
seconds since the first sample of any sensor. Units (the app's unit reference): m/s² (assuming g =
9.80665), rad/s, µT; axes are Android's sensor frame (on iOS, with "Standardise Units & Frames" on).

Accelerometers: ``TotalAcceleration.csv`` is the specific force *including* gravity — what the estimator
needs, and used when present. The app's ``Accelerometer.csv`` is the *user* acceleration, gravity removed;
it is used only together with ``Gravity.csv`` (their sum, gravity interpolated to the accelerometer's
times). An export with only ``Accelerometer.csv`` cannot give a gravity direction and is refused.
Calibrated gyroscope/magnetometer are preferred; the ``…Uncalibrated.csv`` files are a fallback (noted).
"""

from __future__ import annotations

import numpy as np

from hil.logs.table import Container, Table, parse_table
from hil.sensors import SensorKind, SensorLog, SensorStream
from protocol.errors import InputFormatError

NAME = "sensorlogger"
_HEADER_MARK = "seconds_elapsed"


def detect(c: Container) -> bool:
    for name in ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv"):
        if c.has(name):
            return _HEADER_MARK in c.text(name).split("\n", 1)[0]
    return False


def _table(c: Container, name: str) -> Table:
    table = parse_table(c.text(name), c.where(name), ",", header=True, min_columns=5)
    for col in ("time", "x", "y", "z"):
        table.column(col)  # raises naming the file if missing
    return table


def _first(c: Container, *names: str) -> str | None:
    return next((n for n in names if c.has(n)), None)


def read(c: Container) -> SensorLog:
    notes: list[str] = ["Sensor Logger export: columns read by name (files are ordered z, y, x)"]
    tables: dict[SensorKind, Table] = {}
    gyr = _first(c, "Gyroscope.csv", "GyroscopeUncalibrated.csv")
    mag = _first(c, "Magnetometer.csv", "MagnetometerUncalibrated.csv")
    if gyr is None or mag is None:
        raise InputFormatError("needs Gyroscope.csv and Magnetometer.csv", str(c.path))
    for kind, name in ((SensorKind.GYR, gyr), (SensorKind.MAG, mag)):
        tables[kind] = _table(c, name)
        if "Uncalibrated" in name:
            notes.append(f"{name}: no calibrated file in the export, using the uncalibrated one")
    acc_xyz = None
    if c.has("TotalAcceleration.csv"):
        tables[SensorKind.ACC] = _table(c, "TotalAcceleration.csv")
        notes.append("accelerometer: TotalAcceleration.csv (gravity included)")
    elif c.has("Accelerometer.csv") and c.has("Gravity.csv"):
        user, grav = _table(c, "Accelerometer.csv"), _table(c, "Gravity.csv")
        tables[SensorKind.ACC] = user
        acc_xyz = _xyz(user) + np.column_stack(
            [np.interp(user.column("time"), grav.column("time"), grav.column(a)) for a in "xyz"]
        )
        notes.append("accelerometer: Accelerometer.csv (user acceleration) + Gravity.csv (interpolated)")
    elif c.has("Accelerometer.csv"):
        raise InputFormatError(
            "only Accelerometer.csv (user acceleration, gravity removed) in the export: the estimator needs "
            "the gravity direction; export TotalAcceleration (or Gravity) as well",
            c.where("Accelerometer.csv"),
        )
    else:
        raise InputFormatError("no accelerometer file (TotalAcceleration.csv)", str(c.path))
    if c.has("Metadata.csv") and "ios" in c.text("Metadata.csv").lower():
        notes.append("iOS export: axes and units assume 'Standardise Units & Frames' was on")
    t0 = min(float(np.min(t.column("time"))) for t in tables.values() if len(t.data))
    streams = {
        kind: SensorStream(
            kind,
            (t.column("time") - t0) * 1e-9,
            acc_xyz if kind is SensorKind.ACC and acc_xyz is not None else _xyz(t),
        )
        for kind, t in tables.items()
    }
    notes.append(f"time: ns since epoch, origin {t0:.0f} ns")
    return SensorLog(streams, str(c.path), NAME, None, tuple(notes))


def _xyz(t: Table) -> np.ndarray:
    return np.column_stack([t.column("x"), t.column("y"), t.column("z")])
