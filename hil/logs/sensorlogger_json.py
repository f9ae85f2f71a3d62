"""Sensor Logger's JSON export: one file holding the whole recording as one array of records.

The layout is the one the app's author documents (github.com/tszheichoi/awesome-sensor-logger, README,
"File Handling → JSON"): a single file whose content is an array of objects, each one record (a row of
the CSV export) of one sensor, the records of each sensor grouped together and sorted by time::

    [
      {"sensor": "Accelerometer", "time": "1698501144401773000", "seconds_elapsed": "0.21677294921875",
       "z": "-0.1038", "y": "-0.0009", "x": "0.0611"},
      {"sensor": "Location", "time": "1698501145514000000", "seconds_elapsed": "1.3289", "speed": "0", …}
    ]

Every value is a string; ``sensor`` names the sensor as the CSV export names its file (``Gyroscope`` for
``Gyroscope.csv``; matched ignoring letter case, spaces and underscores); the other keys are the CSV's
columns (``time`` Unix epoch in ns, ``seconds_elapsed``, ``z``, ``y``, ``x``). A sensor's records are made
into the table its CSV file would be and read as the CSV export is (:func:`hil.logs.sensorlogger.assemble`:
the same files chosen, units, clock), so the JSON and the CSV export of one recording give the same
samples. Numbers written as JSON numbers rather than strings (a file re-saved by a script) are read as
well. The ``Metadata`` record (``{"sensor": "Metadata", "platform": "ios", "standardisation": "false",
"appVersion": …}``) is read as the CSV export's ``Metadata.csv`` is (:func:`_settings`): an iOS
recording's frames are told by it alike. Records of the other sensors (location, battery, …) are passed
over.

Only the keys the CSV reader would parse are read (:func:`hil.logs.sensorlogger.sensor_columns`, told
from the sensor's first record: its clocks and its x, y, z, found by name as in a CSV header,
:mod:`hil.logs.columns`); any other key of any record — unknown, nested, an array, a string, ``null``,
``1e308``, an integer of 10 000 digits, present in some records and not in others, given twice — is
never parsed and never stops the read, as an unused column of the CSV export does not. Keys may come in
any order. A clock key the first record lacks that a later record gives is read from that record on, the
rows before NaN in it (:meth:`_Sensor.add_clock`: never passed over). Every record of a sensor must hold
the keys read (``seconds_elapsed`` beside ``time`` may be left out: a NaN there), each a number or a
string holding one; a key read that a record gives twice with different values is an error (the first is
read when they agree). What a used value then holds is judged as the CSV reader judges the same cell:
``"NaN"`` a NaN sample, a ``time`` of 0 or ``1e30`` a stray row noted and dropped
(:func:`hil.logs.sensorlogger.samples`), ``"١٢"`` no number, an ISO-8601 ``time`` read as one.

The file is read as a stream (:meth:`hil.logs.table.Container.chunks`), a record at a time: memory is
bounded by the samples kept (8 bytes a value), not by the file's size. The file is at most
:data:`MAX_JSON_BYTES` (decompressed, for a ``.json.gz``), a record at most :data:`MAX_RECORD_CHARS`, its
rows count towards the log's :data:`~hil.logs.table.MAX_LOG_SAMPLES`; anything that is not the layout
above (not JSON, not UTF-8, binary or gzipped bytes under a ``.json`` name, a record nested past Python's
recursion limit, a nested value or ``null`` in a key read, a record without a key its sensor's first
record is read by) is an :class:`InputFormatError` naming the file, the line and the record.
"""

from __future__ import annotations

import codecs
import json
import logging
import math
import re
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from hil.estimation.sensors import SensorLog
from hil.files.bounded import MAX_MEMBER_BYTES
from hil.logs.rows import number as strict_number
from hil.logs.rows import shown
from hil.logs.sensorlogger import (
    ACC_FILES,
    FILE_KINDS,
    GYR_FILES,
    MAG_FILES,
    Export,
    assemble,
    clock_of,
    iso_time_ns,
    sensor_columns,
    settings_of,
)
from hil.logs.table import Container, Header, Table
from protocol.errors import InputFormatError

logger = logging.getLogger(__name__)

