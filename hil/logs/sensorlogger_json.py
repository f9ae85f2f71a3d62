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
well. Records of the other sensors (location, battery, …) are checked to be flat objects and passed over.

The file is read as a stream (:meth:`hil.logs.table.Container.chunks`), a record at a time: memory is
bounded by the samples kept (8 bytes a value), not by the file's size. The file is at most
:data:`MAX_JSON_BYTES` (decompressed, for a ``.json.gz``), a record at most :data:`MAX_RECORD_CHARS`, its
rows count towards the log's :data:`~hil.logs.table.MAX_LOG_SAMPLES`; anything that is not the layout
above (not JSON, not UTF-8, binary or gzipped bytes under a ``.json`` name, nested values, a record whose
keys differ from its sensor's first) is an :class:`InputFormatError` naming the file, the line and the
record.
"""

from __future__ import annotations

import codecs
import json
import math
import re
from array import array
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from hil.estimation.sensors import SensorLog
from hil.files.bounded import MAX_MEMBER_BYTES
from hil.logs.rows import shown
from hil.logs.sensorlogger import ACC_FILES, GYR_FILES, MAG_FILES, Export, assemble
from hil.logs.table import Container, Table
from protocol.errors import InputFormatError

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
    """Whether the member's first bytes are the start of the export: an array whose first record has a
    ``sensor`` and a clock key."""
    head = " ".join(c.head(member, 40)).lstrip()
    return head.startswith("[") and _HEAD_KEYS.search(head) is not None


def detect(c: Container) -> bool:
    return any(_is_export(c, n) for n in _json_members(c)[:20])


@dataclass
class _Sensor:
    """One sensor's records as they are read: its keys (the first record's, ``sensor`` left out), the
    values of each row flattened (float), and ``time`` as exact int64 when it is one of the keys."""

    keys: tuple[str, ...]
    first_line: int
    values: array[float] = field(default_factory=lambda: array("d"))
    times: array[int] = field(default_factory=lambda: array("q"))


def read(c: Container) -> SensorLog:
    exports = [n for n in _json_members(c) if _is_export(c, n)]
    if not exports:
        raise InputFormatError("no Sensor Logger JSON export (an array of records) here", str(c.path))
    if len(exports) > 1:
        raise InputFormatError(
            f"{len(exports)} Sensor Logger JSON exports ({', '.join(exports[:4])}): recordings side by "
            "side; replay one",
            str(c.path),
        )
    member = exports[0]
    where = c.where(member)
    sensors, ignored = _read_records(c, member, where)
    tables = {name: _table(sensor, where) for name, sensor in sensors.items()}
    export = Export(
        str(c.path),
        {name: f"{where} (sensor {name.removesuffix('.csv')})" for name in tables},
        lambda name: tables[name],
        lambda name: False,  # a sensor without records is not in the file at all
        lambda: "",
    )
    notes = [f"Sensor Logger JSON export: {member}, records read by key (x, y, z by name)"]
    if ignored:
        more = ", …" if len(ignored) >= MAX_NAMED else ""
        notes.append(f"records of other sensors passed over: {', '.join(sorted(ignored))}{more}")
    return assemble(export, NAME, notes)


def _read_records(c: Container, member: str, where: str) -> tuple[dict[str, _Sensor], set[str]]:
    """The records of the sensors the log uses (:data:`_SENSOR_FILES`), by the CSV file name they
    belong to; every other record is checked and passed over (the first :data:`MAX_NAMED` of their
    sensors' names are returned, for the notes)."""
    sensors: dict[str, _Sensor] = {}
    ignored: set[str] = set()
    pending = 0
    for line, index, record in _records(c.chunks(member, MAX_JSON_BYTES), where):
        sensor = record.get("sensor")
        if not isinstance(sensor, str):
            raise InputFormatError(f"record {index} has no 'sensor' name", where, line, "sensor")
        name = _SENSOR_FILES.get(re.sub(r"[^a-z0-9]", "", sensor.lower()))
        if name is None:
            if len(ignored) < MAX_NAMED:
                ignored.add(shown(sensor, 30).strip("'\""))
            continue
        keys = tuple(k for k in record if k != "sensor")
        found = sensors.get(name)
        if found is None:
            if not keys:
                raise InputFormatError(f"record {index} ({sensor}) holds no values", where, line)
            found = sensors[name] = _Sensor(keys, line)
        elif len(keys) != len(found.keys) or set(keys) != set(found.keys):
            raise InputFormatError(
                f"record {index} ({sensor}) has keys {', '.join(keys)}; its sensor's first record (line "
                f"{found.first_line}) has {', '.join(found.keys)}",
                where,
                line,
            )
        _append(found, record, index, line, where)
        pending += 1
        if pending >= COUNT_EVERY:
            c.count_samples(pending, where, line)
            pending = 0
    c.count_samples(pending, where, None)
    return sensors, ignored


def _append(sensor: _Sensor, record: dict[str, object], index: int, line: int, where: str) -> None:
    """One record's values onto its sensor's rows: each a number or a string holding one (``nan`` is a
    number: a NaN sample, dropped and counted by the merge), ``time`` also as exact int64 (as the CSV
    reader reads it: a value that is no integer or beyond int64 is its float's to tell)."""
    for key in sensor.keys:
        value = record[key]
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            what = type(value).__name__ if value is not None else "null"
            raise InputFormatError(
                f"record {index}: a {what} where a number (as a string) is expected", where, line, key
            )
        try:
            if isinstance(value, str) and "_" in value:  # Python's float() takes "1_0"; no CSV reader does
                raise ValueError(value)
            number = float(value)
        except (ValueError, OverflowError):
            raise InputFormatError(
                f"record {index}: {shown(str(value))} is not a number", where, line, key
            ) from None
        sensor.values.append(number)
        if key == "time":
            sensor.times.append(_exact(value, number))


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


def _table(sensor: _Sensor, where: str) -> Table:
    """A sensor's records as the table its CSV file would be (columns the record's keys)."""
    # views of the arrays, not copies: their records are all read, and a copy would double what is kept
    data = np.frombuffer(sensor.values, dtype=np.float64).reshape(-1, len(sensor.keys))
    exact = {"time": np.frombuffer(sensor.times, dtype=np.int64)} if "time" in sensor.keys else {}
    return Table(sensor.keys, data, where, sensor.first_line, exact)


def _records(pieces: Iterator[bytes], where: str) -> Iterator[tuple[int, int, dict[str, object]]]:
    """(line, index from 1, record) of each element of the document's one top-level array, read from
    ``pieces`` of its bytes, holding at most a piece and a record at once. Anything but an array of flat
    objects is an InputFormatError naming ``where`` and the line."""
    reader = _Reader(pieces, where)
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
        if reader.next_char() != "{":
            raise reader.error(f"record {index} is not an object (the export is an array of records)")
        line = reader.line
        record = reader.decode_object(index)
        yield line, index, record
        following = reader.next_char()
        reader.advance()
        if not following:
            raise reader.error(f"the file ends after record {index} without the array's closing ']'")
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
        self._json = json.JSONDecoder()
        self.where = where
        self.buffer = ""
        self.pos = 0
        self.line = 1
        self.ended = False

    def error(self, what: str) -> InputFormatError:
        return InputFormatError(what, self.where, self.line)

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

    def decode_object(self, index: int) -> dict[str, object]:
        """The object starting at ``pos``: parsed once the buffer holds all of it (read on while it is
        cut short, up to :data:`MAX_RECORD_CHARS`), and checked to be flat."""
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
                    raise self.error(f"record {index} is not JSON ({exc.msg})") from None
            except ValueError as exc:  # an integer past Python's digit limit
                raise self.error(f"record {index} is not a record of the export ({exc})") from None
        if end - self.pos > MAX_RECORD_CHARS:
            raise self.error(f"record {index} is longer than {MAX_RECORD_CHARS} characters: not the export's")
        nested = next((k for k, v in value.items() if isinstance(v, dict | list)), None)
        if nested is not None:
            raise InputFormatError(
                f"record {index} holds a nested value: the export's records are flat",
                self.where,
                self.line,
                nested,
            )
        self.line += self.buffer.count("\n", self.pos, end)
        self.pos = end
        return value
