"""Sensor Logger (Kelvin Choi's app, Android/iOS) CSV export: a folder or its zip of per-sensor CSVs.

Current exports have the header ``time,seconds_elapsed,z,y,x`` — note the **z, y, x** order; older ones
(late 2022) name their axes like ``GYROSCOPE X (rad/s)``. Columns are found by name
(:mod:`hil.logs.columns`), never by position, and only the clocks and axes are parsed (any other column
may hold text: :func:`sensor_columns`); a re-save may put units on the clocks too (``time (ns)``,
``seconds_elapsed [s]``: :func:`clock_of`), or in a row of units under the header
(:func:`~hil.logs.table.units_under`). ``time`` is Unix epoch in ns (shared by all sensors), read
as exact integers and converted to seconds since the first sample of any sensor; without it,
``seconds_elapsed`` (s since the recording started, also shared). A re-save's ``time`` in s, ms or µs
keeps its fraction; one written as an ISO-8601 date is read (:func:`iso_time_ns`); one a spreadsheet
rounded (``1.67907E+18``) gives way to ``seconds_elapsed`` for every file (:class:`_CoarseTime`); files
on different clocks are refused (:func:`_same_clock`). Units (the app's unit reference): m/s²
(g = 9.80665), rad/s, µT; axes are Android's sensor frame (on iOS, with "Standardise Units & Frames" on;
with it off, as ``Metadata.csv`` says, or before the app had it, the acceleration's axes are negated to
Android's: :func:`_ios_standardised`; so are those of an ``AccelerometerUncalibrated.csv`` in g, which only
iOS writes, where no ``Metadata.csv`` states the platform: :func:`_uncalibrated_in_g`).

Accelerometers, in order of preference: ``TotalAcceleration.csv`` (specific force *including* gravity);
``Accelerometer.csv`` (the *user* acceleration, gravity removed) plus ``Gravity.csv`` (their sum, gravity
interpolated to the accelerometer's times); ``AccelerometerUncalibrated.csv`` (the raw accelerometer,
gravity included; in g rather than m/s² when its median norm says so). ``Accelerometer.csv`` alone gives
no gravity direction and is refused; so is ``Gravity.csv`` alone, named (:data:`GRAVITY_ALONE`: the phone's
filtered estimate, no measurement). Gyroscope and magnetometer: the calibrated files, else the
``…Uncalibrated.csv`` ones (noted). Without a magnetometer file the log is 6-axis (heading unobserved).

:func:`assemble` does the choosing and the clock for any :class:`Export`, so the app's JSON export
(:mod:`hil.logs.sensorlogger_json`) is read exactly as its CSV export is.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from functools import partial

import numpy as np

from hil.estimation.sensors import SensorKind, SensorLog, SensorStream
from hil.logs.columns import axis_columns
from hil.logs.rows import BadCell, is_content, number, shown
from hil.logs.table import (
    Container,
    Header,
    Table,
    content_head,
    one_copy,
    read_table,
    sniff_dialect,
    split_header,
    text_lines,
)
from protocol.errors import InputFormatError

NAME = "sensorlogger"
G = 9.80665
GYR_FILES = ("Gyroscope.csv", "GyroscopeUncalibrated.csv")
MAG_FILES = ("Magnetometer.csv", "MagnetometerUncalibrated.csv")
ACC_FILES = ("TotalAcceleration.csv", "Accelerometer.csv", "AccelerometerUncalibrated.csv")
_TIME = ("time", "seconds_elapsed")
_CLOCK = re.compile(r"^\s*(time|seconds_elapsed)\s*(?:\(\s*([^()]*?)\s*\)|\[\s*([^\[\]]*?)\s*\])?\s*$", re.I)
"""A clock column's header cell: ``time`` or ``seconds_elapsed``, in any letter case, with or without a
unit in parentheses or brackets (``time (ns)``, ``seconds_elapsed [s]``: a tool that re-saved the export
with units in its header)."""
_EPOCH_LABELS = ("", "ns", "µs", "μs", "us", "ms")
"""The units a Sensor Logger ``time`` header may carry: none (the app's), or an epoch's fine unit."""
ELAPSED_UNITS = {"": 1.0, "s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
"""``seconds_elapsed`` header units → s: the app writes seconds, unlabelled."""


def clock_of(cell: str) -> tuple[str, str] | None:
    """(``time`` or ``seconds_elapsed``, its unit in lower case, "" for none) when the header cell names a
    clock column, else None."""
    m = _CLOCK.match(cell)
    if m is None:
        return None
    return m.group(1).lower(), (m.group(2) or m.group(3) or "").lower()


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
MAX_RECORDING_S = 31 * 86400
"""The farthest a row's ``time`` may lie from its file's median (s): a recording of a month. A row
farther off (one at 1e18 ns, 2001, in a recording of 2023: a corrupt timestamp) would become the clock's
origin and put every other sample two decades on; it is a NaN sample instead, noted."""
NO_TIME = np.iinfo(np.int64).min
"""The int64 ``time`` of a row that has none usable (no number, beyond int64, no time of the recording):
NaN once on the log's clock. Never the median's or a neighbour's: a time given to a row it does not have
put its NaN sample in the middle of the recording, and ``hil replay --port`` (which releases a stream at
the latest time recorded up to each sample) held the samples after it back until then."""


def members(c: Container) -> dict[str, str] | None:
    """Sensor Logger's files in ``c`` (:data:`_KNOWN`, matched whatever their letter case) → the members
    holding them: at the top, or all in one folder below it (an export zipped twice, a folder holding the
    export's zip: ``Rec/Gyroscope.csv``). None when they lie in several folders (recordings side by side:
    each is a log of its own)."""
    groups = _by_folder(c)  # every folder holding one: a second recording's is never passed over
    return next(iter(groups.values()), {}) if len(groups) <= 1 else None


def _other_copies(c: Container, member: str) -> list[str]:
    """The members beside ``member``, in its folder, that are the same file of the app's by name
    (``Gyroscope.csv.gz`` beside ``Gyroscope.csv``, a ``gyroscope.csv`` beside it): :func:`_by_folder`
    keeps the first of them, and the others were passed over without a word."""
    folder, _, base = member.rpartition("/")
    plain = plain_name(base).lower()
    return [
        m
        for m in sorted(c.names())
        if m != member
        and m.rpartition("/")[0] == folder
        and plain_name(m.rpartition("/")[2]).lower() == plain
    ]


def _sensor_files(files: Mapping[str, str]) -> bool:
    return any(name != "Metadata.csv" for name in files)


def _by_folder(c: Container) -> dict[str, dict[str, str]]:
    """Sensor Logger's files in ``c`` by the folder they lie in: folder → (the app's file name → member).
    A ``Metadata.csv`` in a folder of no sensor file above a folder of them (``Metadata.csv`` at the top
    beside ``Rec/Gyroscope.csv``: moved, or zipped beside the folder) is that recording's, when the
    recording has none of its own: it was dropped without a word, and an iOS recording replayed in
    Android's frames, upside down (:func:`read` notes where it was read from, and any left unread)."""
    lower = {name.lower(): name for name in _KNOWN}
    groups: dict[str, dict[str, str]] = {}
    for member in sorted(c.names()):
        folder, _, base = member.rpartition("/")
        name = lower.get(plain_name(base).lower())
        if name is not None:
            groups.setdefault(folder, {}).setdefault(name, member)
    sensors = {folder: files for folder, files in groups.items() if _sensor_files(files)}
    if not sensors:
        return groups  # a Metadata.csv in a folder of no sensor file: not a recording
    for folder, files in sensors.items():  # the metadata of a recording whose files lie a folder down
        above = [f for f in groups if f not in sensors and (not f or folder.startswith(f + "/"))]
        if "Metadata.csv" not in files and above:
            files["Metadata.csv"] = groups[max(above, key=len)]["Metadata.csv"]  # the nearest
    return sensors