NAME = "sensorlogger-json"
MAX_JSON_BYTES = MAX_MEMBER_BYTES
"""The most the JSON file may hold, decompressed (256 MiB: about a million records, 90 minutes of three
sensors at 100 Hz; a record takes ~200 bytes)."""
MAX_RECORD_CHARS = 1 << 16
"""The longest one record may be (64 Ki characters): the app's are ~200 (a location record ~500). A longer
one is not the export's (a file of one huge object, a nesting bomb) and is refused before it is parsed."""
MAX_NAMED = 16
"""The most names of passed-over sensors kept for the notes (a hostile file may name a million)."""
COUNT_EVERY = 10_000
"""Records kept between two updates of the log's sample count (the count is cheap, but not free)."""

_SENSOR_FILES = {
    re.sub(r"[^a-z0-9]", "", name.removesuffix(".csv").lower()): name
    for name in (*GYR_FILES, *ACC_FILES, *MAG_FILES, "Gravity.csv")
}
"""A record's ``sensor`` (lower case, letters and digits only) → the CSV file the export would hold it in."""
_HEAD_KEYS = re.compile(
    r'"sensor"\s*:.*"(?:time|seconds_elapsed)"\s*:|"(?:time|seconds_elapsed)"\s*:.*"sensor"\s*:'
)
_WHITESPACE = " \t\r\n"


def _json_members(c: Container) -> list[str]:
    return [n for n in c.names() if n.lower().endswith((".json", ".json.gz"))]


def _is_export(c: Container, member: str) -> bool:
    """Whether the member is the export: an array whose first record has a ``sensor`` and a clock key
    (told from its first bytes; when they do not hold both keys — a first record with a long key the
    reader never uses before its clock, a ``Metadata`` record of many lines first — from its first
    record that is no ``Metadata`` record, read as :func:`read` reads it)."""
    head = " ".join(c.head(member, 40)).lstrip()
    if not head.startswith("["):
        return False
    if _HEAD_KEYS.search(head) is not None:
        return True
    pieces = c.chunks(member, MAX_JSON_BYTES)
    try:
        records = _records(_Reader(pieces, c.where(member)))
        record = next(records)[2]
        if _is_metadata(record):
            record = next(records)[2]  # the app writes one: the record after it is a sensor's
    except (InputFormatError, StopIteration):
        return False
    finally:
        pieces.close()  # type: ignore[attr-defined]
    return "sensor" in record and any(clock_of(key) is not None for key in record)


def _is_metadata(record: dict[str, object]) -> bool:
    """Whether ``record`` is the export's ``Metadata`` record (its ``sensor`` matched as a sensor's is:
    ignoring letter case, spaces and underscores)."""
    sensor = record.get("sensor")
    return isinstance(sensor, str) and re.sub(r"[^a-z0-9]", "", sensor.lower()) == "metadata"


def detect(c: Container) -> bool:
    return any(_is_export(c, n) for n in _json_members(c)[:20])


def exports(c: Container) -> list[str]:
    """The members of ``c`` that are Sensor Logger JSON exports (:func:`_is_export`)."""
    return [n for n in _json_members(c) if _is_export(c, n)]


@dataclass
class _Sensor:
    """One sensor's records as they are read: the keys read (told from its first record, as the CSV
    reader tells its columns from the header: :func:`~hil.logs.sensorlogger.sensor_columns`), the key
    that may be missing from a record (``seconds_elapsed`` beside ``time``: NaN), the values of each row
    flattened (float), and ``time`` as exact int64 (``time_key``, however it is spelt) when it is read.
    ``problem``: why its first record gives no columns to read (no clock, no axis): raised when the log
    needs the sensor, as the CSV reader raises it for a file it reads; its records are passed over."""

    keys: tuple[str, ...]
    first_line: int
    time_key: str | None = None
    optional: str | None = None
    problem: InputFormatError | None = None
    values: array[float] = field(default_factory=lambda: array("d"))
    times: array[int] = field(default_factory=lambda: array("q"))
    clocks: dict[str, str] = field(default_factory=dict)
    """The clocks read (``time``, ``seconds_elapsed``) → the key each is read by."""
    rows: int = 0
    other_keys: set[str] = field(default_factory=set)
    """Keys seen that are no clock (at most :data:`MAX_NAMED` × 16 remembered): not asked again."""

    def add_clock(self, clock: str, key: str) -> None:
        """Read ``key`` (clock ``clock``) from now on: a clock its first record lacked that a later record
        gives. The rows before hold NaN in it (a ``time`` of NaN makes them NaN samples, noted, dropped
        and counted: :func:`hil.logs.sensorlogger.samples`); beside ``time``, ``seconds_elapsed`` may be
        left out (NaN) from now on, as when the first record gives both."""
        width = len(self.keys)
        old = np.frombuffer(self.values, dtype=np.float64).reshape(-1, width) if width else None
        wider = np.full((self.rows, width + 1), np.nan)
        if old is not None:
            wider[:, :width] = old
        self.values = array("d", wider.tobytes())
        self.keys = (*self.keys, key)
        self.clocks[clock] = key
        if clock == "time":
            self.time_key = key
            self.times = array("q", bytes(8 * self.rows))  # 0: the NaN float marks the row unusable
        if "time" in self.clocks:
            self.optional = self.clocks.get("seconds_elapsed")


