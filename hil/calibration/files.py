"""Calibration files: one unit's or a whole array's calibration set as TOML (read with ``tomllib``).

Format ``vscmg-hil calibration``, version 1 (``docs/calibration.md`` has the full description)::

    format = "vscmg-hil calibration"
    version = 1

    [[unit]]                      # one per VSCMG unit
    index = 0                     # the board's unit number, 0..7, unique
    name = "pyramid-a"            # optional label

    [unit.esc]                    # ESC endpoints (µs) and deadband above the low endpoint (µs)
    low_us = 1000.0
    high_us = 2000.0
    deadband_us = 41.2

    [unit.rotor]                  # no-load speed = kv · V · f(throttle)
    kv_rad_s_per_v = 50.1
    throttle = [0.0, 0.125, ...]  # knots of f: throttle 0..1 ...
    fraction = [0.0, 0.16, ...]   # ... and f there, 0..1, strictly increasing

    [unit.gimbal_rate]            # rate 0 between lower_pulse_us[-1] and upper_pulse_us[0]
    hold_us = 1500.0
    lower_pulse_us = [...]
    lower_rate_rad_s = [...]      # ends at 0
    upper_pulse_us = [...]
    upper_rate_rad_s = [...]      # starts at 0

    [unit.gimbal_angle]
    pulse_us = [...]
    angle_rad = [...]

Each map may carry a ``fit`` table (provenance: source CSV, points, residuals). Files store knots; the
slopes of the binary form are computed from them by PCHIP, so editing a knot by hand is safe. Numbers are
written as the shortest decimal that reads back as the same float32. Every error names the file and key.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from hil.files.bounded import load_toml
from protocol.calibration import (
    EscThrottleMap,
    GimbalAngleMap,
    GimbalRateMap,
    MonotoneCubic,
    RotorSpeedMap,
    UnitCalibration,
)
from protocol.calibration.checks import within
from protocol.errors import CalibrationError
from protocol.messages import MAX_UNITS

from .bench import MAX_BATTERY_V
from .textfiles import check_text, read_text, write_atomic

FORMAT = "vscmg-hil calibration"
VERSION = 1
MAPS = ("rotor", "gimbal_rate", "gimbal_angle")


@dataclass(frozen=True)
class FitInfo:
    """Where a map came from and how well it fitted (residual = measured − fitted, in ``residual_unit``)."""

    source: str
    points: int
    rms_residual: float
    max_residual: float
    residual_unit: str
    battery_v: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        check_text(self.source, "fit source", CalibrationError)  # a file's text: see relative_source
        check_text(self.residual_unit, "fit residual_unit", CalibrationError)


def relative_source(path: str | os.PathLike[str], out: str | os.PathLike[str], where: str) -> str:
    """A fit's ``source``: ``path`` (a bench CSV) relative to the folder of ``out`` (its calibration file),
    as :class:`FitInfo` stores it. :class:`CalibrationError` naming ``where`` if that is no text a file can
    hold (a folder or a CSV whose name has a byte that is not UTF-8): asked before any work, so a run
    is refused before its sweeps, not after its upload (:func:`~.textfiles.check_text`)."""
    source = os.path.relpath(Path(path).resolve(), Path(out).resolve().parent)
    return check_text(source, where, CalibrationError)


@dataclass(frozen=True)
class UnitEntry:
    """One unit of a calibration file: its board index, a label, its maps and their provenance."""

    index: int
    name: str
    calibration: UnitCalibration
    fits: Mapping[str, FitInfo] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if isinstance(self.index, bool) or not isinstance(self.index, int) or not 0 <= self.index < MAX_UNITS:
            raise CalibrationError(f"{self.index!r} is not a unit number 0..{MAX_UNITS - 1}", "unit index")
        check_text(self.name, "unit name", CalibrationError)


@dataclass(frozen=True)
class CalibrationSet:
    """The units of one calibration file, in index order."""

    units: tuple[UnitEntry, ...]

    def unit(self, index: int) -> UnitEntry | None:
        return next((u for u in self.units if u.index == index), None)

    def with_unit(self, entry: UnitEntry) -> CalibrationSet:
        """A copy with ``entry`` added, or replacing the unit of the same index."""
        rest = [u for u in self.units if u.index != entry.index]
        return CalibrationSet(tuple(sorted([*rest, entry], key=lambda u: u.index)))

    def for_board(self, n_units: int) -> list[UnitCalibration | None]:
        """Calibrations for units 0..n_units-1 (None where the file has none), e.g. for ``Board``."""
        return [u.calibration if (u := self.unit(i)) is not None else None for i in range(n_units)]


# =========================================================================== reading
def load_calibration(path: str | os.PathLike[str]) -> CalibrationSet:
    """Read a calibration file; :class:`CalibrationError` naming the file and key for anything wrong."""
    return parse_calibration(read_text(path, CalibrationError), str(path))


def parse_calibration(text: str, source: str = "<calibration>") -> CalibrationSet:
    doc = load_toml(text, source, CalibrationError)
    top = f"{source}: "
    _keys(doc, {"format", "version", "unit"}, {"format", "version", "unit"}, top)
    if doc["format"] != FORMAT:
        raise CalibrationError(f"{doc['format']!r} is not {FORMAT!r}", f"{top}format")
    version = doc["version"]
    if isinstance(version, bool) or not isinstance(version, int) or version != VERSION:  # true == 1.0 == 1
        raise CalibrationError(
            f"version {version!r} is not supported (this reader knows the integer {VERSION})", f"{top}version"
        )
    units = doc["unit"]
    if not isinstance(units, list) or not units or not all(isinstance(u, dict) for u in units):
        raise CalibrationError("must be one or more [[unit]] tables", f"{top}unit")
    entries = [_unit(u, f"{source}: unit[{i}]") for i, u in enumerate(units)]
    seen: set[int] = set()
    for i, e in enumerate(entries):
        if e.index in seen:
            raise CalibrationError(f"unit index {e.index} appears twice", f"{source}: unit[{i}].index")
        seen.add(e.index)
    return CalibrationSet(tuple(sorted(entries, key=lambda e: e.index)))


def _unit(doc: dict[str, Any], where: str) -> UnitEntry:
    _keys(doc, {"index", "name", *MAPS, "esc"}, {"index", "esc", *MAPS}, where)
    index = doc["index"]
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < MAX_UNITS:
        raise CalibrationError(f"{index!r} is not a unit number 0..{MAX_UNITS - 1}", f"{where}.index")
    name = doc.get("name", f"unit{index}")
    if not isinstance(name, str):
        raise CalibrationError(f"{name!r} is not a string", f"{where}.name")
    esc_doc = _table(doc, "esc", where)
    w = f"{where}.esc"
    _keys(esc_doc, {"low_us", "high_us", "deadband_us"}, {"low_us", "high_us", "deadband_us"}, w)
    low, high, dead = (_num(esc_doc, k, w) for k in ("low_us", "high_us", "deadband_us"))
    with within(w):
        esc = EscThrottleMap(low, high, dead)
    fits: dict[str, FitInfo] = {}
    rotor_doc = _map_table(doc, "rotor", where, ("kv_rad_s_per_v", "throttle", "fraction"), fits)
    w = f"{where}.rotor"
    kv, curve = _num(rotor_doc, "kv_rad_s_per_v", w), _cubic(rotor_doc, "throttle", "fraction", w)
    with within(w):
        rotor = RotorSpeedMap(esc, kv, curve)
    keys = ("hold_us", "lower_pulse_us", "lower_rate_rad_s", "upper_pulse_us", "upper_rate_rad_s")
    rate_doc = _map_table(doc, "gimbal_rate", where, keys, fits)
    w = f"{where}.gimbal_rate"
    hold = _num(rate_doc, "hold_us", w)
    lower = _cubic(rate_doc, "lower_pulse_us", "lower_rate_rad_s", w)
    upper = _cubic(rate_doc, "upper_pulse_us", "upper_rate_rad_s", w)
    with within(w), _file_keys(_RATE_KEYS):
        rate = GimbalRateMap(hold, lower, upper)
    angle_doc = _map_table(doc, "gimbal_angle", where, ("pulse_us", "angle_rad"), fits)
    w = f"{where}.gimbal_angle"
    curve = _cubic(angle_doc, "pulse_us", "angle_rad", w)
    with within(w), _file_keys(_ANGLE_KEYS):
        angle = GimbalAngleMap(curve)
    return UnitEntry(index, name, UnitCalibration(rotor, rate, angle), fits)


_RATE_KEYS = {
    "lower.x": "lower_pulse_us",
    "lower.y": "lower_rate_rad_s",
    "upper.x": "upper_pulse_us",
    "upper.y": "upper_rate_rad_s",
}
_ANGLE_KEYS = {"curve.x": "pulse_us", "curve.y": "angle_rad"}


@contextmanager
def _file_keys(keys: Mapping[str, str]) -> Iterator[None]:
    """Re-raise a map's :class:`CalibrationError` with the file's key for its table's column
    (``lower.x[0]`` → ``lower_pulse_us[0]``), so the message names what to edit."""
    try:
        yield
    except CalibrationError as exc:
        for old, new in keys.items():
            if exc.where == old or exc.where.startswith((f"{old}[", f"{old}.")):
                raise CalibrationError(exc.detail, new + exc.where[len(old) :]) from exc
        raise


def _map_table(
    doc: dict[str, Any], name: str, where: str, keys: tuple[str, ...], fits: dict[str, FitInfo]
) -> dict[str, Any]:
    table = _table(doc, name, where)
    w = f"{where}.{name}"
    _keys(table, {*keys, "fit"}, set(keys), w)
    if "fit" in table:
        fits[name] = _fit_info(_table(table, "fit", w), f"{w}.fit")
    return table


def _fit_info(doc: dict[str, Any], where: str) -> FitInfo:
    required = {"source", "points", "rms_residual", "max_residual", "residual_unit"}
    _keys(doc, {*required, "battery_v"}, required, where)
    for key in ("source", "residual_unit"):
        if not isinstance(doc[key], str):
            raise CalibrationError(f"{doc[key]!r} is not a string", f"{where}.{key}")
    points = doc["points"]
    if isinstance(points, bool) or not isinstance(points, int) or points < 0:
        raise CalibrationError(f"{points!r} is not a count", f"{where}.points")
    battery = None
    if "battery_v" in doc:
        lo, hi = _numbers(doc, "battery_v", where, length=2)
        if not 0.0 < lo <= hi <= MAX_BATTERY_V:
            raise CalibrationError(
                f"[{lo!r}, {hi!r}] is no range of a bench's battery (0 < low <= high <= {MAX_BATTERY_V:g} V)",
                f"{where}.battery_v",
            )
        battery = (lo, hi)
    rms, largest = _num(doc, "rms_residual", where), _num(doc, "max_residual", where)
    # what a fit measured, shown as such by `hil calibrate show`: a hand's -1 or a max below the rms was
    if rms < 0.0 or largest < 0.0:
        raise CalibrationError(
            "a residual is no negative number", f"{where}.{'rms' if rms < 0 else 'max'}_residual"
        )
    if rms > largest * (1.0 + 1e-9):
        raise CalibrationError(
            f"{rms!r} is above max_residual {largest!r}: no fit's residuals", f"{where}.rms_residual"
        )
    return FitInfo(doc["source"], points, rms, largest, doc["residual_unit"], battery)


def _cubic(doc: dict[str, Any], x_key: str, y_key: str, where: str) -> MonotoneCubic:
    """The PCHIP table of knots ``doc[x_key]``, ``doc[y_key]``; errors name those keys (and the knot)."""
    xs = _numbers(doc, x_key, where)
    ys = _numbers(doc, y_key, where)
    if len(xs) != len(ys):
        raise CalibrationError(f"{len(xs)} {x_key} but {len(ys)} {y_key}", f"{where}.{y_key}")
    try:
        return MonotoneCubic.pchip(xs, ys)
    except CalibrationError as exc:
        axis, _, knot = exc.where.partition("[")
        key = {"x": x_key, "y": y_key}.get(axis, f"{x_key}/{y_key}")
        raise CalibrationError(exc.detail, f"{where}.{key}{'[' + knot if knot else ''}") from exc


def _table(doc: dict[str, Any], key: str, where: str) -> dict[str, Any]:
    value = doc[key]
    if not isinstance(value, dict):
        raise CalibrationError(f"must be a table, not {type(value).__name__}", f"{where}.{key}")
    return value


def _num(doc: dict[str, Any], key: str, where: str) -> float:
    value = doc[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CalibrationError(f"{value!r} is not a finite number", f"{where}.{key}")
    return float(value)


def _numbers(doc: dict[str, Any], key: str, where: str, length: int | None = None) -> list[float]:
    value = doc[key]
    if not isinstance(value, list) or (length is not None and len(value) != length):
        shape = f"an array of {length} numbers" if length else "an array of numbers"
        raise CalibrationError(f"must be {shape}", f"{where}.{key}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise CalibrationError(f"{v!r} is not a finite number", f"{where}.{key}[{i}]")
        out.append(float(v))
    return out


def _keys(doc: Mapping[str, Any], allowed: set[str], required: set[str], where: str) -> None:
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise CalibrationError(
            f"unknown key (allowed: {', '.join(sorted(allowed))})", f"{where}.{unknown[0]}"
        )
    missing = sorted(required - set(doc))
    if missing:
        raise CalibrationError("missing", f"{where}.{missing[0]}")


# =========================================================================== writing
def dump_calibration(cset: CalibrationSet) -> str:
    """The TOML text of ``cset`` (reads back equal with :func:`parse_calibration`)."""
    out = [
        '# vscmg-hil calibration set: see docs/calibration.md ("Calibration files")',
        f"format = {_str(FORMAT)}",
        f"version = {VERSION}",
    ]
    for u in cset.units:
        c = u.calibration
        esc, rotor, rate, angle = c.rotor.esc, c.rotor, c.gimbal_rate, c.gimbal_angle
        out += ["", "[[unit]]", f"index = {u.index}", f"name = {_str(u.name)}"]
        out += _section(
            "unit.esc", [("low_us", esc.low_us), ("high_us", esc.high_us), ("deadband_us", esc.deadband_us)]
        )
        out += _section(
            "unit.rotor",
            [
                ("kv_rad_s_per_v", rotor.kv_rad_s_per_v),
                ("throttle", rotor.curve.x),
                ("fraction", rotor.curve.y),
            ],
        )
        out += _fit_section("unit.rotor", u.fits.get("rotor"))
        out += _section(
            "unit.gimbal_rate",
            [
                ("hold_us", rate.hold_us),
                ("lower_pulse_us", rate.lower.x),
                ("lower_rate_rad_s", rate.lower.y),
                ("upper_pulse_us", rate.upper.x),
                ("upper_rate_rad_s", rate.upper.y),
            ],
        )
        out += _fit_section("unit.gimbal_rate", u.fits.get("gimbal_rate"))
        out += _section("unit.gimbal_angle", [("pulse_us", angle.curve.x), ("angle_rad", angle.curve.y)])
        out += _fit_section("unit.gimbal_angle", u.fits.get("gimbal_angle"))
    return "\n".join(out) + "\n"


def save_calibration(cset: CalibrationSet, path: str | os.PathLike[str]) -> Path:
    """Write ``cset`` to ``path`` atomically (a temporary file renamed over it)."""
    return write_atomic(path, dump_calibration(cset))


def _section(name: str, items: Iterable[tuple[str, Any]], exact: bool = False) -> list[str]:
    """A TOML table; floats as shortest float32 decimals (map numbers), or with ``exact`` as float64."""
    return ["", f"[{name}]"] + [f"{k} = {_value(v, exact)}" for k, v in items]


def _fit_section(name: str, fit: FitInfo | None) -> list[str]:
    if fit is None:
        return []
    items: list[tuple[str, Any]] = [
        ("source", fit.source),
        ("points", fit.points),
        ("rms_residual", fit.rms_residual),
        ("max_residual", fit.max_residual),
        ("residual_unit", fit.residual_unit),
    ]
    if fit.battery_v is not None:
        items.append(("battery_v", fit.battery_v))
    return _section(f"{name}.fit", items, exact=True)


def _value(v: Any, exact: bool = False) -> str:
    if isinstance(v, str):
        return _str(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_value(x, exact) for x in v) + "]"
    return repr(float(v)) if exact else _float(v)


def _float(x: float) -> str:
    """The shortest decimal that reads back as the same float32 (always with a '.' or an exponent)."""
    text = str(np.float32(x))
    return text if any(c in text for c in ".e") else text + ".0"


def _str(s: str) -> str:
    """A TOML basic string: JSON's escapes, plus DEL, which TOML (unlike JSON) forbids raw."""
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def with_fit(entry: UnitEntry, name: str, fit: FitInfo | None) -> UnitEntry:
    """``entry`` with map ``name``'s provenance set (None: removed)."""
    fits = dict(entry.fits)
    if fit is None:
        fits.pop(name, None)
    else:
        fits[name] = fit
    return replace(entry, fits=fits)
