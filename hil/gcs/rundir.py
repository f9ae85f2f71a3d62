"""A run directory as the page's source (``hil gcs RUN_DIR``): finished, killed, or still being written by
another process — the reader follows it.

Each poll reads what was appended to ``telemetry.csv`` and ``events.jsonl`` since the last one, complete
lines only (a line still being written, or torn by a kill, waits; a malformed complete line is dropped and
counted — :mod:`hil.runtime.runlog` flushes whole lines). ``summary.json`` appearing (written atomically
when a run ends) means the run is finished: its final link statistics are sent, and the reader stops
following once it has read the rest. A directory that stops growing without a summary is a killed run
(or a stalled one): the page shows how long nothing has come.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

from hil.files.bounded import MAX_LINE_BYTES, LineSplitter, load_json, read_document
from hil.gcs import info as run_info
from hil.gcs.wire import Batch
from hil.runtime.runlog import EVENTS, SUMMARY, TELEMETRY, RowClock, telemetry_header
from hil.scenario import load_scenario
from protocol.errors import HilError, InputFormatError

logger = logging.getLogger(__name__)

READ_CHUNK = 4 * 1024 * 1024  # bytes read per file per poll (a big file comes in over several polls)


class _Tail:
    """Complete lines appended to one file since the last read (:class:`~hil.files.bounded.LineSplitter`):
    an unfinished line waits for its end, but only up to :data:`~hil.files.bounded.MAX_LINE_BYTES` — a
    longer one (a file that never breaks its line) is dropped as it arrives, and counted, never held."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.offset = 0
        self._splitter = LineSplitter()

    def lines(self) -> tuple[list[str], int]:
        """The new complete lines, and how many lines too long to keep ended or began among them."""
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                data = f.read(READ_CHUNK)
        except FileNotFoundError:
            return [], 0
        except OSError as exc:
            raise InputFormatError(f"cannot read: {exc.strerror}", str(self.path)) from exc
        self.offset += len(data)
        lines = self._splitter.feed(data)
        kept = [line.decode("utf-8", errors="replace") for line in lines if line is not None]
        return kept, len(lines) - len(kept)


class RunDirSource:
    """The page's source for a run directory (see the module docstring); ``follow=False`` reads what is
    there and stops."""

    def __init__(self, run_dir: str | os.PathLike[str], follow: bool = True) -> None:
        self.run_dir = Path(run_dir)
        if not self.run_dir.is_dir():
            raise InputFormatError("not a directory", str(self.run_dir))
        if not (self.run_dir / TELEMETRY).exists() and not (self.run_dir / EVENTS).exists():
            raise InputFormatError(f"not a run directory (no {TELEMETRY} or {EVENTS})", str(self.run_dir))
        self.follow = follow
        self._telemetry = _Tail(self.run_dir / TELEMETRY)
        self._events = _Tail(self.run_dir / EVENTS)
        self.columns: list[str] | None = None
        self.rows = 0
        self.events = 0
        self.bad_rows = 0  # damaged telemetry lines: too long, wrong cell count, not numbers, out of order
        self._clock = RowClock()
        self.bad_events = 0  # damaged event lines: too long, not a JSON object, nested too deep
        self.finished = False
        self._done = False  # finished and everything read
        self._last_t: float | None = None
        self._state: dict[str, Any] = {"state": "waiting"}
        self._sent_status: dict[str, Any] | None = None

    def _info(self, columns: list[str]) -> dict[str, Any]:
        scenario, note = None, ""
        path = self.run_dir / "scenario.toml"
        if path.exists():
            try:
                scenario = load_scenario(path)
            except HilError as exc:
                note = f"scenario.toml unreadable ({exc}): no units or limits drawn"
        else:
            note = "no scenario.toml: no units or limits drawn"
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
            value = load_json(read_document(path, InputFormatError, "summary"), str(path))
        except InputFormatError as exc:  # written atomically: a bad one is a damaged file
            logger.warning("%s", exc)
            return {"exit": f"unreadable summary: {exc.detail}"}
        return value if isinstance(value, dict) else {"exit": "unreadable summary: not a JSON object"}

    def poll(self) -> Batch:
        batch = Batch()
        if self._done:
            return batch
        finished = (self.run_dir / SUMMARY).exists()  # before reading: what follows is all there is
        lines, too_long = self._telemetry.lines()
        self.bad_rows += too_long
        if self.columns is None and (lines or too_long or finished):
            try:
                self.columns = self._header(lines, too_long)
            except InputFormatError as exc:  # not a run's telemetry: said on the page, nothing drawn
                logger.warning("%s", exc)
                self._done = True
                batch.status = self._sent_status = {"state": "error", "error": str(exc)}
                return batch
            lines = lines[1:]
            batch.info = self._info(self.columns)
            self._state = {"state": "following" if self.follow else "reading"}
        if self.columns is not None:
            self._rows(lines, batch)
        self._read_events(batch)
        more = self._telemetry.offset < _size(self._telemetry.path)
        if self.columns is not None and not more:
            if finished:
                summary = self._summary() or {}
                self.finished = self._done = True
                link = summary.get("link")
                if isinstance(link, dict) and link:
                    batch.link.append({"t": self._last_t, **_flatten(link)})
                self._state = {"state": "finished", "exit": summary.get("exit"), "summary": summary}
            elif not self.follow:
                self._done = True
                self._state = {"state": "read", "exit": None}
        status = {**self._state, "bad_rows": self.bad_rows, "bad_events": self.bad_events}
        if status != self._sent_status:
            batch.status = self._sent_status = status
        return batch

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
        assert self.columns is not None
        width = len(self.columns)
        for line in lines:
            cells = line.split(",")  # the log's writer never quotes: numbers and empty cells
            if len(cells) != width:
                self.bad_rows += 1
                continue
            try:
                row = [float(c) if c else None for c in cells]
            except ValueError:
                self.bad_rows += 1
                continue
            if not self._clock.take(row[0]):  # out of time order: not drawn, counted
                self.bad_rows += 1
                continue
            batch.rows.append(row)
            self._last_t = row[0]
        self.rows += len(batch.rows)

    def _read_events(self, batch: Batch) -> None:
        where = str(self._events.path)
        lines, too_long = self._events.lines()
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
