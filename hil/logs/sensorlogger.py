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

from dataclasses import replace

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from hil.logs.columns import axis_columns
from hil.logs.table import Container, Table, read_table, sniff_dialect, split_header, text_lines
from protocol.errors import InputFormatError

NAME = "sensorlogger"
G = 9.80665
GYR_FILES = ("Gyroscope.csv", "GyroscopeUncalibrated.csv")
MAG_FILES = ("Magnetometer.csv", "MagnetometerUncalibrated.csv")
ACC_FILES = ("TotalAcceleration.csv", "Accelerometer.csv", "AccelerometerUncalibrated.csv")
_TIME = ("time", "seconds_elapsed")


_KNOWN = (*GYR_FILES, *ACC_FILES, *MAG_FILES, "Gravity.csv", "Metadata.csv")
"""The export's files this reader reads, as the app names them."""
EPOCH_UNITS: tuple[tuple[int, int, int, str], ...] = (
    (10**18, 10**19, 1, "ns"),
    (10**15, 10**16, 1_000, "µs"),
    (10**12, 10**13, 1_000_000, "ms"),
    (10**9, 10**10, 1_000_000_000, "s"),
)
"""``time`` column units by size: (lowest, highest, ns per unit, name). A time since the epoch between
2001 and 2286 is 1e9–1e10 s: in ns (the app's) 1e18–1e19, in µs or ms (a re-export) 1e15 or 1e12 on."""


def members(c: Container) -> dict[str, str] | None:
    """Sensor Logger's files in ``c`` (:data:`_KNOWN`, matched whatever their letter case) → the members
    holding them: at the top, or all in one folder below it (an export zipped twice, a folder holding the
    export's zip: ``Rec/Gyroscope.csv``). None when they lie in several folders (recordings side by side:
    each is a log of its own)."""
    lower = {name.lower(): name for name in _KNOWN}
    found: dict[str, str] = {}
    folders: set[str] = set()
    for member in sorted(c.names()):
        folder, _, base = member.rpartition("/")
        name = lower.get(_plain(base).lower())
        if name is not None and name not in found:
            found[name] = member
            folders.add(folder)
    return found if len(folders) <= 1 else None


def _plain(base: str) -> str:
    """A member's file name without a ``.gz`` (a file gzipped by hand or by a backup tool:
    :class:`~hil.logs.table.Container` decompresses it as it reads)."""
    return base[:-3] if base.lower().endswith(".gz") else base


def detect(c: Container) -> bool:
    """Whether ``c`` is a Sensor Logger export, told by the header of its first sensor file that has one.
    An empty file (a sensor the app wrote nothing for, a copy cut short) says nothing either way: the
    next one is asked, and :func:`read` names the empty one if it is needed — rather than the export
    going unrecognised and its other files being offered as logs of their own."""
    files = members(c) or {}
    for name in (*GYR_FILES, *ACC_FILES, *MAG_FILES):
        if name not in files:
            continue
        head = [line for line in c.head(files[name], 3) if line.strip()]
        if not head:
            continue
        cells = [x.lower() for x in split_header(head[0], sniff_dialect(head)[0])]
        return "seconds_elapsed" in cells or ("time" in cells and any(" x (" in x for x in cells))
    return False


