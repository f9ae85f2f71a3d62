"""A run directory as the page's source (``hil gcs RUN_DIR``): finished, killed, or still being written by
another process — the reader follows it.

Each poll reads what was appended to ``telemetry.csv`` and ``events.jsonl`` since the last one, complete
lines only (a line still being written, or torn by a kill, waits; a malformed complete line is dropped and
counted — :mod:`hil.runtime.runlog` flushes whole lines). The telemetry's rows are taken as
:func:`hil.runtime.runlog.read_telemetry` takes them (:class:`~hil.runtime.runlog.TelemetryRows`: the
same lines dropped and counted, the same rows out of time order); a row far ahead of the last is held
with the rows after it until they tell whether it is a stray (:class:`~hil.runtime.runlog.RowOrder`),
and what is held when the reading stops is judged then. ``summary.json`` appearing (written atomically
when a run ends) means the run is finished: its final link statistics are sent, and the reader stops
following once it has read the rest. A directory that stops growing without a summary is a stalled run
or a killed one, told apart by the run's lock on its directory (:mod:`hil.files.writing`, held by a run
from its making to its summary): a writer that holds it is stalled (the page shows how long nothing has
come); once it is free — the lock seen held and let go, or, for a directory whose writer takes none
(another program, an older run), nothing new for :data:`QUIET_S` — the run has stopped being written:
the rows held back (:class:`~hil.runtime.runlog.RowOrder`) are judged on what came and given out, a
line left unfinished is counted as torn, and the status says ``stopped`` with why. Reading goes on: a
directory that grows again (a writer without a lock, back) is ``following`` again.

The files are read by name, so the reader checks each poll that they are still the ones it has read: the
directory and ``telemetry.csv`` the same (device and inode), and the bytes last read (the unfinished line
and :data:`SEEN_BYTES` before it) still there — but for the unfinished line itself, which a run's writer
cuts back when the OS refuses part of a write (:class:`~hil.files.appending.LineAppender`). Otherwise (the
directory removed or replaced by a new run of the same name, the telemetry truncated or rewritten) the
run shown is no longer on disk: the reader stops, the
status saying so (``read``, never ``finished``: another run's summary would say how a run ended that the
page does not show), rather than draw the new run's rows on the old run's plots. An ``events.jsonl``
replaced or truncated while the telemetry goes on (rotated) is read again from its start. A line torn
when the reading stops (a run killed mid-write, then finished or read) is counted as damaged. A path that
is not a regular file (a FIFO, whose open waits for a writer; a device) is an error, never opened: on the
first read the directory is refused (``hil gcs`` exits naming the file); later it never ends the station —
an ``events.jsonl`` refused is said in the status's ``error`` while the telemetry is followed on, a
``telemetry.csv`` refused stops the reading with what was read still served. A
``scenario.toml`` whose units are not as many as the telemetry's is not this run's: not drawn, the note
says so.
"""

from __future__ import annotations

import logging
import os
import stat
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

from hil.files.bounded import MAX_LINE_BYTES, LineSplitter, load_json, read_document, regular_file_if_there
from hil.files.writing import writer_holds
from hil.gcs import info as run_info
from hil.gcs.wire import Batch
from hil.runtime.runlog import EVENTS, RUN_FILES_ONLY, SUMMARY, TELEMETRY, TelemetryRows, telemetry_header
from hil.scenario import load_scenario
from protocol.errors import HilError, InputFormatError

logger = logging.getLogger(__name__)

READ_CHUNK = 4 * 1024 * 1024  # bytes read per file per poll (a big file comes in over several polls)
SEEN_BYTES = 64  # bytes read before the unfinished line, compared on the next read (a file rewritten)
SEEN_MAX = 64 * 1024  # bytes compared at most (the unfinished line's, then SEEN_BYTES before it)
STOPPED = "stopped"
"""The state once the directory's writer is gone without a summary: the reader's verdict that nothing more
comes, no progress of the run (:meth:`hil.gcs.station.GroundStation._progress`)."""
QUIET_S = 5.0
"""s without growth after which a directory whose writer holds no lock (:mod:`hil.files.writing`) — never
seen held — has stopped being written. A run flushes its telemetry every 50 ms while it ticks; a run
that holds its lock is never taken as stopped, however long it is silent."""