def plain_name(base: str) -> str:
    """A member's file name without a ``.gz`` (a file gzipped by hand or by a backup tool:
    :class:`~hil.logs.table.Container` decompresses it as it reads)."""
    return base[:-3] if base.lower().endswith(".gz") else base


def detect(c: Container) -> bool:
    """Whether ``c`` is a Sensor Logger export, told by the header of its first sensor file that has one.
    An empty file (a sensor the app wrote nothing for, a copy cut short) says nothing either way: the
    next one is asked, and :func:`read` names the empty one if it is needed — rather than the export
    going unrecognised and its other files being offered as logs of their own. Exports side by side (an
    archive of two recordings) are one too: :func:`read` refuses them, saying so."""
    return any(_detects(c, files) for files in _by_folder(c).values())


def _detects(c: Container, files: Mapping[str, str]) -> bool:
    """Whether the files of one folder (:func:`_by_folder`) are a Sensor Logger export (:func:`detect`)."""
    for name in (*GYR_FILES, *ACC_FILES, *MAG_FILES):
        if name not in files:
            continue
        head = content_head(c, files[name], 3, units_row=True)
        if not head:
            continue
        delimiter = sniff_dialect(head)[0]
        cells = [x.lower() for x in split_header(head[0], delimiter)]
        clocks = dict(clock for clock in map(clock_of, cells) if clock is not None)
        epoch = clocks.get("time") in _EPOCH_LABELS  # phyphox's "Time (s)" is no epoch
        labelled = any(" x (" in x for x in cells)  # the app's older "GYROSCOPE X (rad/s)"
        return "seconds_elapsed" in clocks or (
            epoch
            and (
                (labelled and not _starts_near_zero(head, cells, delimiter))
                or _starts_at_an_epoch(head, cells, delimiter)
            )
        )
    return False


def _starts_near_zero(head: Sequence[str], cells: Sequence[str], delimiter: str) -> bool:
    """Whether the first row's ``time`` is a number below 1e9 in size: an experiment's time from 0, as
    phyphox's ``"Time (ms)","Gyroscope x (rad/s)"`` (labelled as the app's older exports are, and claimed
    for them: refused as no epoch), never an epoch in ms or finer."""
    if len(head) < 2:
        return False
    column = next(i for i, cell in enumerate(cells) if (clock_of(cell) or ("",))[0] == "time")
    row = split_header(head[1], delimiter)
    try:
        cell = row[column].strip().strip('"')
        value = float(cell if delimiter == "," else cell.replace(",", "."))  # a decimal comma
    except (ValueError, IndexError):
        return False
    return math.isfinite(value) and abs(value) < 1e9


def _starts_at_an_epoch(head: Sequence[str], cells: Sequence[str], delimiter: str) -> bool:
    """Whether the first row's ``time`` is an integer time since the epoch (:data:`EPOCH_UNITS`) or since
    the phone booted in ns (:data:`BOOT_NS`; 1e9 on, a second of uptime): a file ``time,z,y,x`` without
    ``seconds_elapsed`` (an app version or a re-save that left it out) is Sensor Logger's, whose ``time``
    is in ns — never a phyphox buffer's ``time`` in s from 0, which read as seconds would put its samples
    50 billion years on (an integer of 1e9 s or more is no experiment's time)."""
    if len(head) < 2:
        return False
    column = next(i for i, cell in enumerate(cells) if (clock_of(cell) or ("",))[0] == "time")
    row = split_header(head[1], delimiter)
    if column < len(row) and _is_iso_time(row[column]):
        return True
    try:
        cell = row[column].strip().strip('"')
        if not cell.isascii():  # "١٦٧٩…": Python's int() reads it, no CSV reader does
            return False
        value = abs(float(number(cell if delimiter == "," else cell.replace(",", "."))))
    except (ValueError, IndexError):
        return False
    # an epoch in s or finer, or ns since boot (1 s on); a fraction too: a re-save's "1679068247.609" (s),
    # which was read as phyphox's time in s, the samples printed at 1.68e9 s
    return math.isfinite(value) and value >= EPOCH_UNITS[-1][0]


_ISO = re.compile(
    r"^\s*(\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}:\d{2})(?:[.,](\d{1,9}))?\s*(Z|[+-]\d{2}(?::?\d{2})?)?\s*$", re.I
)
"""An ISO-8601 date and time, as a spreadsheet or a script re-saves an epoch ``time``:
``2023-03-17T15:50:47.6092966Z`` (``T`` or a space, a fraction of up to 9 digits, ``Z``, an offset or
none)."""


def iso_time_ns(cell: str) -> float:
    """An ISO-8601 ``time`` cell (:data:`_ISO`) as ns since the epoch (a float: to 256 ns, as the app's
    ``seconds_elapsed`` is to ~100 ns); one without an offset is read as UTC (all the export's files alike:
    only differences of time matter). ``nan`` is NaN (a NaN sample); anything else is a :class:`BadCell`."""
    m = _ISO.match(cell)
    if m is None:
        if cell.strip().lower() == "nan":
            return float("nan")
        raise BadCell(f"{shown(cell)} is no ISO-8601 time, as the file's first row's is")
    stamp, fraction, zone = m.groups()
    zone = (zone or "+00:00").upper().replace("Z", "+00:00")
    try:
        when = datetime.fromisoformat(stamp.replace(" ", "T") + zone)
    except ValueError as exc:
        raise BadCell(f"{shown(cell)} is no ISO-8601 time ({exc})") from None
    seconds = int((when - datetime(1970, 1, 1, tzinfo=UTC)).total_seconds())
    return float(seconds * 1_000_000_000 + int((fraction or "0").ljust(9, "0")))


def _is_iso_time(cell: str) -> bool:
    """Whether a first row's ``time`` cell is an ISO-8601 time rather than a number."""
    try:
        number(cell.strip().strip('"'))
        return False
    except ValueError:
        return _ISO.match(cell.strip().strip('"')) is not None


def _csv_table(c: Container, member: str, kind: SensorKind) -> Table:
    """One of the export's CSV files as a :class:`Table` of the columns a ``kind`` sensor is read from
    (:func:`sensor_columns`), read in its own dialect (a spreadsheet's re-save may use semicolons and
    decimal commas), its ``time`` column also as exact int64."""
    head = content_head(c, member, 8, units_row=True)
    delimiter, decimal_comma = sniff_dialect(head)
    cells = split_header(head[0], delimiter) if head else []
    time_name = next((cell for cell in cells if (clock_of(cell) or ("",))[0] == "time"), "time")
    converters = None
    if len(head) > 1 and time_name in cells:
        first = split_header(head[1], delimiter)
        at = cells.index(time_name)
        if at < len(first) and _is_iso_time(first[at]):
            converters = {time_name: iso_time_ns}  # a re-save's dates: read as ns since the epoch
    return read_table(
        c,
        member,
        delimiter,
        header=True,
        decimal_comma=decimal_comma,
        min_columns=4,
        use=partial(sensor_columns, kind=kind),
        exact_columns=(time_name,),
        converters=converters,
        units_row=True,
    )


