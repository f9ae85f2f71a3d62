"""Bench data: measured (pulse, battery voltage, rotor speed or gimbal rate/angle) rows in CSV files.

A bench CSV is UTF-8 text; lines starting with ``#`` are comments, blank lines are skipped; the first
other line is the header. Columns (any order; extra columns are ignored):

* ``pulse_us`` — the commanded pulse width (µs, 500–2500), required;
* ``battery_v`` — battery voltage during the sample (V, 0–60), required for rotor data (at least
  ``MIN_SUPPLY_V``, 1 V, there: the rotor fit divides the speed by it);
* exactly one measurement: ``rpm`` or ``rotor_speed_rad_s`` (rotor no-load speed, 0–100 000 rpm),
  ``gimbal_rate_rad_s`` or ``gimbal_rate_deg_s`` (±100 rad/s), ``gimbal_angle_rad`` or ``gimbal_angle_deg``
  (two turns either way) (:data:`MEASURED_RANGE`).

A comment ``# status: complete`` or ``# status: partial[: why]`` says whether the file holds a whole
sweep (at most one; a file without one, hand-made or generated, is taken as complete). A sweep cut short
— interrupted, stopped by its guard, its board lost, its host killed — is kept and marked partial
(:mod:`.sweep`): :attr:`BenchData.partial` says why and where, and ``hil calibrate fit`` refuses such a
file unless told to fit it anyway (``--allow-partial``).

Every malformed row raises :class:`InputFormatError` naming file, line and column.
"""

from __future__ import annotations

import csv
import enum
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from protocol.calibration import MIN_SUPPLY_V
from protocol.errors import InputFormatError
from protocol.messages import PULSE_MAX_US, PULSE_MIN_US

from .textfiles import read_text, write_atomic

MAX_BATTERY_V = 60.0
STATUS_KEY = "status:"
"""The comment that marks a bench CSV complete or partial (``# status: partial: why``)."""


class BenchKind(enum.Enum):
    """Which map a bench CSV calibrates."""

    ROTOR = "rotor"
    GIMBAL_RATE = "gimbal_rate"
    GIMBAL_ANGLE = "gimbal_angle"


MEASUREMENTS: dict[str, tuple[BenchKind, float]] = {
    "rpm": (BenchKind.ROTOR, math.pi / 30.0),
    "rotor_speed_rad_s": (BenchKind.ROTOR, 1.0),
    "gimbal_rate_rad_s": (BenchKind.GIMBAL_RATE, 1.0),
    "gimbal_rate_deg_s": (BenchKind.GIMBAL_RATE, math.pi / 180.0),
    "gimbal_angle_rad": (BenchKind.GIMBAL_ANGLE, 1.0),
    "gimbal_angle_deg": (BenchKind.GIMBAL_ANGLE, math.pi / 180.0),
}
"""Measurement column → (kind, factor to SI: rad/s or rad)."""

MEASURED_RANGE: dict[BenchKind, tuple[float, float]] = {
    BenchKind.ROTOR: (0.0, 100_000.0 * math.pi / 30.0),
    BenchKind.GIMBAL_RATE: (-100.0, 100.0),
    BenchKind.GIMBAL_ANGLE: (-4.0 * math.pi, 4.0 * math.pi),
}
"""What a bench can measure of each kind, SI (a rotor to 100 000 rpm, a gimbal to 100 rad/s, an angle to two
turns either way): a value past it parses but was never measured (1e160 rpm), and would reach the fit."""


@dataclass(frozen=True)
class BenchData:
    """One bench CSV, in SI units. Arrays of shape (n,): ``pulse_us`` µs, ``battery_v`` V (NaN where the
    file has no battery column), ``value`` rad/s (rotor speed, gimbal rate) or rad (gimbal angle);
    ``lines`` the 1-based line of each row in the file, so errors can name it."""

    kind: BenchKind
    path: str
    column: str
    pulse_us: np.ndarray
    battery_v: np.ndarray
    value: np.ndarray
    lines: np.ndarray
    partial: str | None = None
    """None for a whole sweep; else ``path:line: why`` of its ``# status: partial`` comment."""

    def __len__(self) -> int:
        return len(self.pulse_us)

    def where(self, i: int) -> str:
        """``path:line`` of row ``i``."""
        return f"{self.path}:{int(self.lines[i])}"

    def rows(self, indices: np.ndarray | list[int]) -> str:
        """The file lines of ``indices`` for a message, e.g. ``lines 12, 13, 40``."""
        lines = sorted(int(self.lines[i]) for i in indices)
        shown = ", ".join(str(n) for n in lines[:8])
        return f"line{'s' if len(lines) > 1 else ''} {shown}{', ...' if len(lines) > 8 else ''}"


def read_bench_csv(path: str | os.PathLike[str]) -> BenchData:
    """Read and check a bench CSV (see the module docstring)."""
    return parse_bench_csv(read_text(path, InputFormatError), str(path))