def _sensor(name: str, record: dict[str, object], index: int, line: int, where: str) -> _Sensor:
    """The keys a sensor's records are read by, from its first record (``name``: its CSV file)."""
    keys = tuple(k for k in record if k != "sensor")
    if not keys:
        raise InputFormatError(f"record {index} ({name.removesuffix('.csv')}) holds no values", where, line)
    try:
        used = tuple(sensor_columns(Header(keys, where, line), FILE_KINDS[name.lower()]))
    except InputFormatError as exc:
        return _Sensor((), line, problem=exc)
    clocks = {clock[0]: key for key in used if (clock := clock_of(key)) is not None}
    optional = clocks.get("seconds_elapsed") if "time" in clocks else None
    return _Sensor(used, line, clocks.get("time"), optional, clocks=clocks)


def _new_clocks(sensor: _Sensor, record: dict[str, object]) -> None:
    """Clock keys of ``record`` its sensor is not read by yet (its first record lacked them): read from
    this record on (:meth:`_Sensor.add_clock`), never passed over — a ``time`` that appears on the second
    record is the recording's clock, not a key to ignore."""
    if len(record) <= len(sensor.keys) + 1 or len(sensor.clocks) == 2:
        return  # no key beyond "sensor" and the keys read (the app's records): nothing new
    for key in record:
        if key == "sensor" or key in sensor.keys or key in sensor.other_keys:
            continue
        clock = clock_of(key)
        if clock is not None and clock[0] not in sensor.clocks:
            sensor.add_clock(clock[0], key)
        elif len(sensor.other_keys) < MAX_NAMED * 16:
            sensor.other_keys.add(key)


def read(c: Container) -> SensorLog:
    found = exports(c)
    if not found:
        raise InputFormatError("no Sensor Logger JSON export (an array of records) here", str(c.path))
    if len(found) > 1:
        raise InputFormatError(
            f"{len(found)} Sensor Logger JSON exports ({', '.join(found[:4])}): recordings side by "
            "side; replay one",
            str(c.path),
        )
    member = found[0]
    where = c.where(member)
    sensors, ignored, cut_short, metadata = _read_records(c, member, where)
    tables = {name: _table(sensor, where) for name, sensor in sensors.items() if sensor.problem is None}
    files = {name: f"{where} (sensor {name.removesuffix('.csv')})" for name in sensors}
    settings: dict[str, str] = {}
    if metadata is not None:
        files["Metadata.csv"] = f"{where}:{metadata.line} (record {metadata.index}, sensor Metadata)"
        settings = _settings(metadata, where)
    export = Export(
        str(c.path),
        files,
        lambda name: _needed(sensors[name], tables.get(name)),
        lambda name: False,  # a sensor without records is not in the file at all
        lambda: settings,
        c,
    )
    notes = [f"Sensor Logger JSON export: {member}, records read by key (x, y, z by name)"]
    if ignored:
        more = ", …" if len(ignored) >= MAX_NAMED else ""
        notes.append(f"records of other sensors passed over: {', '.join(sorted(ignored))}{more}")
    if cut_short is not None:
        notes.append(cut_short)
    return assemble(export, NAME, notes)


@dataclass(frozen=True)
class _Metadata:
    """The export's ``Metadata`` record (the CSV export's ``Metadata.csv``: ``platform``,
    ``standardisation``, ``appVersion``, …), where it was read."""

    record: dict[str, object]
    line: int
    index: int


