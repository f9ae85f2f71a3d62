"""A run's directory: telemetry CSV, events log, summary — written incrementally so a killed run keeps
everything it logged.

Layout of ``RUN_DIR``::

    telemetry.csv   one row per control step: time, estimates, truth (simulated runs), commands, board
                    telemetry, link statistics (columns fixed when the run starts; header first)
    events.jsonl    one JSON object per line: board LOG messages, state changes, faults, resets
    summary.json    written when the run ends (atomically: a killed run has none, ``hil report`` copes;
                    signals that come while it is written are held: :mod:`hil.runtime.held_signals`)
    scenario.toml   the scenario the run used (a copy), when there was one
    telemetry_codes.json  what the numbers in telemetry.csv's coded columns mean (:mod:`.codes`)
    *.png           plots (``hil report RUN_DIR`` redraws them)

Each event is flushed to the operating system as it is written, each telemetry row by the log's writer
thread moments later (:class:`CsvLog`), so SIGKILL loses at most a partly written last line, which
:func:`read_telemetry` drops and counts. A write the OS refuses (a full disk) leaves no torn line: the file
is cut back to its last whole line (:class:`hil.files.appending.LineAppender`), the run ends with an
:class:`~hil.files.output.OutputError` naming the file, and what could not be written is counted in the
summary (``telemetry_rows_not_written``) or kept in it (``events_not_written``).
"""

from __future__ import annotations

import collections
import contextlib
import json
import math
import os
import queue
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hil.files.appending import LineAppender
from hil.files.bounded import MAX_LINE_BYTES, load_json, read_lines, regular_file_if_there
from hil.files.output import OutputError, make_dir, safe_label
from hil.threads import ThreadError
from protocol.errors import InputFormatError

TELEMETRY = "telemetry.csv"
EVENTS = "events.jsonl"
SUMMARY = "summary.json"