def parse_bench_csv(text: str, path: str = "<bench csv>") -> BenchData:
    """Parse bench CSV ``text``; ``path`` is used in error messages."""
    header: list[str] | None = None
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    status: tuple[int, str] | None = None
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped.startswith("#") and stripped[1:].strip().startswith(STATUS_KEY):
            if status is not None:
                raise InputFormatError(
                    f"a second status comment (the first is line {status[0]})", path, lineno
                )
            status = (lineno, _status(stripped[1:].strip()[len(STATUS_KEY) :].strip(), path, lineno))
        if not stripped or stripped.startswith("#"):
            continue
        try:
            cells = [c.strip() for c in next(csv.reader(io.StringIO(stripped)))]
        except csv.Error as exc:
            raise InputFormatError(f"not CSV: {exc}", path, lineno) from exc
        if header is None:
            header, header_line = cells, lineno
        else:
            rows.append((lineno, cells))
    if header is None:
        raise InputFormatError("no header line (an empty file?)", path)
    column, kind, factor = _measurement_column(header, path, header_line)
    if len(set(header)) != len(header):
        dupes = sorted({h for h in header if header.count(h) > 1})
        raise InputFormatError(f"duplicate column names {dupes}", path, header_line)
    if "pulse_us" not in header:
        raise InputFormatError(f"no 'pulse_us' column in the header {header}", path, header_line)
    has_battery = "battery_v" in header
    if kind is BenchKind.ROTOR and not has_battery:
        raise InputFormatError(
            "rotor data needs a 'battery_v' column (speed depends on it)", path, header_line
        )
    if not rows:
        raise InputFormatError("no data rows after the header", path, header_line)
    i_pulse, i_value = header.index("pulse_us"), header.index(column)
    i_battery = header.index("battery_v") if has_battery else None
    n = len(rows)
    pulse, battery, value, lines = np.empty(n), np.full(n, np.nan), np.empty(n), np.empty(n, dtype=np.int64)
    for r, (lineno, cells) in enumerate(rows):
        if len(cells) != len(header):
            raise InputFormatError(f"{len(cells)} fields, the header has {len(header)}", path, lineno)
        lines[r] = lineno
        pulse[r] = _number(cells[i_pulse], path, lineno, "pulse_us", PULSE_MIN_US, PULSE_MAX_US)
        if i_battery is not None:
            battery[r] = _number(
                cells[i_battery], path, lineno, "battery_v", 0.0, MAX_BATTERY_V, open_low=True
            )
            if kind is BenchKind.ROTOR and battery[r] < MIN_SUPPLY_V:
                # the rotor fit divides speed by it: a 1e-300 V glitch made a KV of 5e302 (overflow
                # warnings, then a float32 error) and one low row a misleading "starts at 1780 µs"
                raise InputFormatError(
                    f"{cells[i_battery]} V is no supply (a rotor map reads below {MIN_SUPPLY_V:g} V as none)",
                    path,
                    lineno,
                    "battery_v",
                )
        low, high = MEASURED_RANGE[kind]
        value[r] = factor * _number(cells[i_value], path, lineno, column, low / factor, high / factor)
    partial = None if status is None or not status[1] else f"{path}:{status[0]}: {status[1]}"
    return BenchData(kind, path, column, pulse, battery, value, lines, partial)


def _status(text: str, path: str, line: int) -> str:
    """'' for ``complete``; the reason (or ``partial``) for ``partial[: why]``."""
    if text == "complete":
        return ""
    head, _, why = text.partition(":")
    if head.strip() != "partial":
        raise InputFormatError(f"status {text!r}: need 'complete' or 'partial[: why]'", path, line)
    return why.strip() or "partial"


def _measurement_column(header: list[str], path: str, line: int) -> tuple[str, BenchKind, float]:
    found = [h for h in header if h in MEASUREMENTS]
    if len(found) != 1:
        raise InputFormatError(
            f"need exactly one measurement column of {sorted(MEASUREMENTS)}, found {found or 'none'}",
            path,
            line,
        )
    kind, factor = MEASUREMENTS[found[0]]
    return found[0], kind, factor


def _number(
    cell: str, path: str, line: int, column: str, lo: float, hi: float, open_low: bool = False
) -> float:
    try:
        x = float(cell)
    except ValueError:
        raise InputFormatError(f"{cell!r} is not a number", path, line, column) from None
    if not math.isfinite(x):
        raise InputFormatError(f"{cell!r} is not a finite number", path, line, column)
    if x < lo or (open_low and x == lo) or x > hi:
        low_text = f"above {lo:g}" if open_low else f"at least {lo:g}"
        rng = low_text if math.isinf(hi) else f"{low_text} and at most {hi:g}"
        raise InputFormatError(f"{cell} is out of range (must be {rng})", path, line, column)
    return x


def write_bench_csv(
    path: str | os.PathLike[str], columns: list[str], rows: list[tuple[str, ...]], comments: list[str]
) -> Path:
    """Write a bench CSV: ``# comment`` lines, the header, then the already formatted rows."""
    lines = [f"# {c}" for c in comments] + [",".join(columns)] + [",".join(r) for r in rows]
    return write_atomic(path, "\n".join(lines) + "\n")
