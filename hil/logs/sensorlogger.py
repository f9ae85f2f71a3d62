"""Sensor Logger (Kelvin Choi's app, Android/iOS) CSV export: a folder or its zip of per-sensor CSVs.

Current exports have the header ``time,seconds_elapsed,z,y,x`` — note the **z, y, x** order; older ones
(late 2022) name their axes like ``GYROSCOPE X (rad/s)``. Columns are found by name
(:mod:`hil.logs.columns`), never by position. ``time`` is Unix epoch in ns (shared by all sensors), read
as exact integers and converted to seconds since the first sample of any sensor; without it,
``seconds_elapsed`` (s since the recording started, also shared). Units (the app's unit reference): m/s²
(g = 9.80665), rad/s, µT; axes are Android's sensor frame (on iOS, with "Standardise Units & Frames" on).

Accelerometers, in order of preference: ``TotalAcceleration.csv`` (specific force *including* gravity);
``Accelerometer.csv`` (the *user* acceleration, gravity removed) plus ``Gravity.csv`` (their sum, gravity
interpolated to the accelerometer's times); ``AccelerometerUncalibrated.csv`` (the raw accelerometer,
gravity included; in g rather than m/s² when its median norm says so). ``Accelerometer.csv`` alone gives
no gravity direction and is refused. Gyroscope and magnetometer: the calibrated files, else the
``…Uncalibrated.csv`` ones (noted). Without a magnetometer file the log is 6-axis (heading unobserved).
"""

from __future__ import annotations

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from hil.logs.columns import axis_columns
from hil.logs.table import Container, Table, read_table
from protocol.errors import InputFormatError

NAME = "sensorlogger"
G = 9.80665
GYR_FILES = ("Gyroscope.csv", "GyroscopeUncalibrated.csv")
MAG_FILES = ("Magnetometer.csv", "MagnetometerUncalibrated.csv")
ACC_FILES = ("TotalAcceleration.csv", "Accelerometer.csv", "AccelerometerUncalibrated.csv")
_TIME = ("time", "seconds_elapsed")


def detect(c: Container) -> bool:
    for name in (*GYR_FILES, *ACC_FILES, *MAG_FILES):
        if c.has(name):
            head = c.head(name, 1)
            cells = [x.strip().strip('"').lower() for x in (head[0] if head else "").split(",")]
            return "seconds_elapsed" in cells or ("time" in cells and any(" x (" in x for x in cells))
    return False


def _table(c: Container, name: str) -> tuple[Table, np.ndarray, list[tuple[str, float]]]:
    """The file's table, its times (int64 ns since the epoch, or float s since the start) and its axes."""
    table = read_table(c, name, ",", header=True, min_columns=4, exact_columns=("time",))
    kind = _KIND[name]
    axes = axis_columns(table.columns, kind, table.source, table.header_line, skip=_TIME)
    times: np.ndarray
    if "time" in table.exact:
        times = table.exact["time"]
    elif "seconds_elapsed" in table.columns:
        times = table.column("seconds_elapsed")
    else:
        raise InputFormatError(
            f"no 'time' or 'seconds_elapsed' column (columns: {', '.join(table.columns)})",
            table.source,
            table.header_line,
        )
    return table, times, axes


_KIND = {n: SensorKind.GYR for n in GYR_FILES} | {n: SensorKind.MAG for n in MAG_FILES}
_KIND |= {n: SensorKind.ACC for n in (*ACC_FILES, "Gravity.csv")}


def _first(c: Container, names: tuple[str, ...]) -> str | None:
    return next((n for n in names if c.has(n)), None)