_SETTINGS_READ = ("platform", "standardisation", "appversion")
"""The metadata keys the reader decides by (lower case): the platform and its frames
(:func:`hil.logs.sensorlogger.assemble`)."""


def _settings(metadata: _Metadata, where: str) -> dict[str, str]:
    """The ``Metadata`` record's settings as the CSV export's ``Metadata.csv`` gives them
    (:func:`hil.logs.sensorlogger.settings_of`): each value a string, a number or a boolean (``true``:
    a script's re-save) as its text, a ``null`` empty. A nested value in a key decided by
    (:data:`_SETTINGS_READ`) is an InputFormatError naming the record and the key; in any other it is
    never read."""
    pairs = []
    for key, value in metadata.record.items():
        if value is None:
            value = ""
        if isinstance(value, bool):
            value = str(value).lower()
        if not isinstance(value, str | int | float):
            if key.strip().lower() in _SETTINGS_READ:
                raise InputFormatError(
                    f"record {metadata.index} (Metadata): a {type(value).__name__} where the setting's "
                    "text is expected",
                    where,
                    metadata.line,
                    key,
                )
            continue
        pairs.append((key, str(value)))
    return settings_of(pairs)


def _read_records(
    c: Container, member: str, where: str
) -> tuple[dict[str, _Sensor], set[str], str | None, _Metadata | None]:
    """The records of the sensors the log uses (:data:`_SENSOR_FILES`), by the CSV file name they
    belong to; every other record is checked and passed over (the first :data:`MAX_NAMED` of their
    sensors' names are returned, for the notes); what was dropped of a file cut short (None: it was
    not), logged; and the ``Metadata`` record (None: there is none). A second ``Metadata`` record that
    says otherwise than the first is an InputFormatError naming both: which platform and frames the
    recording has cannot be told (read as the first, an iOS recording's axes could come out negated)."""
    sensors: dict[str, _Sensor] = {}
    ignored: set[str] = set()
    metadata: _Metadata | None = None
    pending = 0
    reader = _Reader(c.chunks(member, MAX_JSON_BYTES), where)
    for line, index, record in _records(reader):
        sensor = record.get("sensor")
        if not isinstance(sensor, str):
            raise InputFormatError(f"record {index} has no 'sensor' name", where, line, "sensor")
        if _is_metadata(record):
            if metadata is None:
                metadata = _Metadata(record, line, index)
            elif dict(metadata.record) != dict(record):
                raise InputFormatError(
                    f"record {index} is a second Metadata record, unlike record {metadata.index} (line "
                    f"{metadata.line}): the recording's platform and frames cannot be told",
                    where,
                    line,
                )
            continue
        name = _SENSOR_FILES.get(re.sub(r"[^a-z0-9]", "", sensor.lower()))
        if name is None:
            if len(ignored) < MAX_NAMED:
                ignored.add(shown(sensor, 30).strip("'\""))
            continue
        found = sensors.get(name)
        if found is None:
            found = sensors[name] = _sensor(name, record, index, line, where)
        if found.problem is None:
            _new_clocks(found, record)
            _append(found, record, index, line, where)
            found.rows += 1
        pending += 1
        if pending >= COUNT_EVERY:
            c.count_samples(pending, where, line)
            pending = 0
    c.count_samples(pending, where, None)
    if reader.cut_short is not None:
        logger.warning("%s", reader.cut_short)
    return sensors, ignored, reader.cut_short, metadata


def _append(sensor: _Sensor, record: dict[str, object], index: int, line: int, where: str) -> None:
    """One record's values of the keys read onto its sensor's rows: each a number or a string holding one
    (``nan`` is a number: a NaN sample, dropped and counted by the merge), ``time`` also as exact int64
    (as the CSV reader reads it: a value that is no integer or beyond int64 is its float's to tell). Its
    other keys are never looked at."""
    twice = getattr(record, "twice", ())
    for key in sensor.keys:
        if key not in record:
            if key == sensor.optional:
                sensor.values.append(math.nan)
                continue
            raise InputFormatError(
                f"record {index} has no {key!r}; its sensor's first record (line {sensor.first_line}) is "
                f"read by {', '.join(sensor.keys)}",
                where,
                line,
                key,
            )
        if key in twice:
            raise InputFormatError(
                f"record {index} gives {key!r} twice, with different values: which is meant cannot be told",
                where,
                line,
                key,
            )
        value = record[key]
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            what = type(value).__name__ if value is not None else "null"
            raise InputFormatError(
                f"record {index}: a {what} where a number (as a string) is expected", where, line, key
            )
        number: float | None
        try:
            # a string as the CSV reader reads its cell: not "1_0" nor "١٢", which Python's float() takes
            number = strict_number(value.strip()) if isinstance(value, str) else float(value)
        except (ValueError, OverflowError):
            number = _iso_time(value) if key == sensor.time_key and isinstance(value, str) else None
        if number is None:
            raise InputFormatError(
                f"record {index}: {shown(str(value)) + ' is not a number' if value != '' else 'empty value'}",
                where,
                line,
                key,
            )
        sensor.values.append(number)
        if key == sensor.time_key:
            sensor.times.append(_exact(value, number))