def sensor_columns(header: Header, kind: SensorKind) -> list[str]:
    """The columns of a sensor file that are read: its clocks (the first ``time`` and the first
    ``seconds_elapsed``, however spelt: :func:`clock_of`) and its x, y, z. Any other — an ``accuracy``
    of ``HIGH``, a label, an empty column — is never parsed. An InputFormatError naming the header when
    there is no clock or an axis is missing."""
    clocks: dict[str, str] = {}
    for column in header.columns:
        clock = clock_of(column)
        if clock is not None and clock[0] not in clocks:
            clocks[clock[0]] = column
    if not clocks:
        raise InputFormatError(
            f"no 'time' or 'seconds_elapsed' column (columns: {', '.join(header.columns)})",
            header.source,
            header.line,
        )
    skip = [c for c in header.columns if clock_of(c) is not None]
    axes = axis_columns(header.columns, kind, header.source, header.line, skip=skip)
    return [*clocks.values(), *(col for col, _ in axes)]


@dataclass
class Clocks:
    """What :func:`assemble` learns of its files' clocks as it reads them: ``bases`` (by file name, the
    epoch its recording started at: ``time`` less ``seconds_elapsed``, s); ``elapsed_only`` to read every
    file by ``seconds_elapsed`` (a ``time`` rounded by a spreadsheet: :class:`_CoarseTime`)."""

    bases: dict[str, float] = field(default_factory=dict)
    elapsed_only: bool = False


class _CoarseTime(Exception):
    """A file's ``time`` rounded to a few significant digits (``1.67907E+18``: a spreadsheet re-saved the
    export and wrote the number as it showed it) beside a ``seconds_elapsed`` that is not: the export is
    read again by ``seconds_elapsed``."""

    def __init__(self, source: str, distinct: int, rows: int) -> None:
        super().__init__(source)
        self.source, self.distinct, self.rows = source, distinct, rows


def _coarse(times: np.ndarray, usable: np.ndarray) -> tuple[int, int] | None:
    """(distinct times, rows) when fewer than half the usable rows have a time of their own: a ``time``
    rounded (a sensor's samples are 5-20 ms apart; its clock ticks in ns). None otherwise."""
    rows = int(np.count_nonzero(usable))
    if rows < 10:
        return None
    distinct = len(np.unique(times[usable]))
    return (distinct, rows) if distinct < rows // 2 else None