def _table(
    c: Container, member: str, notes: list[str], required: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """The file's times (int64 ns since the epoch, or float s since the start) and readings (N, 3), read
    in its own dialect (a spreadsheet's re-save may use semicolons and decimal commas). A row whose
    ``time`` is no number (NaN, or beyond int64) has NaN readings: a NaN sample, dropped and counted by
    the merge. A file with no rows is an InputFormatError naming it when ``required``."""
    head = [line for line in c.head(member, 8) if line.strip()]
    delimiter, decimal_comma = sniff_dialect(head)
    cells = split_header(head[0], delimiter) if head else []
    time_name = next((cell for cell in cells if cell.lower() == "time"), "time")
    table = read_table(
        c,
        member,
        delimiter,
        header=True,
        decimal_comma=decimal_comma,
        min_columns=4,
        exact_columns=(time_name,),
    )
    table = _clock_names_lowered(table)
    if required and not len(table.data):
        raise InputFormatError("no samples (a header only)", table.source)
    kind = _KIND[_plain(member.rpartition("/")[2]).lower()]
    axes = axis_columns(table.columns, kind, table.source, table.header_line, skip=_TIME)
    xyz = np.column_stack([table.column(col) * factor for col, factor in axes])
    times: np.ndarray
    if "time" in table.exact:
        exact = table.column("time")
        unusable = ~(np.isfinite(exact) & (np.abs(exact) < 2.0**63))
        if unusable.all() and len(unusable):
            raise InputFormatError("no 'time' cell is a number", table.source, table.header_line, "time")
        times, usable = _epoch_ns(table, ~unusable, notes)
        xyz[~usable] = np.nan
    elif "seconds_elapsed" in table.columns:
        times = table.column("seconds_elapsed")
    else:
        raise InputFormatError(
            f"no 'time' or 'seconds_elapsed' column (columns: {', '.join(table.columns)})",
            table.source,
            table.header_line,
        )
    return times, xyz


def _clock_names_lowered(table: Table) -> Table:
    """``table`` with its clock columns named as the app names them (``TIME``, ``Seconds_Elapsed`` →
    ``time``, ``seconds_elapsed``): :func:`detect` reads a header whatever its letter case (a spreadsheet
    or script that re-saved the export may change it), so the reader must find the same columns."""
    columns = tuple(col.lower() if col.lower() in _TIME else col for col in table.columns)
    exact = {name.lower(): values for name, values in table.exact.items()}
    return replace(table, columns=columns, exact=exact)


def _epoch_ns(table: Table, usable: np.ndarray, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The ``time`` column as int64 ns since the epoch, its unit told by its size (:data:`EPOCH_UNITS`:
    the app writes ns; a re-export may write µs or ms) and checked against ``seconds_elapsed``'s steps
    where there is one; and the rows whose time is usable (of ``usable``, those whose ns fit int64). A
    time that is no epoch in any unit is an InputFormatError naming the column."""
    times = table.exact["time"]
    if not usable.any():
        return times, usable
    typical = int(np.median(times[usable]))
    unit = next((u for u in EPOCH_UNITS if u[0] <= abs(typical) < u[1]), None)
    if unit is None:
        raise InputFormatError(
            f"{typical} is no time since the epoch in ns, µs, ms or s (2001-2286)",
            table.source,
            table.header_line,
            "time",
        )
    _, _, ns_per_unit, name = unit
    usable = usable & (np.abs(times) <= np.iinfo(np.int64).max // ns_per_unit)  # a stray far off: NaN
    ns = np.where(usable, times, typical) * ns_per_unit
    if name != "ns":
        notes.append(f"{table.source}: 'time' in {name} since the epoch (the app writes ns)")
    if "seconds_elapsed" in table.columns:
        rows = np.flatnonzero(usable & np.isfinite(table.column("seconds_elapsed")))
        elapsed = table.column("seconds_elapsed")[rows]
        span_s = float(elapsed[-1] - elapsed[0]) if len(rows) else 0.0
        if abs(span_s) >= 1.0:
            ratio = float(ns[rows[-1]] - ns[rows[0]]) * 1e-9 / span_s
            if not 0.99 < ratio < 1.01:
                raise InputFormatError(
                    f"read as {name} since the epoch, 'time' spans {ratio:.4g} times what "
                    f"'seconds_elapsed' does: its unit is not {name}",
                    table.source,
                    table.header_line,
                    "time",
                )
    return ns, usable


_KIND = {n.lower(): SensorKind.GYR for n in GYR_FILES} | {n.lower(): SensorKind.MAG for n in MAG_FILES}
_KIND |= {n.lower(): SensorKind.ACC for n in (*ACC_FILES, "Gravity.csv")}


def _holds_nothing(c: Container, member: str) -> bool:
    """Whether the member has no line but blank ones (0 bytes: the app wrote nothing for that sensor).
    Streamed, and stopped at the first line with content."""
    for _, lines in text_lines(c, member):
        if any(line.strip() for line in lines):
            return False
    return True


def _first(files: dict[str, str], names: tuple[str, ...]) -> str | None:
    return next((n for n in names if n in files), None)


def read(c: Container) -> SensorLog:
    files = members(c)
    if files is None:
        folders = sorted({m.rpartition("/")[0] or "." for m in c.names()})
        raise InputFormatError(
            f"Sensor Logger files in several folders ({', '.join(folders[:6])}): recordings side by side; "
            "replay one folder",
            str(c.path),
        )
    notes: list[str] = ["Sensor Logger export: columns read by name (files are ordered z, y, x)"]
    parts: dict[SensorKind, tuple[np.ndarray, np.ndarray]] = {}
    gyr = _first(files, GYR_FILES)
    if gyr is None:
        raise InputFormatError("no Gyroscope.csv (nor GyroscopeUncalibrated.csv) in the export", str(c.path))
    mag = _first(files, MAG_FILES)
    for kind, name in ((SensorKind.GYR, gyr), (SensorKind.MAG, mag)):
        if name is None:
            continue
        if kind is SensorKind.MAG and _holds_nothing(c, files[name]):  # as a header only, below
            notes.append(f"{name} is empty: 6-axis log, heading not observed")
            mag = None
            continue
        times, xyz = _table(c, files[name], notes, required=kind is SensorKind.GYR)
        if not len(times):  # a magnetometer file with a header only
            notes.append(f"{name} has no samples: 6-axis log, heading not observed")
            mag = None
            continue
        parts[kind] = (times, xyz)
        if "Uncalibrated" in name:
            notes.append(f"{name}: no calibrated file in the export, using the uncalibrated one")
    if _first(files, MAG_FILES) is None:
        notes.append("no Magnetometer.csv: 6-axis log, heading not observed (gyroscope only, drifting)")
    parts[SensorKind.ACC] = _accelerometer(c, files, notes)
    if "Metadata.csv" in files and "ios" in c.text(files["Metadata.csv"]).lower():
        notes.append("iOS export: axes and units assume 'Standardise Units & Frames' was on")
    if any(m.rpartition("/")[2] != _plain(m.rpartition("/")[2]) for m in files.values()):
        notes.append("the export's files are gzipped (.csv.gz): read decompressed")
    if any(_plain(m) != name for name, m in files.items()):
        folder = next(iter(files.values())).rpartition("/")[0]
        notes.append(f"the export's files read from {folder or 'the top'} (names matched ignoring case)")
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


def _accelerometer(c: Container, files: dict[str, str], notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    if "TotalAcceleration.csv" in files:
        times, xyz = _table(c, files["TotalAcceleration.csv"], notes)
        notes.append("accelerometer: TotalAcceleration.csv (gravity included)")
        return times, xyz
    if "Accelerometer.csv" in files and "Gravity.csv" in files:
        user_t, user = _table(c, files["Accelerometer.csv"], notes)
        grav_t, g = _table(c, files["Gravity.csv"], notes)
        known = np.all(np.isfinite(g), axis=1)  # gravity interpolated between its usable rows
        if not known.any():
            raise InputFormatError("no usable samples", c.where(files["Gravity.csv"]))
        grav_t, g = grav_t[known], g[known]
        base = grav_t[0]
        tu, tg = (user_t - base).astype(float), (grav_t - base).astype(float)
        xyz = user + np.column_stack([np.interp(tu, tg, g[:, i]) for i in range(3)])
        notes.append("accelerometer: Accelerometer.csv (user acceleration) + Gravity.csv (interpolated)")
        return user_t, xyz
    if "AccelerometerUncalibrated.csv" in files:
        times, xyz = _table(c, files["AccelerometerUncalibrated.csv"], notes)
        norm = float(np.nanmedian(np.linalg.norm(xyz, axis=1))) if len(xyz) else G
        if 0.5 < norm < 2.0:  # iOS's raw accelerometer reads in g
            xyz = xyz * G
            notes.append("AccelerometerUncalibrated.csv reads in g (median norm ~1): converted to m/s^2")
        notes.append("accelerometer: AccelerometerUncalibrated.csv (raw, gravity included)")
        return times, xyz
    if "Accelerometer.csv" in files:
        raise InputFormatError(
            "only Accelerometer.csv (user acceleration, gravity removed) in the export: the estimator needs "
            "the gravity direction; export TotalAcceleration (or Gravity) as well",
            c.where(files["Accelerometer.csv"]),
        )
    raise InputFormatError(
        "no accelerometer file (TotalAcceleration.csv, Accelerometer.csv + Gravity.csv, or "
        "AccelerometerUncalibrated.csv)",
        str(c.path),
    )