def _iso_time(value: str) -> float | None:
    """A ``time`` written as an ISO-8601 date (a script's re-save), as ns since the epoch
    (:func:`hil.logs.sensorlogger.iso_time_ns`, as the CSV reader reads one); None when it is none."""
    try:
        return iso_time_ns(value)
    except ValueError:
        return None


def _exact(value: str | int | float, number: float) -> int:
    """``value`` as an int64 integer: exactly when it is one (``"1698501144401773000"``), else its float
    rounded (0 when not finite or beyond int64: the float column marks that row unusable)."""
    try:
        whole = int(value) if not isinstance(value, float) else None
    except ValueError:
        whole = None
    if whole is not None and -(2**63) <= whole < 2**63:
        return whole
    return int(number) if math.isfinite(number) and abs(number) < 2.0**63 else 0


def _needed(sensor: _Sensor, table: Table | None) -> Table:
    """The table of a sensor the log reads; its problem when its records give none."""
    if sensor.problem is not None or table is None:
        raise sensor.problem or InputFormatError("no table", "")
    return table


def _table(sensor: _Sensor, where: str) -> Table:
    """A sensor's records as the table its CSV file would be (columns the record's keys)."""
    # views of the arrays, not copies: their records are all read, and a copy would double what is kept
    data = np.frombuffer(sensor.values, dtype=np.float64).reshape(-1, len(sensor.keys))
    exact = {sensor.time_key: np.frombuffer(sensor.times, dtype=np.int64)} if sensor.time_key else {}
    return Table(sensor.keys, data, where, sensor.first_line, exact)


def _records(reader: _Reader) -> Iterator[tuple[int, int, dict[str, object]]]:
    """(line, index from 1, record) of each element of the document's one top-level array, read by
    ``reader``, holding at most a piece and a record at once. Anything but an array of flat objects is an
    InputFormatError naming the file and the line (what a record's values are is :func:`_append`'s to
    judge, for the keys it reads). A file that ends before the array's closing ``]`` — inside a record,
    after its ``,`` or after it — was cut short (a copy or download stopped mid-way): the records before
    the end are given, the one it cut is dropped, and :attr:`_Reader.cut_short` says so."""
    if reader.next_char() != "[":
        raise reader.error("not a Sensor Logger JSON export: it does not start with '['")
    reader.advance()
    if reader.next_char() == "]":
        reader.advance()
        reader.expect_end()
        return
    index = 0
    while True:
        index += 1
        start = reader.next_char()
        if not start:
            reader.cut(f"ends after record {index - 1} and its ','" if index > 1 else "ends after its '['")
            return
        if start != "{":
            raise reader.error(f"record {index} is not an object (the export is an array of records)")
        line = reader.line
        record = reader.decode_object(index)
        if record is None:
            reader.cut(f"ends inside record {index} (from line {line}), which is dropped")
            return
        yield line, index, record
        following = reader.next_char()
        reader.advance()
        if not following:
            reader.cut(f"ends after record {index}")
            return
        if following == "]":
            reader.expect_end()
            return
        if following != ",":
            raise reader.error(f"{following!r} after record {index}, where ',' or ']' is expected")