def samples(
    table: Table,
    name: str,
    notes: list[str],
    required: bool = True,
    clocks: Clocks | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The times (int64 ns since the epoch, or float s since the start) and readings (N, 3, SI) of
    ``table``, the export's file ``name`` (``Gyroscope.csv``: it says the sensor) however it was stored
    (a CSV file, the records of the JSON export). A row whose ``time`` is no number (NaN, or beyond
    int64) or no time of the recording has NaN readings and the time :data:`NO_TIME` (NaN on the log's
    clock): a NaN sample, dropped and counted by the merge (and by the host's admission under --port).
    A table with no rows is an InputFormatError naming it when ``required``. ``clocks`` collects, by
    ``name``, its clock's base — ``time`` less ``seconds_elapsed``, the epoch the recording started at
    (s) — when it has both, and says whether to read ``seconds_elapsed`` only. A ``time`` rounded
    (:func:`_coarse`) is :class:`_CoarseTime` when the file has a ``seconds_elapsed`` to read instead,
    else an InputFormatError naming the column."""
    notes.extend(table.layout_notes())
    table, units = _clock_names_lowered(table)
    if required and not len(table.data):
        raise InputFormatError("no samples (a header only)", table.source)
    kind = FILE_KINDS[name.lower()]
    axes = axis_columns(table.columns, kind, table.source, table.header_line, skip=_TIME)
    xyz = np.column_stack([table.column(col) * factor for col, factor in axes])
    times: np.ndarray
    elapsed_only = clocks is not None and clocks.elapsed_only and "seconds_elapsed" in table.columns
    if "time" in table.exact and not elapsed_only:
        exact = table.column("time")
        unusable = ~(np.isfinite(exact) & (np.abs(exact) < 2.0**63))
        if unusable.all() and len(unusable):
            raise InputFormatError("no 'time' cell is a number", table.source, table.header_line, "time")
        if unusable.any():  # told as the strays of _epoch_ns are: no row's loss goes unsaid
            notes.append(
                f"{table.source}: {int(unusable.sum())} rows whose 'time' is no time of this recording "
                f"(no number, or beyond int64; the first on data row {int(np.argmax(unusable)) + 1}): NaN "
                "samples, dropped and counted"
            )
        base: dict[str, float] = {}
        times, usable = _epoch_ns(table, ~unusable, notes, units, base)
        if clocks is not None and base:
            clocks.bases[name] = base[table.source]
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


@dataclass(frozen=True)
class _ClockUnits:
    """The units a header gave its clock columns, as written (``time (ns)`` → ``time="ns"``; "" for
    none) and the header cells that gave them (for errors)."""

    time: str = ""
    time_cell: str = "time"
    elapsed: str = ""
    elapsed_cell: str = "seconds_elapsed"


def _clock_names_lowered(table: Table) -> tuple[Table, _ClockUnits]:
    """``table`` with its clock columns named as the app names them (``TIME``, ``Seconds_Elapsed``,
    ``time (ns)`` → ``time``, ``seconds_elapsed``) and the units their header gave: :func:`detect` reads
    a header whatever its letter case and with units on its clocks (a spreadsheet or script that
    re-saved the export may change it), so the reader must find the same columns. ``seconds_elapsed``
    is scaled to s by its unit (an unknown one is an InputFormatError naming the column); ``time``'s
    unit is checked by :func:`_epoch_ns`."""
    units = _ClockUnits()
    columns = []
    for col in table.columns:
        clock = clock_of(col)
        if clock is None or clock[0] in columns:
            columns.append(col)
            continue
        name, unit = clock
        columns.append(name)
        if name == "time":
            units = replace(units, time=unit, time_cell=col)
        else:
            units = replace(units, elapsed=unit, elapsed_cell=col)
    exact = {(clock_of(name) or (name,))[0]: values for name, values in table.exact.items()}
    data = table.data
    if units.elapsed:
        scale = ELAPSED_UNITS.get(units.elapsed.replace("μ", "µ"))
        if scale is None:
            raise InputFormatError(
                f"unknown unit {units.elapsed!r} for seconds_elapsed (known: s, ms, us, ns)",
                table.source,
                table.header_line,
                units.elapsed_cell,
            )
        if scale != 1.0:
            data = data.copy()
            data[:, columns.index("seconds_elapsed")] *= scale
    return replace(table, columns=tuple(columns), data=data, exact=exact), units


BOOT_NS: tuple[int, int, int, str] = (10**9, 10**18, 1, "ns since boot")
"""A ``time`` in ns since the phone booted (Android's sensor clock, ``SensorEvent.timestamp``), as a tool
or an app version writes it instead of the epoch: from a second of uptime (1e9; no phone boots faster) to
an epoch in ns (1e18, 2001). Told from an epoch in µs, ms or s of the same size by its sample steps
(:func:`_time_unit`)."""
SAMPLE_STEP_S = (1e-3, 1.0)
"""s: the median step between a file's samples that a phone sensor has (1 kHz down to 1 Hz): which unit
of ``time`` makes the steps such tells ns since boot from an epoch in a coarser unit of the same size."""
LONE_STEP_S = (1e-4, 1e3)
"""s: the median step a ``time`` that can be only ns since boot (by its size, or its header's ``(ns)``)
must have: wider, there being nothing to tell it from; an epoch in ms under a ``time (ns)`` header (steps
of 20 ns) is still refused."""


def _unit_text(name: str) -> str:
    return "ns since the phone booted" if name == BOOT_NS[3] else f"{name} since the epoch"


def _time_unit(
    table: Table, times: np.ndarray, usable: np.ndarray, units: _ClockUnits
) -> tuple[int, int, int, str]:
    """The unit of the ``time`` column (:data:`EPOCH_UNITS` or :data:`BOOT_NS`): of those its values'
    size allows (and its header's unit, if it names one), the one whose span agrees with
    ``seconds_elapsed``'s (when the file has one spanning a second or more), else the one whose median
    sample step is a phone sensor's (:data:`SAMPLE_STEP_S`). None, or two (a step of 1 ms in ns since
    boot is 1 s in µs since the epoch), is an InputFormatError naming the column: never a guess."""
    typical = int(np.median(times[usable]))
    by_size = next((u for u in EPOCH_UNITS if u[0] <= typical < u[1]), None)
    boot = BOOT_NS if BOOT_NS[0] <= typical < BOOT_NS[1] else None
    candidates = [u for u in (by_size, boot) if u is not None]
    if not candidates:
        raise InputFormatError(
            f"{typical} is no time since the epoch in ns, µs, ms or s (2001-2286), nor since the phone "
            "booted in ns",
            table.source,
            table.header_line,
            "time",
        )
    said = units.time.replace("us", "µs").replace("μ", "µ").replace("sec", "s")
    if said:
        allowed = [u for u in candidates if u[3].split()[0] == said]
        if not allowed:
            raise InputFormatError(
                f"the header says {units.time!r} but the values are "
                f"{' or '.join(_unit_text(u[3]) for u in candidates)} (by their size)",
                table.source,
                table.header_line,
                units.time_cell,
            )
        candidates = allowed
    if len(candidates) == 1 and candidates[0] is by_size:
        return candidates[0]  # an epoch, checked against seconds_elapsed's span by _epoch_ns
    rows = np.flatnonzero(usable)
    elapsed = table.column("seconds_elapsed")[rows] if "seconds_elapsed" in table.columns else None
    if elapsed is not None:
        ok = np.isfinite(elapsed)
        ratios = _spans_per_elapsed(times[rows[ok]], elapsed[ok])
        if ratios is not None:
            fits = [u for u in candidates if _agrees(ratios, u[2])]
            if len(fits) == 1:
                return fits[0]
            if not fits:
                raise InputFormatError(
                    f"no time since the epoch nor since the phone booted: read as "
                    f"{' or '.join(_unit_text(u[3]) for u in candidates)}, 'time' spans none of what "
                    "'seconds_elapsed' does (its unit is none of these)",
                    table.source,
                    table.header_line,
                    "time",
                )
    steps = np.diff(table.column("time")[rows])  # floats: "1679068247.609" (s) keeps its fraction
    steps = steps[steps > 0]
    step = float(np.median(steps)) if len(steps) else math.nan
    lo, hi = SAMPLE_STEP_S if len(candidates) > 1 else LONE_STEP_S
    fits = [u for u in candidates if lo <= step * u[2] * 1e-9 <= hi]
    if len(fits) == 1:
        return fits[0]
    if len(candidates) == 1 and not len(steps):
        return candidates[0]  # one sample: nothing to tell by, and nothing else it could be
    said_units = " or ".join(
        f"{_unit_text(u[3])} (a sample every {step * u[2] * 1e-9:.3g} s)" for u in candidates
    )
    raise InputFormatError(
        f"no time since the epoch nor since the phone booted{' told apart' if fits else ''}: 'time' "
        f"steps by {step:.6g} a sample: read as {said_units}, {'both are' if len(fits) > 1 else 'none is'} "
        f"a phone sensor's ({lo:g}-{hi:g} s a sample); name its unit in the header ('time (ns)') or "
        "keep the export's 'seconds_elapsed' beside it",
        table.source,
        table.header_line,
        "time",
    )


def _epoch_ns(
    table: Table,
    usable: np.ndarray,
    notes: list[str],
    units: _ClockUnits | None = None,
    bases: dict[str, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``time`` column as int64 ns since the epoch, its unit told by its size (:data:`EPOCH_UNITS`:
    the app writes ns; a re-export may write µs or ms) and checked against ``seconds_elapsed``'s steps
    where there is one, and against the unit its header names if it names one (``time (ms)`` over
    values in ns is a header that lies, or values cut wrongly: either way no clock to trust); and the
    rows whose time is usable (of ``usable``, those within the unit's epochs, 2001-2286, whose ns fit
    int64: a row at 0, at a negative time or at 1e18 ns in a recording of 2023 is a NaN sample, noted, not
    the clock's origin). A typical time that is no epoch in any unit is an InputFormatError naming the
    column."""
    units = units or _ClockUnits()
    times = table.exact["time"]
    if not usable.any():
        return np.full(len(times), NO_TIME, np.int64), usable
    typical = int(np.median(times[usable]))
    low, high, ns_per_unit, name = _time_unit(table, times, usable, units)
    coarse = _coarse(table.column("time"), usable)  # floats: "1679068247.609" (s) is no whole second
    if coarse is not None:
        elapsed = table.column("seconds_elapsed") if "seconds_elapsed" in table.columns else None
        if elapsed is not None and _coarse(elapsed, np.isfinite(elapsed)) is None:
            raise _CoarseTime(table.source, *coarse)
        raise InputFormatError(
            f"'time' takes {coarse[0]} values over {coarse[1]} rows: rounded (a spreadsheet's re-save, "
            "1.67907E+18?), its samples cannot be told apart; export the recording again",
            table.source,
            table.header_line,
            "time",
        )
    high = min(high, np.iinfo(np.int64).max // ns_per_unit + 1)  # ns that fit int64 (an epoch in s: 2262)
    near = np.abs(times.astype(float) - typical) <= MAX_RECORDING_S * 1e9 / ns_per_unit  # no int64 wrap
    stray = usable & ~((times >= low) & (times < high) & near)
    if stray.any():  # 0, a negative time, one in 2001 in a recording of 2023: no sample of it; NaN
        notes.append(
            f"{table.source}: {int(stray.sum())} rows whose 'time' is no time of this recording (none "
            f"in {_unit_text(name)}, or {MAX_RECORDING_S // 86400} days or more from its median; the "
            f"first on data row {int(np.argmax(stray)) + 1}: {int(times[np.argmax(stray)])}): NaN samples, "
            "dropped and counted"
        )
        usable = usable & ~stray
    # an unusable row keeps no time it does not have (the median's, once: a row that --port released at
    # the middle of the recording, holding the stream back); NO_TIME, NaN once on the log's clock
    ns = np.where(usable, times * ns_per_unit, NO_TIME)
    floats = table.column("time")
    fractional = usable & (times.astype(float) != floats)
    if fractional.any():  # "1679068247.609" (s), "1679068247609.3" (ms): a re-save's, not truncated
        ns[fractional] = np.round(floats[fractional] * ns_per_unit).astype(np.int64)
    if name == BOOT_NS[3]:
        notes.append(
            f"{table.source}: 'time' in ns since the phone booted (Android's sensor clock), not since the "
            "epoch: told by its sample steps"
        )
    elif name != "ns":
        notes.append(f"{table.source}: 'time' in {name} since the epoch (the app writes ns)")
    if "seconds_elapsed" in table.columns:
        rows = np.flatnonzero(usable & np.isfinite(table.column("seconds_elapsed")))
        elapsed = table.column("seconds_elapsed")[rows]
        if bases is not None and len(rows):
            bases[table.source] = float(np.median(ns[rows] * 1e-9 - elapsed))
        ratios = _spans_per_elapsed(ns[rows], elapsed)
        if ratios is not None and not _agrees(ratios, 1):
            raise InputFormatError(
                f"read as {_unit_text(name)}, 'time' spans {ratios[1]:.4g} times what "
                f"'seconds_elapsed' does: its unit is not {name}",
                table.source,
                table.header_line,
                "time",
            )
    return ns, usable


def _spans_per_elapsed(t_ns: np.ndarray, elapsed_s: np.ndarray) -> tuple[float, float] | None:
    """How many times what ``seconds_elapsed`` spans a file's ``time`` spans (``t_ns``, its values read as
    ns; ``elapsed_s`` the same rows', s), over the steps on which ``seconds_elapsed`` goes on
    (a recording appended to another, ``seconds_elapsed`` from 0 again and ``time`` on from the pause,
    was refused as "its unit is not ns", its ``time`` right throughout): end to end, which a
    ``seconds_elapsed`` rounded by a re-save leaves right, and the median of the steps', which one stray
    row leaves right (a single ``seconds_elapsed`` of 1e160, or a day on, made the end-to-end span
    1e160 s and refused a file whose every ``time`` was right: that column is the clock, and
    ``seconds_elapsed`` only checks its unit). None when those steps span less than a second: too little
    to tell a unit by."""
    steps_s = np.diff(elapsed_s)
    on = steps_s > 0
    span_s = float(steps_s[on].sum())
    if not span_s >= 1.0 or not on.any():
        return None
    steps_t = np.diff(t_ns.astype(float))[on] * 1e-9  # floats: an int64 step between strays wraps
    return float(steps_t.sum()) / span_s, float(np.median(steps_t / steps_s[on]))


def _agrees(ratios: tuple[float, float], ns_per_unit: float) -> bool:
    """Whether ``time`` read in a unit of ``ns_per_unit`` ns spans what ``seconds_elapsed`` does, to 1 %,
    end to end or step by step (:func:`_spans_per_elapsed`'s ``ratios``, of ``time`` read as ns)."""
    return any(0.99 < ratio * ns_per_unit < 1.01 for ratio in ratios)


FILE_KINDS: dict[str, SensorKind] = {
    **{n.lower(): SensorKind.GYR for n in GYR_FILES},
    **{n.lower(): SensorKind.MAG for n in MAG_FILES},
    **{n.lower(): SensorKind.ACC for n in (*ACC_FILES, "Gravity.csv")},
}
"""The export's sensor files (lower case) → the sensor each holds (Gravity.csv: an accelerometer's)."""


def holds_nothing(c: Container, member: str) -> bool:
    """Whether the member has no line but blank ones (0 bytes: the app wrote nothing for that sensor).
    Streamed, and stopped at the first line with content."""
    for _, lines in text_lines(c, member):
        if any(line.strip() for line in lines):
            return False
    return True


SETTING_OFF = frozenset({"false", "0", "no", "off"})
"""How ``Metadata.csv`` may write a setting that is off (the app writes ``false``; a spreadsheet ``FALSE``,
``0``)."""


SETTING_ON = frozenset({"true", "1", "yes", "on"})
"""How ``Metadata.csv`` may write a setting that is on (the app writes ``true``)."""
STANDARDISATION_SINCE = "1.29"
"""The app version that added "Standardise Units & Frames" and ``Metadata.csv``'s ``standardisation``
(awesome-sensor-logger, CROSSPLATFORM.md: off by default "to maintain backwards compatibility")."""


def _ios_standardised(settings: Mapping[str, str], export: Export, notes: list[str]) -> bool:
    """Whether an iOS export's axes are Android's (the app's "Standardise Units & Frames" on), said in
    ``notes``. ``standardisation`` ``true`` or ``false`` (:data:`SETTING_ON`, :data:`SETTING_OFF`)
    decides; without the column the app predates the setting (:data:`STANDARDISATION_SINCE`) and wrote
    iOS's own frames, as the setting's default (off) still does — it was read as on, the accelerometer
    upside down. Any other value is an :class:`InputFormatError` naming ``Metadata.csv``: the frames
    cannot be told, and a guess flips the attitude."""
    where = export.files["Metadata.csv"]
    negated = (
        "the accelerometer's axes negated to Android's (gyroscope and magnetometer share Android's axes)"
    )
    if "standardisation" not in settings:
        version = settings.get("appversion", "")
        notes.append(
            f"iOS export from before app version {STANDARDISATION_SINCE} ({where} has no standardisation"
            + (f"; appVersion {version}" if version else "")
            + f"): iOS's own frames, as with 'Standardise Units & Frames' off: {negated}"
        )
        return False
    value = settings["standardisation"]
    if value in SETTING_OFF:
        notes.append(
            f"iOS export with 'Standardise Units & Frames' off ({where}: standardisation {value}): {negated}"
        )
        return False
    if value in SETTING_ON:
        notes.append(f"iOS export with 'Standardise Units & Frames' on ({where}: standardisation {value})")
        return True
    raise InputFormatError(
        f"standardisation {value!r} is neither on ({', '.join(sorted(SETTING_ON))}) nor off "
        f"({', '.join(sorted(SETTING_OFF))}): whether iOS's accelerometer axes are Android's or the other "
        "way round cannot be told",
        where,
    )


_PLATFORM = re.compile(
    r"^(ios|ipados|iphone\s*os|android)(?:[\s_/-]*(?:v(?:ersion)?\s*)?\d+(?:\.\d+)*)?(?:\s*\(.*\))?$"
)
"""A ``platform`` the recording's metadata may state (lower case): the app writes ``ios`` or ``android``;
a tool or an app version may add a version (``android 14``, ``ios_17.2``, ``iOS 17 (21C62)``) or name
iPadOS or iPhone OS, all iOS's frames."""


def platform_of(settings: Mapping[str, str], where: str, notes: list[str]) -> str:
    """The recording's platform from its metadata's ``platform`` (:func:`settings_of`: lower case):
    ``"ios"`` or ``"android"`` (:data:`_PLATFORM`; a version or another spelling noted), ``""`` when it
    states none (no metadata, no ``platform``, or an empty one, noted: then an
    ``AccelerometerUncalibrated.csv`` in g is told iOS's by its unit, :func:`_uncalibrated_in_g`). Any
    other value (``windows``, ``linux``) is an InputFormatError naming ``where``: it decides whether the
    accelerometer's axes are negated, and every platform but one starting ``ios`` was read as Android's
    without a word (an ``iPadOS`` recording upside down)."""
    value = settings.get("platform")
    if value is None:
        return ""
    if not value:
        notes.append(f"{where}: 'platform' is empty: no platform stated")
        return ""
    m = _PLATFORM.match(value)
    if m is None:
        raise InputFormatError(
            f"platform {value!r} is neither iOS nor Android (Sensor Logger writes 'ios' or 'android'): "
            "whether the accelerometer's axes are Android's or iOS's own (negated) cannot be told",
            where,
        )
    family = "android" if m.group(1) == "android" else "ios"
    if value != family:
        notes.append(f"{where}: platform {value!r} read as {family}")
    return family


def recording_settings(metadata: str) -> dict[str, str]:
    """``Metadata.csv``'s record as {column: value}, both stripped and in lower case (``platform`` →
    ``ios``, ``standardisation`` → ``false``; the app writes one header and one row), read in its own
    dialect (a spreadsheet's re-save with semicolons) as every CSV of the export is. {} when it holds no
    header and row. ``standardisation`` is there from app version 1.29 on (the "Standardise Units &
    Frames" setting, off by default); the platform decides nothing else."""
    lines = [line for line in metadata.splitlines() if is_content(line)]
    if len(lines) < 2:
        return {}
    delimiter, _ = sniff_dialect(lines[:2])
    names = split_header(lines[0], delimiter)
    values = next(csv.reader([lines[1]], delimiter=delimiter, skipinitialspace=True), [])
    return settings_of(zip(names, values, strict=False))


def settings_of(pairs: Iterable[tuple[str, str]]) -> dict[str, str]:
    """The recording's settings as {name: value}, both stripped of blanks and quotes and in lower case,
    the first of a name given twice kept: one rule for ``Metadata.csv``'s header and row
    (:func:`recording_settings`) and the JSON export's ``Metadata`` record
    (:mod:`hil.logs.sensorlogger_json`), so that both exports of one recording say the same."""
    settings: dict[str, str] = {}
    for name, value in pairs:
        settings.setdefault(name.strip().lower(), value.strip().strip('"').strip().lower())
    return settings


def _first(files: Mapping[str, str], names: tuple[str, ...]) -> str | None:
    return next((n for n in names if n in files), None)


def _first_with_samples(
    export: Export, names: Sequence[str], notes: list[str], clocks: Clocks, required: bool = False
) -> tuple[str, np.ndarray, np.ndarray] | None:
    """The first of ``names`` (one sensor's files, in order of preference) in the export that holds a
    sample, with its times and readings (:func:`samples`); None when none does. A file that is empty
    (0 bytes) or a header only — the app's file for a sensor the phone lacks or never started — is
    passed over, noted: the next file of that sensor is read (a header-only ``Magnetometer.csv`` beside
    a ``MagnetometerUncalibrated.csv`` of 35 000 readings once made the log 6-axis, and a header-only
    ``Gyroscope.csv`` or ``TotalAcceleration.csv`` refused an export whose other file held the sensor).
    ``required`` (a sensor the estimator cannot do without): when none holds a sample, the first present
    is an InputFormatError naming it and what it is (an empty file, a header only), as :func:`samples`
    says it."""
    present = [name for name in names if name in export.files]
    for name in present:
        if export.empty(name):
            notes.append(f"{name} is empty: passed over")
            continue
        times, xyz = samples(export.table(name), name, notes, False, clocks)
        if not len(times):
            notes.append(f"{name} has no samples (a header only): passed over")
            continue
        return name, times, xyz
    if required and present:
        samples(export.table(present[0]), present[0], [], True, clocks)  # raises: it holds no sample
    return None


@dataclass(frozen=True)
class Export:
    """A Sensor Logger recording however it was exported (the CSV files, the JSON file), as the sensor
    files the app names: ``path`` for messages; ``files`` the app's file names present
    (``Gyroscope.csv``, …, of :data:`_KNOWN`) → where each is read from, for messages; ``table(name)``
    reads one; ``empty(name)`` says whether it holds nothing at all (0 bytes: the app wrote nothing for
    that sensor); ``settings`` the recording's settings its metadata states (:func:`settings_of`: the
    CSV export's ``Metadata.csv``, the JSON export's ``Metadata`` record; {} when there is none), with
    ``files["Metadata.csv"]`` where they were read from;
    ``container`` the files' container, whose sample count (:data:`~hil.logs.table.MAX_LOG_SAMPLES`)
    the tables read add to."""

    path: str
    files: Mapping[str, str]
    table: Callable[[str], Table]
    empty: Callable[[str], bool]
    settings: Callable[[], Mapping[str, str]]
    container: Container


def read(c: Container) -> SensorLog:
    files = members(c)
    if files is None:
        folders = sorted({m.rpartition("/")[0] or "." for m in c.names()})
        raise InputFormatError(
            f"Sensor Logger files in several folders ({', '.join(folders[:6])}): recordings side by side; "
            "replay one folder (unpack an archive first)",
            str(c.path),
        )
    layout: list[str] = []
    for member in files.values():  # a second copy of a file beside it: read once, or refused
        _, same = one_copy(c, [member, *_other_copies(c, member)])
        if same is not None:
            layout.append(same)
    if any(m.rpartition("/")[2] != plain_name(m.rpartition("/")[2]) for m in files.values()):
        layout.append("the export's files are gzipped (.csv.gz): read decompressed")
    sensor_folder = next(m for name, m in files.items() if name != "Metadata.csv").rpartition("/")[0]
    if "Metadata.csv" in files and files["Metadata.csv"].rpartition("/")[0] != sensor_folder:
        layout.append(
            f"{c.where(files['Metadata.csv'])}: the recording's metadata, read from above its sensor files "
            f"(in {sensor_folder})"
        )
    read_from = files["Metadata.csv"].rpartition("/")[0] if "Metadata.csv" in files else None
    unread = [
        m
        for m in sorted(c.names())
        if plain_name(m.rpartition("/")[2]).lower() == "metadata.csv" and m.rpartition("/")[0] != read_from
    ]
    if unread:  # not beside the sensor files nor above them: no recording's that is read
        layout.append(f"not read (no metadata of this recording's folder): {', '.join(map(c.where, unread))}")
    if any(plain_name(m) != name for name, m in files.items()):
        folder = sensor_folder
        layout.append(f"the export's files read from {folder or 'the top'} (names matched ignoring case)")
    export = Export(
        str(c.path),
        {name: c.where(member) for name, member in files.items()},
        lambda name: _csv_table(c, files[name], FILE_KINDS[name.lower()]),
        lambda name: holds_nothing(c, files[name]),
        lambda: recording_settings(c.text(files["Metadata.csv"])) if "Metadata.csv" in files else {},
        c,
    )
    notes = ["Sensor Logger export: columns read by name (files are ordered z, y, x)"]
    return assemble(export, NAME, notes, layout)


def assemble(export: Export, format_name: str, notes: list[str], layout: Sequence[str] = ()) -> SensorLog:
    """The log of an export: its gyroscope, magnetometer and accelerometer files chosen and read (see
    the module docstring), put on one clock, and noted (``notes`` first, then what was chosen, then
    ``layout``: how the export was stored). When a file's ``time`` is rounded (a spreadsheet's re-save:
    :class:`_CoarseTime`), every file is read by ``seconds_elapsed`` instead, noted; its rows count
    once towards :data:`~hil.logs.table.MAX_LOG_SAMPLES`, not once per reading."""
    counted = export.container.samples
    try:
        return _assemble(export, format_name, list(notes), layout, Clocks())
    except _CoarseTime as coarse:
        export.container.samples = counted  # the files are read again from their first line
        said = (
            f"{coarse.source}: 'time' takes {coarse.distinct} values over {coarse.rows} rows (rounded: a "
            "spreadsheet's re-save?): every file read by seconds_elapsed"
        )
        return _assemble(export, format_name, [*notes, said], layout, Clocks(elapsed_only=True))


def _assemble(
    export: Export, format_name: str, notes: list[str], layout: Sequence[str], clocks: Clocks
) -> SensorLog:
    files = export.files
    parts: dict[SensorKind, tuple[np.ndarray, np.ndarray]] = {}
    bases = clocks.bases
    if _first(files, GYR_FILES) is None:
        raise InputFormatError("no Gyroscope.csv (nor GyroscopeUncalibrated.csv) in the export", export.path)
    for kind, names in ((SensorKind.GYR, GYR_FILES), (SensorKind.MAG, MAG_FILES)):
        found = _first_with_samples(export, names, notes, clocks, required=kind is SensorKind.GYR)
        if found is None:  # a magnetometer file empty or a header only (noted): 6-axis, below
            continue
        name, times, xyz = found
        parts[kind] = (times, xyz)
        # named where its unit is doubted (a gyroscope in deg/s?, a magnetometer in nT?)
        notes.append(f"{'gyroscope' if kind is SensorKind.GYR else 'magnetometer'}: {export.files[name]}")
        if "Uncalibrated" in name:
            notes.append(f"{name}: no calibrated file with samples in the export, using the uncalibrated one")
    if SensorKind.MAG not in parts and _first(files, MAG_FILES) is not None:
        notes.append("no magnetometer samples: 6-axis log, heading not observed (gyroscope only, drifting)")
    elif SensorKind.MAG not in parts:
        notes.append("no Magnetometer.csv: 6-axis log, heading not observed (gyroscope only, drifting)")
    settings = export.settings()
    platform = platform_of(settings, export.files.get("Metadata.csv", export.path), notes)
    parts[SensorKind.ACC] = _accelerometer(export, notes, clocks, platform)
    if platform == "ios" and not _ios_standardised(settings, export, notes):
        # iOS's own frames: its acceleration and gravity point the other way on every axis (flat, screen
        # up, gravity reads -z where Android's specific force reads +z); read as they are, the estimator
        # took the phone to be upside down
        times, xyz = parts[SensorKind.ACC]
        parts[SensorKind.ACC] = (times, -xyz)
    notes.extend(layout)
    epoch = {k: t.dtype.kind == "i" for k, (t, _) in parts.items()}
    if len(set(epoch.values())) > 1:
        raise InputFormatError(
            "some files have a 'time' column and some do not: no common clock", export.path
        )
    _same_clock(bases, parts, export)
    streams = {}
    if all(epoch.values()):
        t0 = min((int(t[t != NO_TIME].min()) for t, _ in parts.values() if (t != NO_TIME).any()), default=0)
        for kind, (t, xyz) in parts.items():
            known = t != NO_TIME
            seconds = np.where(known, np.where(known, t, t0) - t0, 0).astype(float) * 1e-9
            streams[kind] = SensorStream(kind, np.where(known, seconds, np.nan), xyz)
        notes.append(f"time: ns since epoch, origin {t0} ns")
    else:
        streams = {kind: SensorStream(kind, t, xyz) for kind, (t, xyz) in parts.items()}
        why = "the epoch 'time' rounded" if clocks.elapsed_only else "no epoch time column"
        notes.append(f"time: seconds_elapsed ({why})")
    return SensorLog(streams, export.path, format_name, None, tuple(notes))


def _uncalibrated_in_g(xyz: np.ndarray, where: str, platform: str, notes: list[str]) -> np.ndarray:
    """``AccelerometerUncalibrated.csv``'s readings in m/s^2: converted from g when its median norm says
    it reads in g (about 1, where gravity alone is 9.81 m/s^2). Only iOS writes that file in g (Android's
    is in m/s^2; with "Standardise Units & Frames" on, iOS's is too), and in iOS's own frames: the
    acceleration the other way round on every axis (flat, screen up, it reads -1 g on z). So where
    ``Metadata.csv`` states no platform (no such file, or no ``platform`` column), a file in g is iOS's
    and is negated to Android's axes here, noted; the phone lying screen up was replayed as screen down.
    Where it does state one, :func:`_assemble` negates by its settings (:func:`_ios_standardised`)."""
    norm = float(np.nanmedian(np.linalg.norm(xyz, axis=1))) if len(xyz) else G
    if not 0.5 < norm < 2.0:
        return xyz
    notes.append("AccelerometerUncalibrated.csv reads in g (median norm ~1): converted to m/s^2")
    if platform:
        return xyz * G
    notes.append(
        f"{where}: in g, which only iOS writes, and no platform stated (no Metadata.csv, or no 'platform' "
        "in it): iOS's own frames, its axes negated to Android's"
    )
    return xyz * -G


MAX_CLOCK_DISAGREEMENT_S = 1.0
"""How far apart two sensor files' clocks may lie (s): their ``time`` less ``seconds_elapsed`` (the epoch
the recording started at: the same in every file of one recording, to a µs in the app's), or, without
that, the gap between their spans. Farther, a file is on another clock (another recording's, a boot
clock, a file shifted by a tool), and reading it beside the others would put its samples beside readings
taken at another time. The replay's own gap bound (``--max-gap``) is 1 s too."""


def _same_clock(
    bases: Mapping[str, float], parts: Mapping[SensorKind, tuple[np.ndarray, np.ndarray]], export: Export
) -> None:
    """An InputFormatError when the export's files are not on one clock (:data:`MAX_CLOCK_DISAGREEMENT_S`):
    their clock bases differ, or the spans of two of them are that far apart."""
    if len(bases) > 1:
        median = float(np.median(list(bases.values())))
        name, base = max(bases.items(), key=lambda item: abs(item[1] - median))
        if abs(base - median) > MAX_CLOCK_DISAGREEMENT_S:
            raise InputFormatError(
                f"its 'time' less its 'seconds_elapsed' is {base - median:+.6g} s off the other files' "
                "(the epoch the recording started at): it is on another clock than they are (another "
                "recording's, or shifted); replay files of one recording",
                export.files.get(name, name),
                None,
                "time",
            )
    spans = {}
    for kind, (t, xyz) in parts.items():
        kept = t[np.isfinite(t) & np.all(np.isfinite(xyz), axis=1)]  # NaN samples lie nowhere
        if len(kept):
            scale = 1e-9 if kept.dtype.kind == "i" else 1.0
            spans[kind] = (float(kept.min()) * scale, float(kept.max()) * scale)
    for a, (_, a1) in spans.items():
        for b, (b0, _) in spans.items():
            apart = b0 - a1
            if apart > MAX_CLOCK_DISAGREEMENT_S:
                raise InputFormatError(
                    f"the {b.label} samples start {apart:.6g} s after the last {a.label} sample: the files "
                    "are not on one clock (another recording's, or shifted); replay files of one recording",
                    export.path,
                )


GRAVITY_GAP_S = 1.0
"""s: the longest stretch between two ``Gravity.csv`` rows an accelerometer row's gravity is interpolated
across (or three of the file's median periods, if longer: a gravity sensor read slowly) — the replay's
own bound for a pause (``--max-gap``'s default). ``np.interp`` held the end values for ever: 0.2 s of
gravity was added to 693 s of user acceleration, 5 410 of 34 667 samples more than 10° off, with no
word."""
GRAVITY_HOLD_S = 0.1
"""s: the farthest before ``Gravity.csv``'s first row or after its last that its value is held (sensors
start and stop a few samples apart); beyond, gravity is not known."""


def _without_gravity(tu: np.ndarray, tg: np.ndarray) -> tuple[np.ndarray, float]:
    """Which accelerometer times ``tu`` (s) have no gravity to add from rows at ``tg`` (s, increasing) —
    beyond the first or last row by more than :data:`GRAVITY_HOLD_S`, or between two rows farther apart
    than the gap bridged (a row at the very time is gravity) — and that gap (s, :data:`GRAVITY_GAP_S`)."""
    period = float(np.median(np.diff(tg))) if len(tg) > 1 else 0.0
    gap = max(GRAVITY_GAP_S, 3.0 * period)
    i = np.searchsorted(tg, tu)  # tg[i - 1] < tu <= tg[i]
    before, after = tg[np.clip(i - 1, 0, len(tg) - 1)], tg[np.clip(i, 0, len(tg) - 1)]
    inside = (after - before > gap) & (after != tu)
    beyond = np.where(
        i == 0, tg[0] - tu > GRAVITY_HOLD_S, np.where(i == len(tg), tu - tg[-1] > GRAVITY_HOLD_S, inside)
    )
    return beyond, gap


GRAVITY_ALONE = (
    "Gravity.csv is the only accelerometer file in the export, and it cannot stand in for one: it is the "
    "phone's own gravity estimate, low-pass filtered and fused with its gyroscope (it holds still through "
    "motion the accelerometer measures), not a measurement; missing: TotalAcceleration.csv (or "
    "Accelerometer.csv beside this Gravity.csv, or AccelerometerUncalibrated.csv) — export the recording "
    "with TotalAcceleration (or Accelerometer) on"
)
"""The error for an export whose only accelerometer file is ``Gravity.csv``: it was refused as "no
accelerometer file", which said neither that a Gravity.csv had been found nor why it is not read."""


def _accelerometer(
    export: Export, notes: list[str], clocks: Clocks, platform: str = ""
) -> tuple[np.ndarray, np.ndarray]:
    """The accelerometer's times and readings (specific force, gravity included, m/s^2) from the first of
    the export's accelerometer files, in order of preference (the module's docstring), that hold
    samples: a file empty or a header only is passed over, noted (:func:`_first_with_samples`).
    ``platform`` is ``Metadata.csv``'s (lower case; "" when no file or column states it): where it is
    unstated, an ``AccelerometerUncalibrated.csv`` in g is told to be iOS's by its unit
    (:func:`_uncalibrated_in_g`)."""
    files = export.files
    total = _first_with_samples(export, ("TotalAcceleration.csv",), notes, clocks)
    if total is not None:
        notes.append("accelerometer: TotalAcceleration.csv (gravity included)")
        return total[1], total[2]
    user_read = _first_with_samples(export, ("Accelerometer.csv",), notes, clocks)
    grav_read = (
        _first_with_samples(export, ("Gravity.csv",), notes, clocks) if user_read is not None else None
    )
    if user_read is not None and grav_read is not None:
        _, user_t, user = user_read
        _, grav_t, g = grav_read
        known = np.all(np.isfinite(g), axis=1)  # gravity interpolated between its usable rows
        if not known.any():
            raise InputFormatError("no usable samples", files["Gravity.csv"])
        grav_t, g = grav_t[known], g[known]
        # np.interp needs increasing times: a row at or before an earlier one (rows out of order, a clock
        # that went back) was interpolated as if sorted, silently wrong; only rows later than every one
        # before them are kept, the others counted and noted
        later = np.ones(len(grav_t), bool)
        later[1:] = grav_t[1:] > np.maximum.accumulate(grav_t)[:-1]
        if not later.all():
            first = int(np.flatnonzero(known)[np.argmax(~later)]) + 1
            notes.append(
                f"{files['Gravity.csv']}: {int((~later).sum())} rows whose time is not after every earlier "
                f"row's (out of order, or repeated; the first on data row {first}): not interpolated "
                "between, dropped"
            )
            grav_t, g = grav_t[later], g[later]
        base = grav_t[0]
        timed = user_t != NO_TIME if user_t.dtype.kind == "i" else np.isfinite(user_t)
        tu = np.where(timed, np.where(timed, user_t, base) - base, 0).astype(float)
        tg = (grav_t - base).astype(float)
        xyz = user + np.column_stack([np.interp(tu, tg, g[:, i]) for i in range(3)])
        scale = 1e-9 if user_t.dtype.kind == "i" else 1.0  # the clock's units: ns since the epoch, or s
        beyond, gap = _without_gravity(tu * scale, tg * scale)
        bare = timed & beyond
        if bare.sum() > 0.5 * timed.sum():
            span_u = float(np.ptp(tu[timed])) * scale if timed.any() else 0.0
            raise InputFormatError(
                f"its rows ({float(np.ptp(tg)) * scale:.6g} s from the first to the last) give gravity to "
                f"only {int(timed.sum() - bare.sum())} of Accelerometer.csv's {int(timed.sum())} timed rows "
                f"({span_u:.6g} s): the accelerometer's gravity is missing (a cut-short export?)",
                files["Gravity.csv"],
            )
        if bare.any():
            xyz[bare] = np.nan
            notes.append(
                f"{files['Accelerometer.csv']}: {int(bare.sum())} of {len(bare)} rows have no Gravity.csv "
                f"row near (more than {GRAVITY_HOLD_S:g} s before its first or after its last, or in a gap "
                f"of more than {gap:.3g} s): no gravity to add, NaN samples (dropped and counted)"
            )
        notes.append("accelerometer: Accelerometer.csv (user acceleration) + Gravity.csv (interpolated)")
        return user_t, xyz
    uncalibrated = _first_with_samples(export, ("AccelerometerUncalibrated.csv",), notes, clocks)
    if uncalibrated is not None:
        name, times, xyz = uncalibrated
        notes.append("accelerometer: AccelerometerUncalibrated.csv (raw, gravity included)")
        return times, _uncalibrated_in_g(xyz, files[name], platform, notes)
    if user_read is not None:
        raise InputFormatError(
            "only Accelerometer.csv (user acceleration, gravity removed) in the export: the estimator needs "
            "the gravity direction; export TotalAcceleration (or Gravity) as well",
            files["Accelerometer.csv"],
        )
    present = _first(files, ACC_FILES)
    if present is not None:  # every accelerometer file empty or a header only (noted): the first's error
        _first_with_samples(export, (present,), [], clocks, required=True)
    if "Gravity.csv" in files:
        raise InputFormatError(GRAVITY_ALONE, files["Gravity.csv"])
    raise InputFormatError(
        "no accelerometer file (TotalAcceleration.csv, Accelerometer.csv + Gravity.csv, or "
        "AccelerometerUncalibrated.csv)",
        export.path,
    )
