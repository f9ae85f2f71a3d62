"""Finding a sensor's columns by their header names, whatever the app's spelling, and their units.

Apps label axes in many ways: Sensor Logger ``x``; older Sensor Logger ``GYROSCOPE X (rad/s)``; phyphox
``"Gyroscope x (rad/s)"``, a custom experiment's ``"Acceleration x"`` (no unit). Which column is an axis
(:func:`axis_column`), its unit in parentheses (or brackets, ``x [deg/s]``) set aside, letter case and
runs of spaces ignored:

1. an *exact* name: the bare letter (``x``), or a sensor's full name and the letter (``Gyroscope x``:
   :data:`SENSOR_NAMES`, of the file's sensor only), wherever it stands in the header;
2. else a *partial* one: a label holding one lone ``x``/``y``/``z`` (``Rotation x``, ``x_uncalibrated``),
   when exactly one column is such;
3. a column whose label says ``bias`` (``xBias``, ``bias x``, ``x_bias``: Sensor Logger's uncalibrated
   files carry the OS's bias estimates beside the reading) is never an axis.

Two columns of different names that are equally the axis (two exact ones, ``x`` and ``x (deg/s)``; or no
exact one and two partial ones, ``x accuracy`` and ``x_uncalibrated``) are an InputFormatError naming the
file, the header's line and both columns: never a guess. A name the header holds twice is one column (its
first: :mod:`hil.logs.rows`). The unit converts to SI (:data:`UNITS`); a missing unit means SI. A time
column is named ``time``/``Time …``/``t``; its unit (``(s)``, ``(ms)``, ``in ms``, ``(ns)``) gives its
scale to seconds.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

from hil.estimation.sensors import SensorKind
from protocol.errors import InputFormatError

UNITS: dict[SensorKind, dict[str, float]] = {
    SensorKind.ACC: {
        **{"": 1.0, "m/s^2": 1.0, "m/s²": 1.0, "m/s2": 1.0, "m s^-2": 1.0},
        **{"g": 9.80665, "mg": 9.80665e-3},
    },
    SensorKind.GYR: {
        **{"": 1.0, "rad/s": 1.0, "mrad/s": 1e-3},
        **{"°/s": math.pi / 180, "deg/s": math.pi / 180, "dps": math.pi / 180},
    },
    SensorKind.MAG: {
        **{"": 1.0, "µt": 1.0, "μt": 1.0, "ut": 1.0, "mt": 1000.0, "nt": 1e-3},
        **{"g": 100.0, "gauss": 100.0, "mg": 0.1},
    },
}
"""Per sensor: unit (lower case) → factor to m/s², rad/s or µT. Besides SI, the units other apps and IMU
tools write: g and milli-g (mg) for acceleration; deg/s (``dps``) and mrad/s for rates; gauss (G, 100 µT)
and milligauss (mG, 0.1 µT) for the field — each sensor's table its own, so ``g`` is 9.81 m/s² on an
accelerometer and 100 µT on a magnetometer (a header of G was refused, "unknown unit", though it says
exactly what its numbers are)."""
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


SENSOR_NAMES: dict[SensorKind, tuple[str, ...]] = {
    SensorKind.ACC: ("acceleration", "accelerometer", "total acceleration", "gravity"),
    SensorKind.GYR: ("gyroscope",),
    SensorKind.MAG: ("magnetic field", "magnetometer"),
}
"""Per sensor: the names (lower case) an app writes before an axis letter in a full axis label — phyphox's
``Acceleration x``, ``Gyroscope x``, ``Magnetic field x``; older Sensor Logger's ``ACCELERATION X``,
``GYROSCOPE X``, ``MAGNETIC FIELD X`` (``GRAVITY X`` in its Gravity.csv)."""
_BIAS = re.compile(r"bias", re.IGNORECASE)


def _label(column: str) -> str:
    """A header cell without its unit, stripped, in lower case, runs of spaces as one."""
    return " ".join(_UNIT.sub("", column).split()).lower()


def axis_of(column: str) -> str | None:
    """``x``, ``y`` or ``z`` when the label (unit set aside) holds exactly one lone axis letter and does
    not say ``bias``: a column that may be an axis (:func:`axis_column` chooses among them)."""
    label = _UNIT.sub("", column)
    if _BIAS.search(label):
        return None
    found = _AXIS.findall(label)
    return found[0].lower() if len(found) == 1 else None


def axis_column(
    columns: Sequence[str],
    axis: str,
    names: Sequence[str],
    what: str,
    where: str,
    line: int = 1,
    skip: Sequence[str] = (),
) -> str | None:
    """The column of ``axis`` (``x``, ``y``, ``z``) among ``columns`` (see the module's docstring): the
    one exact name (the bare letter, or one of ``names`` and the letter), else the one partial match;
    None when there is no candidate. Two of different names at the best rank are an InputFormatError
    naming ``where``, ``line`` and both (``what`` says which sensor, for the message)."""
    exact_labels = {axis, *(f"{name} {axis}" for name in names)}
    exact: list[str] = []
    partial: list[str] = []
    for column in columns:
        if column in skip or axis_of(column) != axis:
            continue
        rank = exact if _label(column) in exact_labels else partial
        if column not in rank:
            rank.append(column)
    found = exact or partial
    if len(found) > 1:
        how = "named exactly" if exact else "named in part (and none exactly)"
        raise InputFormatError(
            f"two columns could be the {axis} of the {what}, {how}: {found[0]!r} and {found[1]!r} "
            f"(columns: {', '.join(columns)}); rename or remove one",
            where,
            line,
        )
    return found[0] if found else None


def axis_columns(
    columns: Sequence[str], kind: SensorKind, where: str, line: int = 1, skip: Sequence[str] = ()
) -> list[tuple[str, float]]:
    """The x, y, z columns of ``kind`` (:func:`axis_column`, its full names :data:`SENSOR_NAMES`) with
    their factors to SI; InputFormatError naming the header's line and the column when one is missing,
    ambiguous or in an unknown unit."""
    out = []
    for axis in "xyz":
        what = kind.name.lower()
        col = axis_column(columns, axis, SENSOR_NAMES[kind], what, where, line, skip)
        if col is None:
            raise InputFormatError(
                f"no {axis} column for the {what} (columns: {', '.join(columns)})", where, line
            )
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


TIME_WORDS = ("t", "time", "zeit", "temps", "tiempo", "tempo", "tijd", "czas")
"""A time column's label, in English and in the languages a phone app writes its export's labels in
(phyphox's "Zeit (s)", "Temps (s)": a German phone's export was "no time column")."""


def is_time_label(column: str) -> bool:
    """Whether ``column`` names time (:data:`TIME_WORDS`, or begins with "time": ``timestamp``), its unit
    aside."""
    label = _UNIT.sub("", column).strip().lower()
    return label in TIME_WORDS or label.startswith("time")


def time_column(columns: Sequence[str], where: str, line: int = 1) -> tuple[str, float]:
    """The time column and its factor to seconds."""
    for col in columns:
        if is_time_label(col):
            unit = unit_of(col)
            if unit not in TIME_UNITS:
                raise InputFormatError(f"unknown time unit {unit!r}", where, line, col)
            return col, TIME_UNITS[unit]
    raise InputFormatError(f"no time column (columns: {', '.join(columns)})", where, line)
