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

import bisect
import collections
import itertools
import math
import os
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

import numpy as np

from hil.files.appending import LineAppender
from hil.files.bounded import (
    CHUNK_BYTES,
    MAX_LINE_BYTES,
    LineSplitter,
    load_json,
    read_document,
    read_lines,
    regular_file_if_there,
)
from hil.files.json_text import strict_json
from hil.files.output import OutputError, make_dir, replace_file, safe_label
from hil.threads import ThreadError
from protocol.errors import InputFormatError

TELEMETRY = "telemetry.csv"
EVENTS = "events.jsonl"
SUMMARY = "summary.json"


def new_run_dir(root: str | os.PathLike[str], label: str) -> Path:
    """A fresh directory ``root/YYYYmmdd-HHMMSS-label[-n]`` (never an existing one: a name taken by
    anything — a directory, a file, a link to nothing — moves on to the next ``n``; ``label`` made safe
    and cut to fit a file name, :func:`hil.files.output.safe_label`); a ConfigError naming it, or the part
    of ``root`` in its way, when it cannot be made."""
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
                self._file.write((strict_json(event) + "\n").encode())
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
    disk, the directory gone) an :class:`~hil.files.output.OutputError` naming it, no temporary file left.

    Each writer has its own temporary (:func:`~hil.files.output.replace_file`: renamed into place): two
    writers at once — ``hil report DIR`` while the session writing DIR ends, two reports — shared one fixed
    ``summary.json.tmp``, so one renamed the other's half-written file into place (a reader saw invalid
    JSON) and the other's rename failed ("No such file or directory"). Now the last rename wins, whole.

    JSON has no NaN or infinity: a figure that is not a finite number is written as null, as a figure never
    measured is (:func:`hil.files.json_text.strict_json`; the events too)."""
    text = strict_json(summary, indent=2) + "\n"
    return replace_file(Path(run_dir) / SUMMARY, lambda f: f.write(text.encode("utf-8")))


@dataclass
class Telemetry:
    """A telemetry CSV read back: ``columns[name]`` is a float array (NaN where empty)."""

    columns: dict[str, np.ndarray]
    rows: int
    dropped_lines: int  # a torn last line (killed run), malformed lines, rows out of time order: counted

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __contains__(self, name: str) -> bool:
        return name in self.columns


MAX_ROW_TIME_S = 1e7
"""The largest time (s, either sign) a telemetry row may carry: a run lasts at most a day of simulated time
(:data:`hil.scenario.reader.MAX_DURATION_S`), and waits for its board and phone by bounded timeouts; 1e7 s
is 115 days."""

LOOKAHEAD_ROWS = 32
"""The most rows :class:`RowOrder` holds after a row it doubts (0.16 s of a 200 Hz run)."""
JUMP_STEPS = 8.0
"""A row more than this many steps (the run's recent step between rows) after the last one taken is
doubted (:class:`RowOrder`): a late tick is a step or two, a stall longer."""
START_S = 10.0
"""Before a run's step is known (its first rows), a row more than this many seconds after the last one taken
(the first row: at more than this from 0 s, either sign) is doubted: a run's clock starts at 0 s."""

R = TypeVar("R")


class RowOrder(Generic[R]):
    """Which rows of a run's telemetry are in time order, streamed: each row (its time ``t``, s, column 0,
    and whatever the reader keeps of it) is offered in file order, and the rows taken come out in order.

    A run writes its rows in the order of its ticks; a file edited, spliced or damaged may not — a row at
    1e300 s squashed every figure into its first pixel, rows repeated from earlier drew the run twice over
    itself, and one row at a large but possible time (5e6 s), once taken, put every later row of the run
    "before" it. The policy:

    - a row whose time is empty, not finite, beyond ±:data:`MAX_ROW_TIME_S` or before the last row taken is
      dropped;
    - a row within :data:`JUMP_STEPS` steps of the last one taken (the step: the recent spacing of the rows
      taken; :data:`START_S` before it is known) is taken at once — the common case, no delay;
    - a row further ahead is doubted: it is held with the rows after it, up to :data:`LOOKAHEAD_ROWS` of
      them (or to the end of the file), then judged on them. It is dropped when one of them goes on from
      the last row taken, within those steps (the earlier sequence goes on: the doubted row is a stray);
      otherwise it is taken when taking it keeps at least as many of them in order as leaving it out would
      (the longest run of them in time order, with and without it; a tie goes to the side most of them are
      on). So a real jump ahead (a run that stalled) followed by rows after it is taken, late; stray rows
      far ahead are dropped as long as the run's own rows come back within the look-ahead, and the run
      goes on. The held rows are then offered again, in order.

    Memory holds at most ``lookahead + 1`` rows. What it cannot tell: more than ``lookahead`` stray rows
    together; a stray row less than :data:`JUMP_STEPS` steps ahead (taken: the few rows it passes are
    dropped); a stray row at the very start of a file before the run's first row, or at its very end after
    the last (in order: taken); a real jump followed, within the look-ahead, by a stray row from before it
    (the rows after the jump held with it are dropped). Rows dropped are counted
    in :attr:`dropped`; :meth:`end` gives the rows still held when nothing more will come."""

    def __init__(self, lookahead: int = LOOKAHEAD_ROWS, jump: float = JUMP_STEPS) -> None:
        self.lookahead = lookahead
        self.jump = jump
        self.last = -math.inf  # the time of the last row taken
        self.step: float | None = None  # the recent spacing of the rows taken (s)
        self.taken = 0
        self.dropped = 0
        self._held: list[tuple[float, R]] = []  # the doubted row, then the rows after it

    @property
    def held(self) -> int:
        """Rows held (a doubted one and those after it), not yet taken or dropped."""
        return len(self._held)

    def offer(self, t: float | None, row: R) -> list[R]:
        """The rows taken now that the row at ``t`` (None: an empty cell) is offered, in order (none, this
        one, or rows held and this one)."""
        out: list[R] = []
        self.offer_into(t, row, out)
        return out

    def end(self) -> list[R]:
        """Nothing more will be offered: the rows held are judged on what came after them."""
        out: list[R] = []
        while self._held:
            self._judge(out)
        return out

    def offer_into(self, t: float | None, row: R, out: list[R]) -> None:
        """:meth:`offer`, the rows taken appended to ``out`` (a reader's batch: no list per row)."""
        if t is None or not (self.last <= t <= MAX_ROW_TIME_S and t >= -MAX_ROW_TIME_S):  # NaN: False
            self.dropped += 1
        elif self._held:
            self._held.append((t, row))
            if len(self._held) > self.lookahead:
                self._judge(out)
        elif self._doubted(t):
            self._held.append((t, row))
        else:
            if self.taken and t > self.last:  # the spacing, forgetting a long one slowly (a late tick)
                self.step = max(t - self.last, 0.5 * (self.step or 0.0))
            self._take(t, row, out)

    def _doubted(self, t: float) -> bool:
        """Whether ``t`` (not before the last row taken) is further ahead of it than the run's steps."""
        if self.taken == 0:
            return abs(t) > START_S
        if self.step is None:
            return t - self.last > START_S
        return t - self.last > self.jump * self.step

    def _take(self, t: float, row: R, out: list[R]) -> None:
        self.last = t
        self.taken += 1
        out.append(row)

    def _judge(self, out: list[R]) -> None:
        """The doubted row taken or dropped on the rows held after it, which are then offered again."""
        (t, row), rest = self._held[0], self._held[1:]
        self._held = []
        after = [u for u, _ in rest]
        on = [u for u in after if u >= t]
        with_it, without = 1 + _in_order(on), _in_order(after)
        goes_on = not all(map(self._doubted, after))  # a row after it within steps of the last taken
        if not goes_on and (with_it > without or (with_it == without and 2 * len(on) >= len(after))):
            steps = sorted(b - a for a, b in itertools.pairwise(on) if b > a)
            if steps:  # the spacing of the rows that go on from it (a run's rate may have changed)
                self.step = steps[len(steps) // 2]
            self._take(t, row, out)
        else:
            self.dropped += 1
        for u, r in rest:
            self.offer_into(u, r, out)


def _in_order(times: Sequence[float]) -> int:
    """The length of the longest subsequence of ``times`` in time order (non-decreasing)."""
    tails: list[float] = []
    for u in times:
        i = bisect.bisect_right(tails, u)
        if i == len(tails):
            tails.append(u)
        else:
            tails[i] = u
    return len(tails)


class TelemetryRows:
    """A run's telemetry rows from its lines, sans-IO: the one policy of every reader of a run's telemetry
    (:func:`read_telemetry`, ``hil gcs``'s :class:`~hil.gcs.rundir.RunDirSource`). :meth:`lines` takes the
    complete lines that follow the header (bytes or text; None: a line too long to keep) and returns the
    rows taken, ``width`` numbers each (an empty cell ``empty``); a line with another number of cells, a
    non-number or bytes that are not UTF-8 is dropped, and so is a row out of time order
    (:class:`RowOrder`: held rows come out late, by :meth:`end` at the latest). :meth:`end` is told whether
    the file ended in an unfinished line: a run writes whole lines
    (:class:`~hil.files.appending.LineAppender`), so that is a line torn by a kill — dropped, whatever it
    holds (``0.21234`` cut to ``0.2`` still parses). :attr:`dropped` counts every line dropped."""

    def __init__(self, width: int, empty: float | None = math.nan) -> None:
        self.width = width
        self.empty = empty
        self.order: RowOrder[list[Any]] = RowOrder()
        self.damaged = 0

    @property
    def dropped(self) -> int:
        return self.damaged + self.order.dropped

    @property
    def taken(self) -> int:
        return self.order.taken

    def lines(self, lines: Iterable[bytes | str | None]) -> list[list[Any]]:
        out: list[list[Any]] = []
        offer = self.order.offer_into
        for line in lines:
            row = _numbers(line, self.width, self.empty)
            if row is None:
                self.damaged += 1
            else:
                offer(row[0], row, out)
        return out

    def end(self, torn: bool) -> list[list[Any]]:
        """The rows still held; ``torn``: the file ended in an unfinished line (dropped, counted)."""
        self.damaged += torn
        return self.order.end()


RUN_FILES_ONLY = ": a run directory holds files (a device, a FIFO there is never read: /dev/zero never ends)"
"""Said of a run's telemetry or events that is there and is not a regular file."""


Columns = Iterable[str] | Callable[[Sequence[str]], Iterable[str]] | None
"""The columns a reader keeps: their names (names the header lacks are left out), or a function of the
header's names that says them; None: all."""


class TelemetryBlocks:
    """A run's telemetry CSV read a block of rows at a time, streamed: iterating gives float arrays, one per
    piece of :data:`~hil.files.bounded.CHUNK_BYTES` read (its rows taken × :attr:`names`, NaN where empty),
    so memory holds one block, not the file (:func:`read_telemetry` keeps them; a reader that needs less —
    the plots' envelopes — keeps less). ``columns`` says which are kept (:data:`Columns`); ``()`` keeps none
    and only counts the rows.

    Every line is read the same whichever columns are kept (:class:`TelemetryRows`): a line with the wrong
    number of cells, a non-number, bytes that are not UTF-8 or more than
    :data:`~hil.files.bounded.MAX_LINE_BYTES` is dropped and counted, and so is a last line without its
    line break (torn by a kill) and a row out of time order (:class:`RowOrder`): :attr:`rows` and
    :attr:`dropped_lines` once iterated. A missing or header-less file is an InputFormatError, raised when
    it is opened (the header is read then: :attr:`header`)."""

    def __init__(self, path: str | os.PathLike[str], columns: Columns = None) -> None:
        self.path = Path(path)
        regular_file_if_there(self.path, InputFormatError, "telemetry", RUN_FILES_ONLY)
        try:
            self._file = open(self.path, "rb")  # noqa: SIM115 — closed by close()
        except FileNotFoundError:
            raise InputFormatError("no such file (telemetry)", str(self.path)) from None
        except OSError as exc:
            raise InputFormatError(f"cannot read telemetry: {exc.strerror}", str(self.path)) from exc
        self._splitter = LineSplitter()
        try:
            first = self._first_lines()
            self.header = _header(first.pop(0), self.path)
        except BaseException:
            self._file.close()
            raise
        self._first: list[bytes | None] = first
        self._reader = TelemetryRows(len(self.header))
        kept = _kept(self.header, columns)
        self.names = [name for name, _ in kept]
        self._picks = [i for _, i in kept]

    def _first_lines(self) -> list[bytes | None]:
        """The lines of the first piece(s) read that holds a whole line (the header); a header alone,
        without its line break, is still the header."""
        while data := self._file.read(CHUNK_BYTES):
            lines = self._splitter.feed(data)
            if lines:
                return lines
        last = self._splitter.end()
        if not last:
            raise InputFormatError("empty file (no header)", str(self.path), 1)
        return last

    @property
    def rows(self) -> int:
        """Rows taken so far."""
        return self._reader.taken

    @property
    def dropped_lines(self) -> int:
        """Lines dropped so far (damaged, torn, out of time order)."""
        return self._reader.dropped

    def __iter__(self) -> Iterator[np.ndarray]:
        try:
            lines, self._first = self._first, []
            while True:
                block = self._block(self._reader.lines(lines))
                if block is not None:
                    yield block
                if self._file.closed:
                    return
                data = self._file.read(CHUNK_BYTES)
                if data:
                    lines = self._splitter.feed(data)
                    continue
                torn = bool(self._splitter.end())  # a line without its line break: torn by a kill
                self._file.close()
                block = self._block(self._reader.end(torn))
                if block is not None:
                    yield block
                return
        finally:
            self._file.close()

    def _block(self, rows: list[list[Any]]) -> np.ndarray | None:
        if not rows:
            return None
        if not self._picks:
            return np.zeros((len(rows), 0))
        data = np.array(rows, dtype=float)
        return data if len(self._picks) == data.shape[1] else data[:, self._picks]

    def close(self) -> None:
        """Stop reading (idempotent)."""
        self._file.close()

    def __enter__(self) -> TelemetryBlocks:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_telemetry(path: str | os.PathLike[str], columns: Columns = None) -> Telemetry:
    """Read a run's telemetry CSV (:class:`TelemetryBlocks`: the lines it drops, and why), its columns
    ``columns`` (:data:`Columns`; default: all) kept whole: memory holds the numbers kept, not the text —
    each column of a 10-hour run at 200 Hz is 58 MB; ``()`` keeps none, only counts the rows."""
    with TelemetryBlocks(path, columns) as blocks:
        parts: list[list[np.ndarray]] = [[] for _ in blocks.names]
        for block in blocks:
            for j, part in enumerate(parts):
                part.append(block[:, j].copy())  # not a view: the block's other columns freed
    out: dict[str, np.ndarray] = {}
    for name, part in zip(blocks.names, parts, strict=True):
        out[name] = np.concatenate(part) if part else np.zeros(0)
        part.clear()  # one column at a time: never the blocks and all the columns at once
    return Telemetry(out, blocks.rows, blocks.dropped_lines)


def _kept(header: list[str], columns: Columns) -> list[tuple[str, int]]:
    """(name, index) of the columns a reader keeps (:data:`Columns`)."""
    index = {name: i for i, name in enumerate(header)}
    if columns is None:
        return list(index.items())
    names = columns(header) if callable(columns) else columns
    return [(name, index[name]) for name in dict.fromkeys(names) if name in index]


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
    reader of a run's rows takes column 0 for the time. A column named twice is one too (a run names each
    once; which of them would a reader by name mean?)."""
    columns = line.rstrip("\r").split(",")
    if columns[0] != "t":
        raise InputFormatError(
            f"no 't' column first (found {columns[0][:40]!r}): not a run's telemetry", str(path), 1
        )
    if len(set(columns)) < len(columns):  # a reader by name took the last of them, silently
        twice = next(c for c, n in collections.Counter(columns).items() if n > 1)
        raise InputFormatError(f"column {twice[:40]!r} named twice: not a run's telemetry", str(path), 1)
    return columns


def _numbers(line: bytes | str | None, width: int, empty: float | None = math.nan) -> list[Any] | None:
    """A telemetry row's ``width`` numbers (an empty cell is ``empty``), or None for a damaged line."""
    if line is None:
        return None
    try:
        text = line if isinstance(line, str) else line.decode("utf-8")
        cells = text.split(",")  # the log's writer never quotes: numbers and empty cells
        if len(cells) != width:
            return None
        return [float(c) if c != "" else empty for c in cells]
    except (UnicodeDecodeError, ValueError):
        return None


def iter_events(path: str | os.PathLike[str]) -> Iterator[dict[str, Any]]:
    """The readable events of a run's events log, one at a time (a reader that keeps less than every
    event — the plots' markers — holds none of the rest); unreadable lines skipped, as :func:`read_events`
    drops them. Nothing if there is no file."""
    for event in _events(Path(path)):
        if event is not None:
            yield event


def read_summary(run_dir: str | os.PathLike[str]) -> dict[str, Any] | None:
    """A run's ``summary.json`` (a JSON object), read through the bounded readers as every reader of it
    does (a BOM skipped; at most :data:`~hil.files.bounded.MAX_DOCUMENT_BYTES`, nested at most
    :data:`~hil.files.bounded.MAX_NESTING` deep); None if there is none; anything else an
    :class:`InputFormatError` naming it."""
    path = Path(run_dir) / SUMMARY
    regular_file_if_there(path, InputFormatError, "summary", RUN_FILES_ONLY)
    if not path.exists():
        return None
    doc = load_json(read_document(path, InputFormatError, SUMMARY), str(path))
    if not isinstance(doc, dict):
        raise InputFormatError("expected a JSON object", str(path))
    return doc


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
