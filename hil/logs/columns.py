"""Finding a sensor's columns by their header names, whatever the app's spelling, and their units.

Apps label axes in many ways: Sensor Logger ``x``; older Sensor Logger ``GYROSCOPE X (rad/s)``; phyphox
``"Gyroscope x (rad/s)"``, a custom experiment's ``"Acceleration x"`` (no unit). An axis column carries a
lone ``x``/``y``/``z`` (any case) once its unit in parentheses (or brackets, ``x [deg/s]``) is set aside;
the unit converts to SI (:data:`UNITS`); a missing unit means SI. A time column is named
``time``/``Time …``/``t``; its unit (``(s)``, ``(ms)``, ``in ms``, ``(ns)``) gives its scale to seconds.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

from hil.estimation.sensors import SensorKind
from protocol.errors import InputFormatError

UNITS: dict[SensorKind, dict[str, float]] = {
    SensorKind.ACC: {"": 1.0, "m/s^2": 1.0, "m/s²": 1.0, "m/s2": 1.0, "m s^-2": 1.0, "g": 9.80665},
    SensorKind.GYR: {"": 1.0, "rad/s": 1.0, "°/s": math.pi / 180, "deg/s": math.pi / 180},
    SensorKind.MAG: {"": 1.0, "µt": 1.0, "μt": 1.0, "ut": 1.0, "mt": 1000.0, "nt": 1e-3},
}
"""Per sensor: unit (lower case) → factor to m/s², rad/s or µT."""
TIME_UNITS = {"": 1.0, "s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}

_AXIS = re.compile(r"(?<![A-Za-z])([xyz])(?![A-Za-z])", re.IGNORECASE)
_UNIT = re.compile(r"(?:\(([^()]*)\)|\[([^\[\]]*)\])\s*$")
"""A unit in trailing parentheses, ``x (rad/s)``, or brackets, ``x [rad/s]`` (a re-save's spelling: read,
so that ``[deg/s]`` is never taken for rad/s)."""
_IN_UNIT = re.compile(r"\bin\s+(\w+)\s*$", re.IGNORECASE)


def unit_of(column: str) -> str:
    """The unit of a header cell: in trailing parentheses or brackets, or after a trailing 'in' (lower
    case)."""
    m = _UNIT.search(column)
    if m:
        return (m.group(1) if m.group(1) is not None else m.group(2)).strip().lower()
    m = _IN_UNIT.search(column.strip())
    return m.group(1).lower() if m else ""


def axis_of(column: str) -> str | None:
    """``x``, ``y`` or ``z`` when the label (unit set aside) holds exactly one lone axis letter."""
    found = _AXIS.findall(_UNIT.sub("", column))
    return found[0].lower() if len(found) == 1 else None


def axis_columns(
    columns: Sequence[str], kind: SensorKind, where: str, line: int = 1, skip: Sequence[str] = ()
) -> list[tuple[str, float]]:
    """The x, y, z columns of ``kind`` with their factors to SI; InputFormatError naming the header's line
    and the column when one is missing, ambiguous or in an unknown unit."""
    out = []
    for axis in "xyz":
        found = [c for c in columns if c not in skip and axis_of(c) == axis]
        if not found:
            raise InputFormatError(
                f"no {axis} column for the {kind.name.lower()} (columns: {', '.join(columns)})", where, line
            )
        col = found[0]
        out.append((col, unit_factor(kind, col, where, line)))
    return out


def unit_factor(kind: SensorKind, column: str, where: str, line: int = 1) -> float:
    unit = unit_of(column)
    table = UNITS[kind]
    factor = table.get(unit, table.get(unit.replace("µ", "u").replace("μ", "u")))
    if factor is None:
        known = ", ".join(u for u in table if u)
        raise InputFormatError(
            f"unknown unit {unit!r} for the {kind.label} (known: {known})", where, line, column
        )
    return factor


def time_column(columns: Sequence[str], where: str, line: int = 1) -> tuple[str, float]:
    """The time column and its factor to seconds."""
    for col in columns:
        label = _UNIT.sub("", col).strip().lower()
        if label in ("t", "time") or label.startswith("time"):
            unit = unit_of(col)
            if unit not in TIME_UNITS:
                raise InputFormatError(f"unknown time unit {unit!r}", where, line, col)
            return col, TIME_UNITS[unit]
    raise InputFormatError(f"no time column (columns: {', '.join(columns)})", where, line)
