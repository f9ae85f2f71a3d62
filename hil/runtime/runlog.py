"""A run's directory: telemetry CSV, events log, summary — written incrementally so a killed run keeps
everything it logged.

Layout of ``RUN_DIR``::

    telemetry.csv   one row per control step: time, estimates, truth (simulated runs), commands, board
                    telemetry, link statistics (columns fixed when the run starts; header first)
    events.jsonl    one JSON object per line: board LOG messages, state changes, faults, resets
    summary.json    written when the run ends (atomically: a killed run has none, ``hil report`` copes)
    scenario.toml   the scenario the run used (a copy), when there was one
    *.png           plots (``hil report RUN_DIR`` redraws them)

Each row and event is flushed to the operating system as it is written, so SIGKILL loses at most a
partly written last line, which :func:`read_telemetry` drops and counts.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from protocol.errors import InputFormatError

TELEMETRY = "telemetry.csv"
EVENTS = "events.jsonl"
SUMMARY = "summary.json"


def new_run_dir(root: str | os.PathLike[str], label: str) -> Path:
    """A fresh directory ``root/YYYYmmdd-HHMMSS-label[-n]`` (never an existing one)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in label) or "run"
    base = Path(root) / f"{stamp}-{safe}"
    path, n = base, 1
    while True:
        try:
            path.mkdir(parents=True)
            return path
        except FileExistsError:
            n += 1
            path = base.with_name(f"{base.name}-{n}")


Tap = Callable[[Mapping[str, Any]], None]
"""Called with each row or event record right after it is written (a run's observer, :mod:`hil.gcs`)."""


class CsvLog:
    """Rows of numbers under a fixed header, line-flushed. Missing values are written empty (read as NaN).
    ``tap`` (optional) sees each row after it is written."""

    def __init__(self, path: str | os.PathLike[str], columns: Sequence[str], tap: Tap | None = None) -> None:
        if len(set(columns)) != len(columns):
            raise ValueError(f"duplicate CSV columns: {list(columns)}")
        self.path = Path(path)
        self.columns = tuple(columns)
        self._file: io.TextIOWrapper | None = open(self.path, "w", newline="", buffering=1)  # noqa: SIM115
        self._writer = csv.writer(self._file)
        self._writer.writerow(self.columns)
        self.rows = 0
        self.tap = tap

    def write(self, row: Mapping[str, Any]) -> None:
        """Write one row (unknown keys raise KeyError: a typo must not silently drop a column)."""
        unknown = set(row) - set(self.columns)
        if unknown:
            raise KeyError(f"{self.path.name}: no column(s) {sorted(unknown)}")
        if self._file is None:
            raise ValueError(f"{self.path}: log is closed")
        self._writer.writerow([_cell(row.get(c)) for c in self.columns])
        self._file.flush()
        self.rows += 1
        if self.tap is not None:
            self.tap(row)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> CsvLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _cell(value: Any) -> str:
    """A CSV cell: floats (Python or numpy) at full precision, NaN and None empty."""
    if value is None:
        return ""
    if isinstance(value, float | np.floating):
        return "" if math.isnan(value) else repr(float(value))
    if isinstance(value, np.integer | np.bool_):
        return str(int(value))
    return str(value)


class EventLog:
    """JSON lines, each flushed: ``{"t": seconds, "kind": ..., ...}``. ``tap`` (optional) sees each record
    after it is written."""

    def __init__(self, path: str | os.PathLike[str], tap: Tap | None = None) -> None:
        self.path = Path(path)
        self._file: io.TextIOWrapper | None = open(self.path, "a", buffering=1)  # noqa: SIM115
        self.count = 0
        self.tap = tap

    def write(self, t: float, kind: str, **fields: Any) -> None:
        if self._file is None:
            raise ValueError(f"{self.path}: log is closed")
        record = {"t": t, "kind": kind, **fields}
        self._file.write(json.dumps(record, default=str) + "\n")
        self._file.flush()
        self.count += 1
        if self.tap is not None:
            self.tap(record)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def write_summary(run_dir: str | os.PathLike[str], summary: Mapping[str, Any]) -> Path:
    """Write ``summary.json`` atomically (a reader never sees half a file)."""
    path = Path(run_dir) / SUMMARY
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(summary, indent=2, default=_json_default, allow_nan=True) + "\n")
    os.replace(tmp, path)
    return path


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return str(value)


@dataclass
class Telemetry:
    """A telemetry CSV read back: ``columns[name]`` is a float array (NaN where empty)."""

    columns: dict[str, np.ndarray]
    rows: int
    dropped_lines: int  # a torn last line (killed run) or malformed lines, counted not fatal

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __contains__(self, name: str) -> bool:
        return name in self.columns


def read_telemetry(path: str | os.PathLike[str]) -> Telemetry:
    """Read a run's telemetry CSV. A line with the wrong number of cells or a non-number is dropped and
    counted (a run killed mid-write leaves one); a missing or header-less file is an InputFormatError."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputFormatError(f"cannot read telemetry: {exc.strerror}", str(path)) from exc
    reader = csv.reader(io.StringIO(text))
    try:
        header = next(reader)
    except StopIteration:
        raise InputFormatError("empty file (no header)", str(path), 1) from None
    values: list[list[float]] = []
    dropped = 0
    for cells in reader:
        if len(cells) != len(header):
            dropped += 1
            continue
        try:
            values.append([float(c) if c != "" else math.nan for c in cells])
        except ValueError:
            dropped += 1
    data = np.array(values, dtype=float).reshape(len(values), len(header))
    return Telemetry({name: data[:, i] for i, name in enumerate(header)}, len(values), dropped)


def read_events(path: str | os.PathLike[str]) -> tuple[list[dict[str, Any]], int]:
    """Events of a run and the number of unreadable (torn) lines."""
    events: list[dict[str, Any]] = []
    bad = 0
    p = Path(path)
    if not p.exists():
        return events, 0
    for line in p.read_text().splitlines():
        try:
            events.append(json.loads(line))
        except json.JSONDecodeError:
            bad += 1
    return events, bad
