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

import io

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from hil.logs.table import Container, Table, parse_table
from protocol.errors import InputFormatError

NAME = "sensorlogger"
_HEADER_MARK = "seconds_elapsed"


def detect(c: Container) -> bool:
    for name in ("Gyroscope.csv", "TotalAcceleration.csv", "Magnetometer.csv"):
        if c.has(name):
            return _HEADER_MARK in c.text(name).split("\n", 1)[0]
    return False


def _table(c: Container, name: str) -> tuple[Table, np.ndarray]:
    """The file's table and its ``time`` column as exact int64 ns (a float64 would round to 256 ns)."""
    text = c.text(name)
    table = parse_table(text, c.where(name), ",", header=True, min_columns=5)
    for col in ("time", "x", "y", "z"):
        table.column(col)  # raises naming the file if missing
    try:
        ns = np.loadtxt(io.StringIO(text), delimiter=",", skiprows=1, usecols=table.columns.index("time"),
                        dtype=np.int64, ndmin=1, comments="#")  # fmt: skip
    except ValueError:  # not integers (a re-saved file): the float column, to its precision
        ns = table.column("time").astype(np.int64)
    return table, ns


def _first(c: Container, *names: str) -> str | None:
    return next((n for n in names if c.has(n)), None)


def read(c: Container) -> SensorLog:
    notes: list[str] = ["Sensor Logger export: columns read by name (files are ordered z, y, x)"]
    tables: dict[SensorKind, tuple[Table, np.ndarray]] = {}
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
        user, user_ns = _table(c, "Accelerometer.csv")
        grav, grav_ns = _table(c, "Gravity.csv")
        tables[SensorKind.ACC] = (user, user_ns)
        base = int(grav_ns[0]) if len(grav_ns) else 0
        tu, tg = (user_ns - base).astype(float), (grav_ns - base).astype(float)
        acc_xyz = _xyz(user) + np.column_stack([np.interp(tu, tg, grav.column(a)) for a in "xyz"])
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
    t0 = min(int(ns.min()) for _, ns in tables.values() if len(ns))
    streams = {}
    for kind, (table, ns) in tables.items():
        xyz = acc_xyz if kind is SensorKind.ACC and acc_xyz is not None else _xyz(table)
        streams[kind] = SensorStream(kind, (ns - t0).astype(float) * 1e-9, xyz)
    notes.append(f"time: ns since epoch, origin {t0} ns")
    return SensorLog(streams, str(c.path), NAME, None, tuple(notes))


def _xyz(t: Table) -> np.ndarray:
    return np.column_stack([t.column("x"), t.column("y"), t.column("z")])
