"""phyphox (RWTH Aachen) "Export data → CSV": a zip (or its folder) of one CSV per sensor.

Files ``Accelerometer.csv`` ("Acceleration with g": gravity included), ``Gyroscope.csv``,
``Magnetometer.csv``; headers like ``"Time (s)","Acceleration x (m/s^2)",…``, ``"Gyroscope x (rad/s)"``,
``"Magnetic field x (µT)"``. Columns are found by name: the time column starts with "Time", axis columns
carry a lone ``x``/``y``/``z`` and their unit in parentheses, which is converted to SI (g → m/s² with
9.80665, °/s → rad/s, mT/nT → µT). All three of phyphox's CSV dialects are read: comma with decimal
point, tab with decimal point, semicolon with decimal comma. ``Time (s)`` is seconds since the experiment
started, one clock for all sensors; axes are the phone's sensor frame. ``Linear Acceleration.csv`` (no
gravity) cannot replace the accelerometer and is refused.
"""

from __future__ import annotations

import math
import re

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from hil.logs.table import Container, Table, parse_table
from protocol.errors import InputFormatError

NAME = "phyphox"
FILES = {
    SensorKind.ACC: "Accelerometer.csv",
    SensorKind.GYR: "Gyroscope.csv",
    SensorKind.MAG: "Magnetometer.csv",
}
_UNITS = {
    SensorKind.ACC: {"m/s^2": 1.0, "m/s²": 1.0, "m/s2": 1.0, "g": 9.80665},
    SensorKind.GYR: {"rad/s": 1.0, "°/s": math.pi / 180, "deg/s": math.pi / 180},
    SensorKind.MAG: {"µt": 1.0, "μt": 1.0, "ut": 1.0, "mt": 1000.0, "nt": 1e-3},
}
_AXIS = re.compile(r"(?<![A-Za-z])([xyz])(?![A-Za-z])", re.IGNORECASE)
_UNIT = re.compile(r"\(([^()]*)\)\s*$")


def detect(c: Container) -> bool:
    for name in FILES.values():
        if c.has(name):
            head = c.text(name).split("\n", 1)[0]
            return head.lstrip('"').startswith("Time")
    return False


def _dialect(header: str) -> tuple[str, bool]:
    if ";" in header:
        return ";", True
    if "\t" in header:
        return "\t", False
    return ",", False


def _stream(c: Container, kind: SensorKind) -> SensorStream:
    name = FILES[kind]
    text = c.text(name)
    delimiter, decimal_comma = _dialect(text.split("\n", 1)[0])
    table = parse_table(
        text, c.where(name), delimiter, header=True, decimal_comma=decimal_comma, min_columns=4
    )
    time_col = next((col for col in table.columns if col.lower().startswith("time")), None)
    if time_col is None:
        raise InputFormatError(f"no 'Time (s)' column (columns: {', '.join(table.columns)})", table.source)
    axes = []
    for axis in "xyz":
        col = next((x for x in table.columns if x != time_col and _axis_of(x) == axis), None)
        if col is None:
            raise InputFormatError(f"no {axis} column (columns: {', '.join(table.columns)})", table.source)
        axes.append(table.column(col) * _scale(kind, col, table))
    return SensorStream(kind, table.column(time_col), np.column_stack(axes))


def _axis_of(column: str) -> str | None:
    label = _UNIT.sub("", column)
    m = _AXIS.findall(label)
    return m[-1].lower() if len(m) == 1 else None


def _scale(kind: SensorKind, column: str, table: Table) -> float:
    m = _UNIT.search(column)
    unit = m.group(1).strip().lower() if m else ""
    factor = _UNITS[kind].get(unit) or _UNITS[kind].get(unit.replace("µ", "u"))
    if factor is None:
        raise InputFormatError(f"unknown unit {unit!r} for the {kind.label}", table.source, 1, column)
    return factor


def read(c: Container) -> SensorLog:
    if not c.has(FILES[SensorKind.ACC]) and c.has("Linear Acceleration.csv"):
        raise InputFormatError(
            "only 'Linear Acceleration.csv' (gravity removed): record with phyphox's 'Acceleration with g'",
            c.where("Linear Acceleration.csv"),
        )
    missing = [n for n in FILES.values() if not c.has(n)]
    if missing:
        raise InputFormatError(f"missing {', '.join(missing)}", str(c.path))
    streams = {kind: _stream(c, kind) for kind in FILES}
    return SensorLog(streams, str(c.path), NAME, None, ("phyphox export: units converted to SI",))
