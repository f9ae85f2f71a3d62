"""phyphox (RWTH Aachen) "Export data → CSV": one CSV per sensor, from one experiment or several.

Layouts read (docs/formats.md):

- one experiment with several sensors: ``Accelerometer.csv`` ("Acceleration with g"), ``Gyroscope.csv``,
  ``Magnetometer.csv`` — one clock, ``Time (s)`` since the experiment started;
- the built-in single-sensor experiments, each exported on its own: a zip (or its folder) holding
  ``Raw Data.csv`` and ``meta/time.csv``. Several of them in one folder (or zips in one folder) are read
  together: each file is on its own clock starting at 0, and its export's ``meta/time.csv`` (``"event",
  "experiment time","system time","system time text"``, rows ``START``/``PAUSE``) gives the system time of
  its START, which puts every file on one clock (a START after a PAUSE: the stretch it resumes, placed
  by its own system time — the experiment time stands still while paused);
- a custom experiment's buffers, e.g. ``Acceleration.csv`` with ``"time","Acceleration x"`` (no unit:
  SI assumed).

What a file holds is read from its x column's label — ``Acceleration``/``Accelerometer`` (gravity
included), ``Gyroscope``, ``Magnetic field``/``Magnetometer`` — or, when that is a bare ``"X (m/s^2)"`` (as
current phyphox writes an experiment's files), from the file's name (``Accelerometer.csv``,
``Gyroscope.csv``, ``Magnetometer.csv``), or from its export folder's name (a built-in export's ``Raw
Data.csv``). Linear (gravity-free) acceleration — ``Linear Accelerometer.csv`` (current phyphox), ``Linear
Acceleration.csv`` (older), a ``Linear Acceleration x`` column, an "Acceleration (without g)" export —
cannot give the gravity direction: it is ignored beside an accelerometer with g, refused alone. Units in
parentheses convert to SI (:mod:`hil.logs.columns`), as do those of a row of units under the header
(:func:`~hil.logs.table.units_under`); only the time and x, y, z columns are parsed (any
other may hold text). Dialects: comma, tab or semicolon separated, decimal
point or decimal comma (told from the first data line). Without a magnetometer file the log is 6-axis
(heading unobserved). An Excel (``.xls``) export is refused with a message to export CSV.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import partial

import numpy as np
from numpy.typing import NDArray

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from hil.logs.columns import SENSOR_NAMES, axis_column, axis_columns, is_time_label, time_column
from hil.logs.rows import is_content
from hil.logs.sensorlogger import MAX_RECORDING_S, clock_of, holds_nothing, plain_name
from hil.logs.table import (
    Container,
    Header,
    content_head,
    one_copy,
    read_table,
    sniff_dialect,
    split_header,
)
from protocol.errors import InputFormatError

NAME = "phyphox"
_HOLDS = {
    SensorKind.ACC: "accelerometer",
    SensorKind.GYR: "gyroscope",
    SensorKind.MAG: "magnetometer",
    None: "linear acceleration",
}
"""What a file of each kind holds, for messages (None: gravity removed, :data:`_LINEAR`)."""
TIME_CSV = "meta/time.csv"
EXCEL = (".xls", ".xlsx")
# phyphox writes its labels in the phone's language ("Beschleunigung x (m/s^2)", "Accélération x",
# "Giroscopio x"): each pattern takes English and the languages' words phyphox translates them to
# (German, French, Spanish, Italian, Portuguese, Dutch, Polish), lower case, accents either way
_LINEAR = re.compile(
    r"linea[rl]|lin[ée]aire|liniow|without\s*g\b|ohne\s*g\b|sans\s*g\b|sin\s*g\b|senza\s*g\b|sem\s*g\b",
    re.IGNORECASE,
)
_KINDS = (
    (re.compile(r"acc[eé]l[eé]r|acelera|beschleunig|versnell|przyspiesz", re.IGNORECASE), SensorKind.ACC),
    (re.compile(r"gyro|giro|[zż]yro", re.IGNORECASE), SensorKind.GYR),
    (re.compile(r"magn[eé]t", re.IGNORECASE), SensorKind.MAG),
)


def excel_message(where: str) -> InputFormatError:
    return InputFormatError(
        "an Excel export: hil reads CSV; in phyphox use Export data -> 'CSV (Comma, decimal point)' "
        "(any of its CSV options works)",
        where,
    )


@dataclass(frozen=True)
class _File:
    """A sensor CSV of the export: member name, what it holds, its dialect and its export group."""

    name: str
    kind: SensorKind | None  # None: gravity-free (linear) acceleration
    delimiter: str
    decimal_comma: bool
    group: str  # the folder of its export ("" at the top): where its meta/time.csv is


def _csv_members(c: Container) -> list[str]:
    """The export's sensor tables: every ``.csv`` member but its ``meta/`` files, gzipped ones too (a folder
    gzipped file by file, ``gzip -r``: the container reads a ``.gz`` decompressed, as in every format; they
    were passed over, and the export was "not a recognised log")."""
    return [
        n for n in c.names() if n.lower().endswith((".csv", ".csv.gz")) and "meta/" not in f"/{n}".lower()
    ]


def _classify(c: Container, name: str) -> _File | None:
    """The file's sensor, or None if it is not a phyphox sensor table (see :func:`_kind`)."""
    lines = c.head(name, 8)
    numbered = [(i, line) for i, line in enumerate(lines, 1) if is_content(line)]
    head = content_head(c, name, 2, units_row=True)  # a row of units under the header: in its names
    if not head:
        return None
    delimiter, decimal_comma = sniff_dialect(head)
    cells = split_header(head[0], delimiter)
    time_at = next((i for i, cell in enumerate(cells) if is_time_label(cell)), None)
    if time_at is None:  # first as phyphox writes it; after a column a tool added, too
        return None
    if any((clock_of(cell) or ("",))[0] == "seconds_elapsed" for cell in cells):
        return None  # Sensor Logger's, with or without units (its epoch time in ns is no phyphox clock)
    # the x column as _stream will choose it, the sensor not yet known: any sensor's full name is exact
    x_col = axis_column(cells, "x", _ANY_SENSOR, "sensor", c.where(name), numbered[0][0], (cells[time_at],))
    if x_col is None:
        return None
    group = name.rsplit("/", 1)[0] + "/" if "/" in name else ""
    found = _kind(x_col, name.rsplit("/", 1)[-1], group.rstrip("/").rsplit("/", 1)[-1])
    if found is _NOT_A_SENSOR:
        return None
    kind = found if isinstance(found, SensorKind) else None
    return _File(name, kind, delimiter, decimal_comma, group)