def new_run_dir(root: str | os.PathLike[str], label: str) -> Path:
    """A fresh directory ``root/YYYYmmdd-HHMMSS-label[-n]`` (never an existing one; ``label`` made safe
    and cut, :func:`hil.files.output.safe_label`); a ConfigError naming it when it cannot be made."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    base = Path(root) / f"{stamp}-{safe_label(label)}"
    path, n = base, 1
    while True:
        try:
            return make_dir(path, exist_ok=False)
        except FileExistsError:
            n += 1
            path = base.with_name(f"{base.name}-{n}")


Tap = Callable[[Mapping[str, Any]], None]
"""Called with each row or event record as it is written (a run's observer, :mod:`hil.gcs`)."""


class RowTap:
    """Rows that go to a tap only, never to a file: what a run without a run directory writes when its
    observer wants the rows (a fault campaign's run checks its invariants on them). ``keep`` names the
    columns the tap is given (default: all); the rest are not copied."""

    def __init__(self, columns: Sequence[str], tap: Tap, keep: Sequence[str] | None = None) -> None:
        self.columns = tuple(columns)
        index = {name: i for i, name in enumerate(self.columns)}
        names = self.columns if keep is None else tuple(keep)
        missing = [name for name in names if name not in index]
        if missing:
            raise KeyError(f"no column(s) {missing}")
        self._picks = tuple((name, index[name]) for name in names)
        self.tap = tap
        self.rows = 0

    def write_values(self, values: Sequence[Any]) -> None:
        """One row in column order, handed to the tap by name (the kept columns)."""
        if len(values) != len(self.columns):
            raise ValueError(f"{len(values)} values for {len(self.columns)} columns")
        self.rows += 1
        self.tap({name: values[i] for name, i in self._picks})

    def flush(self) -> None:
        """Nothing is held back."""

    def close(self) -> None:
        """Nothing to close."""


class CsvLog:
    """Rows of numbers under a fixed header. Missing values (None, NaN) are written empty (read as NaN).

    Written off the caller's thread: :meth:`write_values` puts the row on a bounded queue (a list of
    numbers in column order: no formatting on the control tick) and a writer thread, woken by a row, lets
    rows gather for ``batch_s`` (wall time: one write and one flush per batch, not per row), then formats
    whatever has queued, writes it and flushes it to the operating system — so a killed run keeps every row
    older than about ``batch_s``, at most a torn last line. A full queue (``max_pending`` rows: a disk that
    stalls for that long) makes the caller wait: rows are never dropped. An error of the writer thread (a
    full disk: an :class:`~hil.files.output.OutputError`) is raised by the next :meth:`write_values`,
    :meth:`flush` or :meth:`close`; the file then ends at the last row that fitted whole, and the rows not
    written (the rest of that batch and any after it) are counted in :attr:`rows_not_written`, never
    written later past the gap. ``tap``
    (optional: a run's observer, :mod:`hil.gcs`) sees each row, by column name, as it is written.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        columns: Sequence[str],
        max_pending: int = 4096,
        batch_s: float = 0.05,
        tap: Tap | None = None,
    ) -> None:
        if len(set(columns)) != len(columns):
            raise ValueError(f"duplicate CSV columns: {list(columns)}")
        self.path = Path(path)
        self.columns = tuple(columns)
        self._index = {name: i for i, name in enumerate(self.columns)}
        self._file: LineAppender | None = LineAppender(self.path, "w")
        try:
            self._file.write((",".join(self.columns) + _EOL).encode())
        except BaseException:
            self._file.close()
            raise
        self.rows = 0
        self._not_written = 0  # the writer thread's count, after a refused write
        self._refused = 0  # the caller's: rows offered as the refusal was raised
        self._queue: queue.Queue[Sequence[Any] | None] = queue.Queue(max_pending)
        self._batch_s = batch_s
        self._closing = threading.Event()
        # The writer thread's error (a full disk), raised as it is, once, by the next write, flush or close.
        self._thread_error = ThreadError(None, once=True)
        self._thread = threading.Thread(target=self._run, name=f"csv:{self.path.name}", daemon=True)
        self._thread.start()
        self.tap = tap

    def write(self, row: Mapping[str, Any]) -> None:
        """Write one row given by column name (unknown keys raise KeyError: a typo must not silently drop a
        column)."""
        unknown = set(row) - set(self._index)
        if unknown:
            raise KeyError(f"{self.path.name}: no column(s) {sorted(unknown)}")
        self.write_values([row.get(c) for c in self.columns])

    def write_values(self, values: Sequence[Any]) -> None:
        """Write one row given as ``len(columns)`` values in column order (the control tick's path)."""
        if self._file is None:
            raise ValueError(f"{self.path}: log is closed")
        try:
            self._thread_error.check()
        except BaseException:
            self._refused += 1  # this row too: the run ends on the error, the row is not written
            raise
        if len(values) != len(self.columns):
            raise ValueError(f"{self.path.name}: {len(values)} values for {len(self.columns)} columns")
        self._queue.put(values)
        self.rows += 1
        if self.tap is not None:
            self.tap(dict(zip(self.columns, values, strict=True)))

    @property
    def rows_not_written(self) -> int:
        """Rows given to the log that are not in its file (after a write the OS refused; exact once the
        log is closed)."""
        return self._not_written + self._refused

    def flush(self) -> None:
        """Wait until every row written so far is in the file (flushed to the operating system; up to
        ``batch_s`` later)."""
        if self._file is not None:
            self._queue.join()
        self._thread_error.check()

    def close(self) -> None:
        if self._file is None:
            return
        self._closing.set()
        self._queue.put(None)
        self._thread.join()
        self._file.close()  # nothing held back: never raises for the rows
        self._file = None
        self._thread_error.check()

    def _run(self) -> None:
        """The writer thread: everything queued, formatted and written in one go, then flushed."""
        assert self._file is not None
        out = self._file
        q = self._queue
        failed = False
        while True:
            batch = [q.get()]
            self._closing.wait(self._batch_s)  # let rows gather (not when closing)
            while True:
                try:
                    batch.append(q.get_nowait())
                except queue.Empty:
                    break
            rows = [r for r in batch if r is not None]
            before = out.size
            data = b""
            try:
                if rows and not failed:
                    data = "".join(",".join(map(_cell, r)) + _EOL for r in rows).encode()
                    out.write(data)
                elif rows:  # after a refused write: counted, never written past the gap
                    self._not_written += len(rows)
            except BaseException as exc:  # stored, raised on the caller's thread: never lost silently
                failed = True  # the rows that fitted are in the file, whole; the others counted
                self._not_written += len(rows) - data[: out.size - before].count(b"\n")
                self._thread_error.store(exc)
            finally:
                for _ in batch:
                    q.task_done()
            if len(rows) < len(batch):  # the close() sentinel
                return

    def __enter__(self) -> CsvLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_EOL = "\r\n"  # csv.writer's line terminator: the files' format since the first runs


def _cell(value: Any) -> str:
    """A CSV cell: floats (Python or numpy) at full precision, NaN and None empty."""
    if type(value) is float:  # the common case first
        return repr(value) if value == value else ""
    if value is None:
        return ""
    if isinstance(value, float | np.floating):
        return "" if math.isnan(value) else repr(float(value))
    if isinstance(value, np.integer | np.bool_):
        return str(int(value))
    return str(value)


class EventLog:
    """JSON lines, each flushed: ``{"t": seconds, "kind": ..., ...}``. ``path`` None keeps the events in
    memory instead (``events``; a run without a run directory, e.g. a Monte Carlo run), the newest
    ``keep`` of them: older ones are counted in ``dropped``, never an unbounded list. ``tap`` (optional)
    sees each record as it is written.

    A write the OS refuses (a full disk) raises an :class:`~hil.files.output.OutputError` once, leaving the
    file at its last whole line; that event and every later one are kept in :attr:`unwritten` instead (the
    newest ``keep``, older ones counted in ``dropped``) without raising again — the run is already ending on
    the first error, and what it still records on its way out (its Disarm) goes into its summary."""

    def __init__(
        self, path: str | os.PathLike[str] | None, keep: int = 10_000, tap: Tap | None = None
    ) -> None:
        self.path = None if path is None else Path(path)
        self._file: LineAppender | None = None
        if self.path is not None:
            self._file = LineAppender(self.path, "a")
        self.events: collections.deque[dict[str, Any]] = collections.deque(maxlen=keep)
        self.unwritten: collections.deque[dict[str, Any]] = collections.deque(maxlen=keep)
        self.failed: OutputError | None = None  # the refused write, once there was one
        self._closed = False
        self.count = 0
        self.dropped = 0
        self.tap = tap

    def write(self, t: float, kind: str, **fields: Any) -> None:
        if self._closed:
            raise ValueError(f"{self.path or 'event log'}: log is closed")
        record = event = {"t": t, "kind": kind, **fields}
        refused: OutputError | None = None
        if self._file is not None and self.failed is None:
            try:
                self._file.write((json.dumps(event, default=str) + "\n").encode())
            except OutputError as exc:
                refused = self.failed = exc
        if self._file is None:
            self.dropped += len(self.events) == self.events.maxlen
            self.events.append(event)
        elif self.failed is not None:
            self.dropped += len(self.unwritten) == self.unwritten.maxlen
            self.unwritten.append(event)
        self.count += 1
        if self.tap is not None:
            self.tap(record)
        if refused is not None:
            raise refused

    def close(self) -> None:
        self._closed = True
        if self._file is not None:
            self._file.close()
            self._file = None


def write_summary(run_dir: str | os.PathLike[str], summary: Mapping[str, Any]) -> Path:
    """Write ``summary.json`` atomically (a reader never sees half a file); a write the OS refuses (a full
    disk, the directory gone) an :class:`~hil.files.output.OutputError` naming it, no temporary file left."""
    path = Path(run_dir) / SUMMARY
    tmp = path.with_suffix(".json.tmp")
    text = json.dumps(summary, indent=2, default=_json_default, allow_nan=True) + "\n"
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise OutputError(path, exc) from exc
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


MAX_ROW_TIME_S = 1e7
"""The largest time (s, either sign) a telemetry row may carry: a run lasts at most a day of simulated time
(:data:`hil.scenario.reader.MAX_DURATION_S`), and waits for its board and phone by bounded timeouts; 1e7 s
is 115 days."""


class RowClock:
    """Which rows of a run's telemetry are in time order: a row is taken while its time ``t`` (s; column 0)
    is finite, within ±:data:`MAX_ROW_TIME_S` and not before the last row taken. A run writes its rows in
    the order of its ticks; a file edited, spliced or damaged may not — a row at 1e300 s squashed every
    figure into its first pixel, rows repeated from earlier drew the run twice over itself. Such rows are
    not taken (their readers count them as dropped)."""

    def __init__(self) -> None:
        self.last = -math.inf

    def take(self, t: float | None) -> bool:
        """Whether the row at ``t`` (None: an empty cell) is taken; a taken row moves the clock on."""
        if t is None or not (self.last <= t <= MAX_ROW_TIME_S and t >= -MAX_ROW_TIME_S):
            return False
        self.last = t
        return True


RUN_FILES_ONLY = ": a run directory holds files (a device, a FIFO there is never read: /dev/zero never ends)"
"""Said of a run's telemetry or events that is there and is not a regular file."""


def read_telemetry(path: str | os.PathLike[str]) -> Telemetry:
    """Read a run's telemetry CSV, streamed (:func:`hil.files.bounded.read_lines`: memory holds the
    numbers, not the text). A line with the wrong number of cells, a non-number, bytes that are not UTF-8
    or more than :data:`~hil.files.bounded.MAX_LINE_BYTES` is dropped and counted (a run killed mid-write
    leaves one), and so is a row out of time order (:class:`RowClock`); a missing or header-less file is an
    InputFormatError."""
    path = Path(path)
    regular_file_if_there(path, InputFormatError, "telemetry", RUN_FILES_ONLY)
    try:
        f = open(path, "rb")  # noqa: SIM115 — closed below
    except FileNotFoundError:
        raise InputFormatError("no such file (telemetry)", str(path)) from None
    except OSError as exc:
        raise InputFormatError(f"cannot read telemetry: {exc.strerror}", str(path)) from exc
    header: list[str] | None = None
    blocks: list[np.ndarray] = []
    dropped = 0
    clock = RowClock()
    with f:
        for batch in read_lines(f):
            if header is None:
                header = _header(batch.pop(0), path)
            values = []
            for line in batch:
                row = _numbers(line, len(header))
                if row is None or not clock.take(row[0]):
                    dropped += 1
                else:
                    values.append(row)
            if values:
                blocks.append(np.array(values, dtype=float))
    if header is None:
        raise InputFormatError("empty file (no header)", str(path), 1)
    data = np.concatenate(blocks) if blocks else np.zeros((0, len(header)))
    return Telemetry({name: data[:, i] for i, name in enumerate(header)}, len(data), dropped)


def _header(line: bytes | None, path: Path) -> list[str]:
    """A telemetry file's column names (its first line), or InputFormatError naming its line 1."""
    if line is None:
        raise InputFormatError(f"a header longer than {MAX_LINE_BYTES} bytes: not telemetry", str(path), 1)
    try:
        text = line.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputFormatError(f"not a text file (not UTF-8: {exc.reason})", str(path), 1) from None
    return telemetry_header(text, path)


def telemetry_header(line: str, path: str | os.PathLike[str]) -> list[str]:
    """The column names of a telemetry file's first line ``line``: a run's, whose first column is its time
    ``t``; anything else (a file cut at its head, another CSV) an InputFormatError naming line 1 — every
    reader of a run's rows takes column 0 for the time."""
    columns = line.rstrip("\r").split(",")
    if columns[0] != "t":
        raise InputFormatError(
            f"no 't' column first (found {columns[0][:40]!r}): not a run's telemetry", str(path), 1
        )
    return columns


def _numbers(line: bytes | None, width: int) -> list[float] | None:
    """A telemetry row's ``width`` numbers (an empty cell is NaN), or None for a damaged line."""
    if line is None:
        return None
    try:
        cells = line.decode("utf-8").split(",")
        if len(cells) != width:
            return None
        return [float(c) if c != "" else math.nan for c in cells]
    except (UnicodeDecodeError, ValueError):
        return None


def read_events(path: str | os.PathLike[str]) -> tuple[list[dict[str, Any]], int]:
    """Events of a run and the number of unreadable lines (torn by a kill, not a JSON object, nested more
    than :data:`~hil.files.bounded.MAX_NESTING` deep, longer than :data:`~hil.files.bounded.MAX_LINE_BYTES`):
    dropped and counted, never fatal. Memory holds the events, not the file."""
    events: list[dict[str, Any]] = []
    bad = 0
    for event in _events(Path(path)):
        if event is None:
            bad += 1
        else:
            events.append(event)
    return events, bad


def count_events(path: str | os.PathLike[str]) -> tuple[int, int]:
    """The number of readable events and of unreadable lines in a run's events log (as
    :func:`read_events`), without holding them."""
    good = bad = 0
    for event in _events(Path(path)):
        good += event is not None
        bad += event is None
    return good, bad


def _events(path: Path) -> Iterator[dict[str, Any] | None]:
    """Each line of an events log as its event, or None when it is unreadable; nothing if there is no
    file."""
    regular_file_if_there(path, InputFormatError, "events", RUN_FILES_ONLY)
    try:
        f = open(path, "rb")  # noqa: SIM115 — closed below
    except FileNotFoundError:
        return
    except OSError as exc:
        raise InputFormatError(f"cannot read events: {exc.strerror}", str(path)) from exc
    with f:
        for batch in read_lines(f):
            for line in batch:
                yield event_of(line, str(path))


def event_of(line: bytes | None, where: str) -> dict[str, Any] | None:
    """One line of an events log as its event (a JSON object), or None if it is damaged (see
    :func:`read_events`)."""
    if line is None:
        return None
    try:
        value = load_json(line, where)
    except InputFormatError:
        return None
    return value if isinstance(value, dict) else None