def read(c: Container) -> SensorLog:
    notes: list[str] = ["Sensor Logger export: columns read by name (files are ordered z, y, x)"]
    parts: dict[SensorKind, tuple[np.ndarray, np.ndarray]] = {}
    gyr = _first(c, GYR_FILES)
    if gyr is None:
        raise InputFormatError("no Gyroscope.csv (nor GyroscopeUncalibrated.csv) in the export", str(c.path))
    mag = _first(c, MAG_FILES)
    for kind, name in ((SensorKind.GYR, gyr), (SensorKind.MAG, mag)):
        if name is None:
            continue
        table, times, axes = _table(c, name)
        parts[kind] = (times, _xyz(table, axes))
        if "Uncalibrated" in name:
            notes.append(f"{name}: no calibrated file in the export, using the uncalibrated one")
    if mag is None:
        notes.append("no Magnetometer.csv: 6-axis log, heading not observed (gyroscope only, drifting)")
    parts[SensorKind.ACC] = _accelerometer(c, notes)
    if c.has("Metadata.csv") and "ios" in c.text("Metadata.csv").lower():
        notes.append("iOS export: axes and units assume 'Standardise Units & Frames' was on")
    epoch = {k: t.dtype.kind == "i" for k, (t, _) in parts.items()}
    if len(set(epoch.values())) > 1:
        raise InputFormatError(
            "some files have a 'time' column and some do not: no common clock", str(c.path)
        )
    streams = {}
    if all(epoch.values()):
        t0 = min(int(t.min()) for t, _ in parts.values() if len(t))
        for kind, (t, xyz) in parts.items():
            streams[kind] = SensorStream(kind, (t - t0).astype(float) * 1e-9, xyz)
        notes.append(f"time: ns since epoch, origin {t0} ns")
    else:
        streams = {kind: SensorStream(kind, t, xyz) for kind, (t, xyz) in parts.items()}
        notes.append("time: seconds_elapsed (no epoch time column)")
    return SensorLog(streams, str(c.path), NAME, None, tuple(notes))


def _accelerometer(c: Container, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    if c.has("TotalAcceleration.csv"):
        table, times, axes = _table(c, "TotalAcceleration.csv")
        notes.append("accelerometer: TotalAcceleration.csv (gravity included)")
        return times, _xyz(table, axes)
    if c.has("Accelerometer.csv") and c.has("Gravity.csv"):
        user, user_t, user_axes = _table(c, "Accelerometer.csv")
        grav, grav_t, grav_axes = _table(c, "Gravity.csv")
        base = grav_t[0] if len(grav_t) else 0
        tu, tg = (user_t - base).astype(float), (grav_t - base).astype(float)
        g = _xyz(grav, grav_axes)
        xyz = _xyz(user, user_axes) + np.column_stack([np.interp(tu, tg, g[:, i]) for i in range(3)])
        notes.append("accelerometer: Accelerometer.csv (user acceleration) + Gravity.csv (interpolated)")
        return user_t, xyz
    if c.has("AccelerometerUncalibrated.csv"):
        table, times, axes = _table(c, "AccelerometerUncalibrated.csv")
        xyz = _xyz(table, axes)
        norm = float(np.nanmedian(np.linalg.norm(xyz, axis=1))) if len(xyz) else G
        if 0.5 < norm < 2.0:  # iOS's raw accelerometer reads in g
            xyz = xyz * G
            notes.append("AccelerometerUncalibrated.csv reads in g (median norm ~1): converted to m/s^2")
        notes.append("accelerometer: AccelerometerUncalibrated.csv (raw, gravity included)")
        return times, xyz
    if c.has("Accelerometer.csv"):
        raise InputFormatError(
            "only Accelerometer.csv (user acceleration, gravity removed) in the export: the estimator needs "
            "the gravity direction; export TotalAcceleration (or Gravity) as well",
            c.where("Accelerometer.csv"),
        )
    raise InputFormatError(
        "no accelerometer file (TotalAcceleration.csv, Accelerometer.csv + Gravity.csv, or "
        "AccelerometerUncalibrated.csv)",
        str(c.path),
    )


def _xyz(t: Table, axes: list[tuple[str, float]]) -> np.ndarray:
    return np.column_stack([t.column(col) * factor for col, factor in axes])