_ANY_SENSOR = tuple(name for names in SENSOR_NAMES.values() for name in names)
"""The full names of every sensor (``Gyroscope``, ``Magnetic field``, …): a file's x column is found
before its sensor is known (it says the sensor); ``Linear Acceleration x`` is a partial name, so that a
bare ``X (rad/s)`` wins over it."""
_NOT_A_SENSOR = object()
MAX_TIME_S = 1e10
"""The latest a sample's time may typically be (s; the median of a file's): an experiment's clock starts at
0, a custom experiment may count seconds since the epoch (1.7e9); 1e10 s is 2286 in seconds since the
epoch (the end of the epochs :mod:`hil.logs.sensorlogger` takes), and anything beyond it read as seconds
is refused rather than replayed as centuries: an epoch in ms, µs or ns (1.7e12 on), and ns since the
phone booted (Android's sensor clock, 1e10 after 10 s of uptime; it was taken as seconds up to 1e11, 100
s of uptime)."""


def _kind(x_col: str, file_name: str, folder: str) -> SensorKind | None | object:
    """What a table holds, from the labels that can say it: gravity-free acceleration (None) when its x
    column or its file's name says "linear" (or "without g"); else the sensor its x column names
    (``"Acceleration x (m/s^2)"``), else the one its file's name names (an experiment's
    ``Accelerometer.csv`` whose columns are ``"X (m/s^2)"``), else the one its export folder's name names
    (a built-in export's ``Raw Data.csv``); :data:`_NOT_A_SENSOR` when none does (a barometer, a
    location)."""
    if _LINEAR.search(x_col) or _LINEAR.search(file_name):
        return None
    for label in (x_col, file_name):
        kind = next((k for pattern, k in _KINDS if pattern.search(label)), None)
        if kind is not None:
            return kind
    if _LINEAR.search(folder):
        return None
    return next((k for pattern, k in _KINDS if pattern.search(folder)), _NOT_A_SENSOR)


def detect(c: Container) -> bool:
    if any(n.lower().endswith(EXCEL) for n in c.names()) and not _csv_members(c):
        raise excel_message(str(c.path))
    return any(_classify(c, n) is not None for n in _csv_members(c)[:20])