class _Reader:
    """A JSON text read from a stream of byte pieces, a value at a time: ``buffer[pos:]`` is what is
    read and not yet taken, ``line`` the line ``pos`` is on."""

    def __init__(self, pieces: Iterator[bytes], where: str) -> None:
        self._pieces = pieces
        self._decoder = codecs.getincrementaldecoder("utf-8-sig")()
        self._json = json.JSONDecoder(object_pairs_hook=_Record.of, parse_int=_integer)
        self.where = where
        self.buffer = ""
        self.pos = 0
        self.line = 1
        self.ended = False
        self.cut_short: str | None = None  # the file ended before the array closed: what was dropped

    def error(self, what: str) -> InputFormatError:
        return InputFormatError(what, self.where, self.line)

    def cut(self, what: str) -> None:
        """The file ended before the array's closing ']': ``what`` that means, noted."""
        self.cut_short = (
            f"{self.where}:{self.line}: the file cut short (a copy, download or recording stopped "
            f"mid-write): it {what}, without the array's closing ']'; the records before that read"
        )

    def _more(self) -> bool:
        """Read the next piece onto the buffer (the part taken dropped); False at the end."""
        if self.ended:
            return False
        piece = next(self._pieces, None)
        held = self.line + self.buffer.count("\n", self.pos)  # the line the piece starts on
        try:
            text = self._decoder.decode(piece or b"", final=piece is None)
        except UnicodeDecodeError as exc:
            line = held + (piece or b"").count(b"\n", 0, exc.start)
            what = f"not UTF-8 text ({exc.reason}): not a JSON export (gzipped, or binary, under .json?)"
            raise InputFormatError(what, self.where, line) from None
        nul = text.find("\x00")
        if nul >= 0:
            line = held + text.count("\n", 0, nul)
            raise InputFormatError("binary data (a NUL byte), not a JSON export", self.where, line)
        self.ended = piece is None
        self.buffer = self.buffer[self.pos :] + text
        self.pos = 0
        return bool(text) or not self.ended

    def _skip_blank(self) -> None:
        while True:
            end = len(self.buffer)
            start = self.pos
            while self.pos < end and self.buffer[self.pos] in _WHITESPACE:
                self.pos += 1
            self.line += self.buffer.count("\n", start, self.pos)
            if self.pos < end or not self._more():
                return

    def next_char(self) -> str:
        """The next character that is not blank ("" at the end of the file)."""
        self._skip_blank()
        return self.buffer[self.pos] if self.pos < len(self.buffer) else ""

    def advance(self) -> None:
        self.pos += 1

    def expect_end(self) -> None:
        if self.next_char():
            raise self.error("more after the array's closing ']': not one JSON export")

    def decode_object(self, index: int) -> dict[str, object] | None:
        """The object starting at ``pos``: parsed once the buffer holds all of it (read on while it is
        cut short, up to :data:`MAX_RECORD_CHARS`); None when the file ends inside it. Its values may be
        anything JSON holds (nested ones too): only the keys a sensor is read by are judged
        (:func:`_append`)."""
        while True:
            try:
                value, end = self._json.raw_decode(self.buffer, self.pos)
                break
            except RecursionError:
                raise self.error(
                    f"record {index} is nested too deep: not the export's flat records"
                ) from None
            except json.JSONDecodeError as exc:
                # raw_decode stops at the object's end: failing, the object is malformed or cut short
                if len(self.buffer) - self.pos >= MAX_RECORD_CHARS:
                    raise self.error(
                        f"record {index} is not JSON ({exc.msg}) or longer than {MAX_RECORD_CHARS} "
                        "characters: not the export's records"
                    ) from None
                if not self._more():
                    return None  # the file ends inside it: cut short
        if end - self.pos > MAX_RECORD_CHARS:
            raise self.error(f"record {index} is longer than {MAX_RECORD_CHARS} characters: not the export's")
        self.line += self.buffer.count("\n", self.pos, end)
        self.pos = end
        return value


class _Record(dict[str, object]):
    """A JSON object as read: its first value of each key (as the CSV reader reads a name its header
    holds twice from its first column), and ``twice`` the keys given again with another value."""

    twice: frozenset[str] = frozenset()

    @classmethod
    def of(cls, pairs: list[tuple[str, object]]) -> _Record:
        record = cls()
        twice = set()
        for key, value in pairs:
            if key not in record:
                record[key] = value
            elif record[key] != value or repr(record[key]) != repr(value):
                twice.add(key)
        if twice:
            record.twice = frozenset(twice)
        return record


def _integer(digits: str) -> int | float:
    """A JSON integer: exact, or (past Python's digit limit: 10 000 digits in a key never read) its
    float, ``inf``, as a CSV cell of those digits is read."""
    try:
        return int(digits)
    except ValueError:
        return float(digits)