class _Tail:
    """Complete lines appended to one file since the last read (:class:`~hil.files.bounded.LineSplitter`):
    an unfinished line waits for its end, but only up to :data:`~hil.files.bounded.MAX_LINE_BYTES` — a
    longer one (a file that never breaks its line) is dropped as it arrives, and counted, never held.

    :attr:`changed` says why the file at the path is no longer the one read (removed, another file,
    shorter than what was read, other bytes where the last ones read were — the unfinished line cut back
    by its writer excepted); nothing more is read from it until :meth:`restart`."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.restart()

    @property
    def pending(self) -> bool:
        """Whether an unfinished line is held (a torn line when no more will come)."""
        return self._splitter.pending > 0

    def restart(self) -> None:
        """Read the file at the path from its start, as a new one."""
        self.offset = 0
        self._splitter = LineSplitter()
        self._identity: tuple[int, int] | None = None  # (device, inode) of the file read
        self._seen = b""  # the last bytes read: still there on the next read, or the file was rewritten
        self.changed: str | None = None

    def lines(self) -> tuple[list[str], int]:
        """The new complete lines, and how many lines too long to keep ended or began among them."""
        if self.changed is not None:
            return [], 0
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO's open would wait for a writer
        except FileNotFoundError:
            if self._identity is not None:
                self.changed = "removed"
            return [], 0
        except OSError as exc:
            raise InputFormatError(f"cannot read: {exc.strerror}", str(self.path)) from exc
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                raise InputFormatError("not a regular file: a run writes regular files only", str(self.path))
            if self._identity is None:
                self._identity = (st.st_dev, st.st_ino)
            elif (st.st_dev, st.st_ino) != self._identity:
                self.changed = "replaced"
                return [], 0
            data = self._read(f)
            if data is None and self._cut_back(f):
                data = self._read(f)
        if data is None:
            self.changed = "truncated" if st.st_size < self.offset else "rewritten"
            return [], 0
        self.offset += len(data)
        lines = self._splitter.feed(data)
        window = min(SEEN_BYTES + self._splitter.pending, SEEN_MAX)  # the unfinished line and a bit before
        self._seen = (self._seen + data)[-window:]
        kept = [line.decode("utf-8", errors="replace") for line in lines if line is not None]
        return kept, len(lines) - len(kept)

    def _read(self, f: BinaryIO) -> bytes | None:
        """Up to :data:`READ_CHUNK` bytes from the offset, or None when the bytes before it are not the
        last ones read (the file was truncated or rewritten)."""
        back = len(self._seen)
        f.seek(self.offset - back)
        data = f.read(READ_CHUNK + back)
        return data[back:] if data[:back] == self._seen else None

    def _cut_back(self, f: BinaryIO) -> bool:
        """Whether the file differs from what was read only in the unfinished line held: its writer cut
        its torn last line back to the end of the last whole one — a run's
        :class:`~hil.files.appending.LineAppender` does when the OS refuses part of a write (a full disk)
        — and may have written on from there. Then the unfinished line is forgotten and the reading goes
        on from its start (the offset and the bytes seen moved back to it)."""
        cut = self._splitter.pending
        keep = max(len(self._seen) - cut, 0)
        f.seek(self.offset - cut - keep)
        if not cut or f.read(keep) != self._seen[:keep]:
            return False
        self.offset -= cut
        self._splitter = LineSplitter()
        self._seen = self._seen[:keep]
        return True


class RunDirSource:
    """The page's source for a run directory (see the module docstring); ``follow=False`` reads what is
    there and stops. A file refused after the first poll (made a FIFO, unreadable) never ends the station:
    a refused ``events.jsonl`` is said in the status's ``error`` while the telemetry is followed on (unless
    ``events_refused_stops``), a refused ``telemetry.csv`` stops the reading (:meth:`fail`)."""

    def __init__(
        self,
        run_dir: str | os.PathLike[str],
        follow: bool = True,
        clock: Callable[[], float] = time.monotonic,
        events_refused_stops: bool = False,
    ) -> None:
        self.run_dir = Path(run_dir)
        # A refused events.jsonl stops the reading as a refused telemetry does: for an overlay of
        # hil.gcs.compare, whose events are not shown (its contract: any file refused, the overlay in error).
        self.events_refused_stops = events_refused_stops
        self.clock = clock
        if not self.run_dir.is_dir():
            raise InputFormatError("not a directory", str(self.run_dir))
        if not (self.run_dir / TELEMETRY).exists() and not (self.run_dir / EVENTS).exists():
            raise InputFormatError(f"not a run directory (no {TELEMETRY} or {EVENTS})", str(self.run_dir))
        self.follow = follow
        self._identity = _identity(self.run_dir)
        self._telemetry = _Tail(self.run_dir / TELEMETRY)
        self._events = _Tail(self.run_dir / EVENTS)
        self.columns: list[str] | None = None
        self.rows = 0
        self.events = 0
        self._too_long = 0  # telemetry lines too long to keep (the others: the reader's, :attr:`bad_rows`)
        self._reader: TelemetryRows | None = None  # once the header is read
        self.bad_events = 0  # damaged event lines: too long, not a JSON object, nested too deep
        self.finished = False
        self._done = False  # finished and everything read
        self._last_t: float | None = None
        self._state: dict[str, Any] = {"state": "waiting"}
        self._sent_status: dict[str, Any] | None = None
        self._lock_seen = False  # the run's writer was seen holding its directory's lock
        self._grown_at = clock()  # when (clock) the telemetry or the events last grew
        self._sizes = (-1, -1)
        self.stopped = False  # the writer is gone: nothing more will be written (while no growth)
        self._polls = 0  # polls made: a refused read on the first one refuses the directory (hil gcs: exit 2)
        self.events_refused: str | None = None  # why events.jsonl cannot be read now (a FIFO, unreadable)

    @property
    def status(self) -> dict[str, Any]:
        """The status last sent (``{"state": "waiting"}`` before the first)."""
        return dict(self._sent_status or self._state)

    def _info(self, columns: list[str]) -> dict[str, Any]:
        scenario, note = None, ""
        path = self.run_dir / "scenario.toml"
        if path.exists():
            try:
                regular_file_if_there(
                    path, InputFormatError, "scenario", RUN_FILES_ONLY
                )  # a FIFO's open waits
                scenario = load_scenario(path)
            except HilError as exc:
                note = f"scenario.toml unreadable ({exc}): no units or limits drawn"
        else:
            note = "no scenario.toml: no units or limits drawn"
        logged = run_info.units_from_columns(columns)
        if scenario is not None and logged and logged != scenario.spacecraft.n_units:
            # a scenario.toml copied or edited since the run: the telemetry is what the run logged
            note = (
                f"scenario.toml has {scenario.spacecraft.n_units} units, the telemetry {logged}: "
                "not this run's scenario, no units or limits drawn"
            )
            scenario = None
        hold = False
        summary = self._summary()
        if summary is not None and summary.get("replay"):
            hold = True  # a recording drove the board: the target was the attitude held after warm-up
        return run_info.info(
            mode="replay",
            run=self.run_dir.name,
            columns=columns,
            uplink=False,
            scenario=scenario,
            hold=hold,
            note=note,
        )

    def _summary(self) -> dict[str, Any] | None:
        """The run's summary.json, or None before it is written; a damaged one (not a JSON object, larger
        than :data:`~hil.files.bounded.MAX_DOCUMENT_BYTES`, nested deeper than
        :data:`~hil.files.bounded.MAX_NESTING`) is logged and stands as ``{"exit": "unreadable summary:
        ..."}``."""
        path = self.run_dir / SUMMARY
        if not path.exists():
            return None
        try:
            regular_file_if_there(path, InputFormatError, "summary", RUN_FILES_ONLY)  # a FIFO's open waits
            value = load_json(read_document(path, InputFormatError, "summary"), str(path))
        except InputFormatError as exc:  # written atomically: a bad one is a damaged file
            logger.warning("%s", exc)
            return {"exit": f"unreadable summary: {exc.detail}"}
        return value if isinstance(value, dict) else {"exit": "unreadable summary: not a JSON object"}

    def poll(self) -> Batch:
        """What the run directory has that was not given out yet. A read refused on the first poll (the
        telemetry a FIFO or unreadable) raises :class:`~protocol.errors.HilError` naming the file: ``hil
        gcs`` refuses the directory before it serves. Refused later (a file replaced under the page), the
        reading stops as :meth:`fail` says — what was read stays served, the status says why — rather
        than end the station (its pump raised it, and ``hil gcs`` exited with a traceback)."""
        self._polls += 1
        try:
            return self._poll()
        except HilError as exc:
            if self._polls == 1:
                raise
            return self.fail(exc)

    def _poll(self) -> Batch:
        batch = Batch()
        if self._done:
            return batch
        finished = (self.run_dir / SUMMARY).exists()  # before reading: what follows is all there is
        lines, too_long = self._telemetry.lines()
        self._too_long += too_long
        gone = self._gone()
        if gone is not None:  # what was read is no longer there: stop, never mix in another run's rows
            return self._stop(batch, gone)
        if self.columns is None and (lines or too_long or finished):
            try:
                self.columns = self._header(lines, too_long)
            except InputFormatError as exc:  # not a run's telemetry: said on the page, nothing drawn
                logger.warning("%s", exc)
                self._done = True
                batch.status = self._sent_status = {"state": "error", "error": str(exc)}
                return batch
            lines = lines[1:]
            self._reader = TelemetryRows(len(self.columns), empty=None)
            batch.info = self._info(self.columns)
            self._state = {"state": "following" if self.follow else "reading"}
        if self.columns is not None:
            self._rows(lines, batch)
        self._read_events(batch)
        # what is left to read, of either file: a finished run's events past the first READ_CHUNK were
        # never read when this looked at the telemetry alone (the reading stopped at its end)
        more = any(tail.offset < _size(tail.path) for tail in (self._telemetry, self._events))
        if self.columns is not None and not more:
            if finished:
                summary = self._summary() or {}
                self.finished = self._done = True
                self._count_torn(batch)
                link = summary.get("link")
                if isinstance(link, dict) and link:
                    batch.link.append({"t": self._last_t, **_flatten(link)})
                self._state = {"state": "finished", "exit": summary.get("exit"), "summary": summary}
            elif not self.follow:
                self._done = True
                self._count_torn(batch)
                self._state = {"state": "read", "exit": None}
            else:
                self._writer(batch)
        bad_rows, bad_events = self.bad_rows, self.bad_events
        if self.stopped and not self._done:  # lines left unfinished will never be: torn (counted at the end)
            bad_rows += self._telemetry.pending
            bad_events += self._events.pending
        status = {**self._state, "bad_rows": bad_rows, "bad_events": bad_events}
        if self.events_refused is not None and "error" not in status:
            status["error"] = self.events_refused  # shown on the page; the telemetry is still read
        if status != self._sent_status:
            batch.status = self._sent_status = status
        return batch

    def _writer(self, batch: Batch) -> None:
        """Everything written has been read and there is no summary: whether the run's writer is still
        there (see the module docstring). Once it is gone the rows held are given out and the status says
        ``stopped``; a directory that grows again is ``following`` again."""
        now = self.clock()
        sizes = (self._telemetry.offset, self._events.offset)
        if sizes != self._sizes:
            self._sizes, self._grown_at = sizes, now
            if self.stopped:
                self.stopped = False
                self._state = {"state": "following"}
            return
        if self.stopped:
            return
        holds = writer_holds(self.run_dir)
        if holds:
            self._lock_seen = True
            return
        if not (self._lock_seen and holds is False) and now - self._grown_at < QUIET_S:
            return
        if (self.run_dir / SUMMARY).exists():  # written just before the lock was let go: finished next poll
            return
        self.stopped = True
        if self._reader is not None:
            self._add(self._reader.order.end(), batch)  # judged on what came; the reader goes on after
        why = (
            "its writer is gone (the run's lock let go) without a summary: killed or crashed"
            if self._lock_seen
            else f"nothing written for {QUIET_S:g} s, no summary, and no writer holds the run's lock"
        )
        self._state = {"state": STOPPED, "exit": None, "stopped": f"the run stopped being written: {why}"}

    def _gone(self) -> str | None:
        """Why the run read so far is no longer on disk (the directory removed or replaced, its telemetry
        removed, replaced, truncated or rewritten), or None while it is."""
        if _identity(self.run_dir) != self._identity:
            return "the run directory was removed or replaced"
        if self._telemetry.changed is not None:
            return f"{TELEMETRY} was {self._telemetry.changed}"
        return None

    def _stop(self, batch: Batch, why: str) -> Batch:
        """Stop reading (:meth:`_gone` said ``why``): the status says so, the page shows what was read."""
        logger.warning("%s: %s: stopped following", self.run_dir, why)
        self._done = True
        if self._reader is not None:  # the rows held were read from the run shown: judged on what came
            self._add(self._reader.end(torn=False), batch)
        self._state = {
            "state": "read",
            "exit": None,
            "error": f"{why} after {self.rows} rows: the page shows the run as it was read "
            "(open the directory again for what is there now)",
        }
        batch.status = self._sent_status = {
            **self._state,
            "bad_rows": self.bad_rows,
            "bad_events": self.bad_events,
        }
        return batch

    def fail(self, exc: HilError) -> Batch:
        """Stop reading after a read refused with ``exc`` (a file of the run that became a FIFO, or
        unreadable): the rows held are given out (read from the run shown) and the status says ``error``
        with why. For a source that is not the page's only one (an overlay of :mod:`hil.gcs.compare`),
        whose error must not stop the station's pump; the page's own run raises it to the pump instead."""
        logger.warning("%s: %s: stopped reading", self.run_dir, exc)
        batch = Batch()
        self._done = True
        if self._reader is not None:
            self._add(self._reader.end(torn=False), batch)
        self._state = {"state": "error", "exit": None, "error": str(exc)}
        batch.status = self._sent_status = {
            **self._state,
            "bad_rows": self.bad_rows,
            "bad_events": self.bad_events,
        }
        return batch

    def _count_torn(self, batch: Batch) -> None:
        """No more will be read: the rows held given out, a line still unfinished (torn by a kill) a
        damaged one, counted."""
        self._end_rows(batch)
        self.bad_events += self._events.pending

    def _header(self, lines: list[str], too_long: int) -> list[str]:
        """The telemetry's columns from its first line kept (none yet: a run that has written no row): a
        run's, its time first (:func:`hil.runtime.runlog.telemetry_header`), else InputFormatError — so a
        first data row is never taken for the header of a file whose own was too long to keep."""
        if lines:
            return telemetry_header(lines[0], self._telemetry.path)
        if too_long:
            raise InputFormatError(
                f"a header longer than {MAX_LINE_BYTES} bytes: not telemetry", str(self._telemetry.path), 1
            )
        return []

    def _rows(self, lines: list[str], batch: Batch) -> None:
        """The rows taken of ``lines`` (:class:`~hil.runtime.runlog.TelemetryRows`: the policy of
        :func:`~hil.runtime.runlog.read_telemetry` too) into ``batch``."""
        assert self._reader is not None
        self._add(self._reader.lines(lines), batch)

    def _add(self, rows: list[list[Any]], batch: Batch) -> None:
        if rows:
            batch.rows.extend(rows)
            self._last_t = rows[-1][0]
            self.rows += len(rows)

    @property
    def bad_rows(self) -> int:
        """Damaged telemetry lines: too long, wrong cell count, not numbers, torn, out of time order."""
        return self._too_long + (self._reader.dropped if self._reader is not None else 0)

    def _end_rows(self, batch: Batch) -> None:
        """No more will be read: the rows held (:class:`~hil.runtime.runlog.RowOrder`) judged on what came
        after them, and a line still unfinished (torn by a kill) counted as damaged."""
        if self._reader is not None:
            self._add(self._reader.end(torn=self._telemetry.pending), batch)
        else:
            self._too_long += self._telemetry.pending

    def _read_events(self, batch: Batch) -> None:
        where = str(self._events.path)
        try:
            lines, too_long = self._events_lines()
        except HilError as exc:
            if self.events_refused_stops:
                raise
            self._refuse_events(exc)
            return
        if self.events_refused is not None:
            logger.warning("%s: readable again: read from its start", where)
            self.events_refused = None
        self.bad_events += too_long
        for line in lines:
            try:
                record = load_json(line, where)
            except InputFormatError:
                self.bad_events += 1
                continue
            if isinstance(record, dict):
                batch.events.append(record)
            else:
                self.bad_events += 1
        self.events += len(batch.events)

    def _events_lines(self) -> tuple[list[str], int]:
        """The events' new complete lines, and how many too long to keep; a log rotated (replaced or
        truncated while the telemetry goes on) is read again from its start."""
        lines, too_long = self._events.lines()
        if self._events.changed is not None:  # rotated (the telemetry goes on): the new file from its start
            self.bad_events += self._events.pending  # the old file's torn last line
            self._events.restart()
            more, more_long = self._events.lines()
            lines, too_long = lines + more, too_long + more_long
        return lines, too_long

    def _refuse_events(self, exc: HilError) -> None:
        """events.jsonl cannot be read (made a FIFO, a device, unreadable): the events file alone is in
        error — the status says so (``error``, on the page), logged once — and the telemetry goes on being
        served. It is tried again each poll from its start, as a rotated log: a regular file back at the
        path is read whole, the error cleared."""
        why = f"{exc}: its events are not read (the telemetry still is)"
        if why != self.events_refused:
            logger.warning("%s", why)
        self.events_refused = why
        self.bad_events += self._events.pending  # a line left unfinished in the file that was there
        self._events.restart()


def _identity(path: Path) -> tuple[int, int] | None:
    """(device, inode) of ``path``, None when it is not there."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_dev, st.st_ino


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _flatten(value: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"rtt": {"p99_ms": 1}}`` → ``{"rtt.p99_ms": 1}``, as :meth:`LinkStats.as_dict` names them."""
    out: dict[str, Any] = {}
    for key, v in value.items():
        name = f"{prefix}{key}"
        if isinstance(v, dict):
            out.update(_flatten(v, f"{name}."))
        else:
            out[name] = v
    return out