def read(c: Container) -> SensorLog:
    files = [f for f in (_classify(c, n) for n in _csv_members(c)) if f is not None]
    if not files and any(n.lower().endswith(EXCEL) for n in c.names()):
        raise excel_message(str(c.path))
    notes = ["phyphox export: units converted to SI"]
    chosen: dict[SensorKind, _File] = {}
    for f in files:
        if f.kind is not None and f.kind not in chosen:
            chosen[f.kind] = f
        elif f.kind is not None and plain_name(f.name) == plain_name(chosen[f.kind].name):
            _, same = one_copy(c, [chosen[f.kind].name, f.name])  # differing bytes: an error naming both
            if same is not None:
                notes.append(same)
        elif f.kind is not None and f.group != chosen[f.kind].group:
            raise _side_by_side(c, f.kind, chosen[f.kind], f)
        elif f.kind is not None:
            notes.append(f"{f.name}: a second {f.kind.label} file, ignored (using {chosen[f.kind].name})")
    empty = _empty_files(c, chosen)
    linear = [f.name for f in files if f.kind is None]
    if SensorKind.ACC not in chosen and linear:
        raise InputFormatError(
            f"only linear acceleration ({', '.join(linear)}: gravity removed): the estimator needs the "
            "gravity direction; record with phyphox's 'Acceleration with g'",
            c.where(linear[0]),
        )
    for kind in (SensorKind.ACC, SensorKind.GYR):
        if kind not in chosen and kind in empty:  # the file is there, holding nothing: named, as such
            raise InputFormatError(
                f"{empty[kind].rsplit('/', 1)[-1]} is empty (0 bytes): no {_HOLDS[kind]} readings",
                c.where(empty[kind]),
            )
        if kind not in chosen:  # one sensor's export alone (phyphox exports one table per experiment)
            found = ", ".join(f"{f.name}: {_HOLDS[f.kind]}" for f in files) or "no sensor tables"
            raise InputFormatError(
                f"no {_HOLDS[kind]} file (found {found}): the estimator needs the gyroscope and the "
                "accelerometer (with g); put each sensor's export in one folder and replay the folder",
                str(c.path),
            )
    if linear:
        notes.append(f"ignored (gravity removed): {', '.join(linear)}")
    if SensorKind.MAG not in chosen and SensorKind.MAG in empty:
        notes.append(
            f"{empty[SensorKind.MAG]} is empty (0 bytes): 6-axis log, heading not observed (gyroscope only, "
            "drifting)"
        )
    elif SensorKind.MAG not in chosen:
        notes.append("no magnetometer file: 6-axis log, heading not observed (gyroscope only, drifting)")
    clocks = _clock_offsets(c, {f.group for f in chosen.values()}, notes)
    streams = {}
    for kind, f in chosen.items():
        stream = _stream(c, f, clocks[f.group], notes)
        if not len(stream.t):  # a header only: the phone lacks the sensor, or it never started
            if kind is not SensorKind.MAG:  # it was "log has no GYR samples", naming the folder
                raise InputFormatError(
                    f"no samples (a header only): no {_HOLDS[kind]} readings", c.where(f.name)
                )
            # as Sensor Logger's header-only Magnetometer.csv is; it was refused, "an empty MAG stream"
            notes.append(f"{f.name} has no samples (a header only): 6-axis log, heading not observed")
            continue
        streams[kind] = stream
    acc_norm = float(np.nanmedian(np.linalg.norm(streams[SensorKind.ACC].xyz, axis=1)))
    if acc_norm < 3.0:
        raise InputFormatError(
            f"the accelerometer's median norm is {acc_norm:.2f} m/s^2: gravity is missing (linear "
            "acceleration?); record with phyphox's 'Acceleration with g'",
            c.where(chosen[SensorKind.ACC].name),
        )
    return SensorLog(streams, str(c.path), NAME, None, tuple(notes))


def _empty_files(c: Container, chosen: dict[SensorKind, _File]) -> dict[SensorKind, str]:
    """The sensor files of the export that hold nothing but blank lines (0 bytes: phyphox, a copy or a
    sync cut short wrote nothing), by the sensor their name (or their export folder's) says, for the
    sensors no file with a header holds: :func:`_classify` has no header to read them by, and a 0-byte
    ``Gyroscope.csv`` was refused as "no gyroscope file" and a 0-byte ``Magnetometer.csv`` noted as "no
    magnetometer file", the file that is there never named. Sensor Logger's reader says "X.csv is
    empty" (:func:`hil.logs.sensorlogger.holds_nothing`); one wording."""
    empty: dict[SensorKind, str] = {}
    for name in _csv_members(c):
        folder, _, base = name.rpartition("/")
        kind = _kind("", base, folder.rsplit("/", 1)[-1])
        if (
            isinstance(kind, SensorKind)
            and kind not in chosen
            and kind not in empty
            and holds_nothing(c, name)
        ):
            empty[kind] = name
    return empty


def _side_by_side(c: Container, kind: SensorKind, first: _File, second: _File) -> InputFormatError:
    """Two exports (folders) each holding a ``kind`` file: two experiments, recordings side by side, as
    Sensor Logger's folders side by side are (:func:`hil.logs.sensorlogger.read`) — refused naming the
    archive and both, never one read and the other passed over. The first export's accelerometer and
    gyroscope were read and the second's noted as ignored — or, the second export holding the only
    magnetometer, its readings joined to the first recording's motion. Single-sensor exports side by
    side (each a sensor the others lack) are one recording's, joined by their ``meta/time.csv``."""
    exports = ", ".join(f"{f.group.rstrip('/') or 'the top'} ({f.name})" for f in (first, second))
    return InputFormatError(
        f"phyphox exports side by side that each hold a {_HOLDS[kind]} file: {exports}: two experiments' "
        "recordings; replay one export (unpack an archive first)",
        str(c.path),
    )


def _stream(c: Container, f: _File, clock: _Clock, notes: list[str]) -> SensorStream:
    kind = f.kind
    assert kind is not None
    use = partial(_sensor_columns, kind=kind)
    table = read_table(
        c, f.name, f.delimiter, decimal_comma=f.decimal_comma, min_columns=4, use=use, units_row=True
    )
    notes.extend(table.layout_notes())
    t_col, t_scale = time_column(table.columns, table.source, table.header_line)
    axes = axis_columns(table.columns, kind, table.source, table.header_line, skip=(t_col,))
    xyz = np.column_stack([table.column(col) * factor for col, factor in axes])
    t = table.column(t_col) * t_scale
    finite = np.abs(t[np.isfinite(t)])
    if len(finite) and float(np.median(finite)) > MAX_TIME_S:
        raise InputFormatError(
            f"times of {float(np.median(finite)):.4g} s: no experiment time (s since it started) but a "
            "time since the epoch in a finer unit (a Sensor Logger file, whose 'time' is in ns?)",
            table.source,
            table.header_line,
            t_col,
        )
    return SensorStream(kind, clock.place(t), xyz)


def _sensor_columns(header: Header, kind: SensorKind) -> list[str]:
    """The columns a sensor file is read from: its time column and its x, y, z (by name: a column
    beside them — a label, an accuracy, an empty one — is never parsed)."""
    t_col, _ = time_column(header.columns, header.source, header.line)
    axes = axis_columns(header.columns, kind, header.source, header.line, skip=(t_col,))
    return [t_col, *(col for col, _ in axes)]


@dataclass(frozen=True)
class _Clock:
    """Where an export's experiment times lie on the exports' one clock: from each START of its
    ``meta/time.csv`` on (``starts``, experiment time s, increasing), ``shifts`` s added (its system time
    then, less its experiment time, less the exports' earliest start). phyphox's experiment time stands
    still while an experiment is paused and goes on from there when it is resumed, while the system time
    goes on: each stretch between a START and the next has a shift of its own, later by the pause."""

    starts: tuple[float, ...] = (0.0,)
    shifts: tuple[float, ...] = (0.0,)

    def place(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Experiment times ``t`` (s) on the one clock: each shifted by its stretch's shift (a time before
        the first START by the first's; NaN stays NaN)."""
        if len(self.starts) == 1:
            return t + self.shifts[0]
        at = np.clip(np.searchsorted(np.asarray(self.starts), t, side="right") - 1, 0, len(self.starts) - 1)
        return t + np.asarray(self.shifts)[at]


def _clock_offsets(c: Container, groups: set[str], notes: list[str]) -> dict[str, _Clock]:
    """Each export's :class:`_Clock`, which puts them all on one clock. A single export needs no
    ``meta/time.csv`` (its files share its experiment time); when it has one, its pauses are placed as
    several exports' are: its experiment time stood still while paused, so without them a recording
    paused for minutes read as one unbroken stretch, the motion before and after the pause joined with
    no gap and no word. A single export's ``meta/time.csv`` that cannot be read (another app version's
    layout) is noted and its tables read on their own clock, as before it was read at all."""
    runs: dict[str, list[tuple[float, float]]] = {}
    for g in sorted(groups):
        name = next((n for n in (g + TIME_CSV, g + TIME_CSV + ".gz") if c.has(n)), g + TIME_CSV)
        if c.has(name) and len(groups) == 1:
            try:
                runs[g] = _start_system_times(c, name)
            except InputFormatError as unreadable:  # its tables share one clock: read them, say so
                notes.append(f"{unreadable}: not used; a pause of the recording, if any, is not placed")
        elif c.has(name):
            runs[g] = _start_system_times(c, name)
        elif len(groups) > 1:
            where = g or "the top folder"
            raise InputFormatError(
                f"several exports ({', '.join(sorted(groups))}) and no {TIME_CSV} in {where}: "
                "their clocks cannot be aligned (each starts at 0)",
                str(c.path),
            )
    if not runs:  # a single export without meta/time.csv: its own clock
        return dict.fromkeys(groups, _Clock())
    starts = {g: run[0][1] for g, run in runs.items()}
    first = min(starts.values())
    if max(starts.values()) - first > MAX_RECORDING_S:  # exports of one recording start within its length
        median = float(np.median(list(starts.values())))
        odd = max(sorted(starts), key=lambda g: abs(starts[g] - median))  # the one farthest from the rest
        raise InputFormatError(
            f"its start ({starts[odd]:.6g} s) lies {abs(starts[odd] - median):.6g} s from the exports' "
            f"median start ({median:.6g} s): exports of one recording start within "
            f"{MAX_RECORDING_S // 86400} days of each other; its 'system time' is corrupt or it is "
            "another recording's",
            str(c.path / (odd + TIME_CSV)),
        )
    if len(groups) > 1:
        notes.append(
            "exports aligned by meta/time.csv: "
            + ", ".join(f"{g.rstrip('/')} +{s - first:.3f} s" for g, s in sorted(starts.items()))
        )
    clocks = {}
    for g, run in sorted(runs.items()):
        clocks[g] = _Clock(tuple(e for e, _ in run), tuple(s - first for _, s in run))
        if len(run) > 1:
            paused = ", ".join(
                f"at {e:.3f} s for {s - p:.3f} s" for (e, s), (_, p) in zip(run[1:], run[:-1], strict=True)
            )
            notes.append(
                f"{g + TIME_CSV}: the export was paused and resumed {len(run) - 1} time(s) (its experiment "
                f"time stood still; resumed {paused}): each stretch placed by its START's system time"
            )
    return clocks


def _start_system_times(c: Container, name: str) -> list[tuple[float, float]]:
    """(experiment time, system time less experiment time) of each START row, s — the system time (s since
    the epoch) at which each stretch's experiment time would have been 0 — in order: the first is the
    export's start, each later one a resume after a PAUSE. The file is in its export's dialect (phyphox
    writes it with the data's separator and decimal mark); its ``event`` is text, read as 0 for START, and
    its ``system time text`` is never parsed."""
    delimiter, decimal_comma = sniff_dialect([line for line in c.head(name, 8) if line.strip()])
    table = read_table(
        c,
        name,
        delimiter,
        decimal_comma=decimal_comma,
        min_columns=3,
        use=_TIME_COLUMNS,
        converters={"event": _start_event},
    )
    rows = np.flatnonzero(table.column("event") == 0.0)
    if not len(rows):
        raise InputFormatError("no START event", table.source, table.header_line)
    run: list[tuple[float, float]] = []
    for row in rows:
        system = float(table.column("system time")[row])
        experiment = float(table.column("experiment time")[row])
        start = system - experiment
        if not (math.isfinite(system) and math.isfinite(experiment) and abs(start) <= MAX_EPOCH_S):
            raise InputFormatError(
                f"its START event's system time {system!r} s less its experiment time {experiment!r} s is "
                f"no time since the epoch (within ±{MAX_EPOCH_S:.0e} s): the exports cannot be aligned by it",
                table.source,
            )
        if run and not (experiment >= run[-1][0] and start >= run[-1][1]):
            raise InputFormatError(
                f"a START at experiment time {experiment!r} s, system time {system!r} s, before the one "
                "before it: the experiment time and the system time of a resume go on from the pause",
                table.source,
            )
        run.append((experiment, start))
    return run


_TIME_COLUMNS = ("event", "experiment time", "system time")
MAX_EPOCH_S = 1e11
"""s: the largest |system time| at experiment time 0 taken as a time since the epoch (the year ~5100; a
phone's is ~1.8e9). Beyond it, or not finite (1e308 less -1e308 overflowed, and every time of that export
became infinite), the exports' clocks cannot be aligned: an error naming ``meta/time.csv``."""


def _start_event(cell: str) -> float:
    """0 for a START event, 1 for any other (PAUSE)."""
    return 0.0 if cell.strip('"') == "START" else 1.0
