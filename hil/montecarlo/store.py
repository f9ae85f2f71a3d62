"""A campaign's output directory, written run by run so that a crash or Ctrl-C loses no finished run and a
re-run with the same directory carries on where it stopped.

Layout of ``OUT``::

    campaign.json   what the campaign is (scenario and dispersion texts, seed, duration, trace rate,
                    columns, the code that runs it): written first; a re-run must match it (more runs
                    may be asked for). Its ``session`` (:data:`SESSION`) says what the last session asked
                    and how it ended, rewritten as it starts and as it ends
    runs.csv        one row per finished run, ok or failed, flushed as it finishes: index, status, error,
                    the drawn parameters, the metrics. A row is the run's commit record.
    traces.bin      each ok run's decimated traces (:data:`~.metrics.TRACES`), fixed-size little-endian
                    records (index int32, then float32 samples), written just before its row
    summary.json    percentiles and pass rates (rewritten at the end of every session)
    plots/          histograms, error envelopes, parameter-vs-metric scatter

One session writes a directory at a time (:func:`_lock_dir`: a second is a ConfigError naming it). A SIGKILL
can leave a torn last line or record; opening the directory again cuts it off (and a trace
whose row never made it is ignored, then written again with the run; an empty runs.csv starts afresh). A
directory this campaign cannot resume — a manifest that is not a JSON object, results without a manifest, a
runs.csv under another header, a file that is not a regular file — is a ConfigError naming the file, as is
a write the OS refuses (a full disk); a row whose index or metric is not a number is dropped and counted.
"""

from __future__ import annotations

import csv
import fcntl
import hashlib
import io
import json
import logging
import math
import os
import re
import stat
import time
from array import array
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import IO, Any, BinaryIO, TypeVar

import numpy as np
from numpy.typing import NDArray

from hil import version
from hil.files.bounded import (
    MAX_DOCUMENT_BYTES,
    Unterminated,
    input_kind,
    load_json,
    read_lines,
    regular_file_if_there,
)
from hil.files.output import make_dir, refuse_others_outputs
from hil.scenario.paths import read_text
from protocol.errors import ConfigError, HilError, InputFormatError

from .dispersions import FAULT_COLUMNS, LINK_COLUMNS
from .metrics import METRICS, TRACES, trace_length
from .runner import CHECK_COLUMNS, VIOLATION_COLUMNS, RunResult

MANIFEST = "campaign.json"
MAX_DURATION_S = 86_400.0
"""A campaign run's longest duration (s): the scenario's bound."""
MAX_TRACE_HZ = 490.0
"""The highest trace rate (Hz): the highest control rate a scenario may have."""

logger = logging.getLogger(__name__)

TRACE_CHUNK_BYTES = 16 << 20
"""traces.bin is read this much at a time (whole records)."""
RUNS = "runs.csv"
TRACE_FILE = "traces.bin"
FIXED_COLUMNS = ("index", "status", "error")
TAIL_BLOCK_BYTES = 1 << 16
"""runs.csv's torn tail is looked for this much at a time, from the end."""
MAX_HEADER_BYTES = 1 << 20
"""The most of runs.csv's first line read to compare it with the manifest's columns."""
MAX_INDEX = 2**31 - 1
"""The largest run index a row may have (a trace record's index is an int32; a campaign's at most 10^7)."""
MAX_MESSAGE_CHARS = 2000
"""The most characters of a run's message cells (:data:`MESSAGE_COLUMNS`) written to runs.csv; the rest
is said cut. An error's message is whatever the code that raised it said (a user's estimator quoting an
array, a file): one of 2 MB made its row longer than runs.csv's longest readable line
(:data:`~hil.files.bounded.MAX_LINE_BYTES`), so the row was dropped as damaged when read back — the failed
run missing from the summary, the campaign exiting 0 as if every run was ok, and the run run again by
every later session."""
TEXT_COLUMNS = frozenset(
    {*FAULT_COLUMNS, *LINK_COLUMNS, *CHECK_COLUMNS}
    - {"faults.n", "link.outages", "link.outage_s"}
    - set(VIOLATION_COLUMNS)
)
"""The columns a run writes as text (an exit reason, a message, ``kind@time;...`` lists): read as text
whatever their cells (:func:`read_runs`). An ``exit`` column edited to numbers (``0``/``1``, by a script) was
taken for numbers, and the summary, which reads these columns' text, counted no run's exit at all."""
MESSAGE_COLUMNS = ("error", "inv.first")
"""The cells of free text (a run's error; a fault campaign's first violation, which may quote it)."""
_INDEX = re.compile(r"[0-9]{1,10}")
T = TypeVar("T")
_SAME = ("scenario_sha256", "dispersions_sha256", "seed", "duration_s", "trace_hz", "columns", "board")
"""What a re-run into a campaign's directory must match. ``board`` (the built-in emulator's board: the
Python emulator or the firmware under simavr, ``--board``; not in the scenario's text) was not among them:
a firmware extension of an emulator campaign pooled both in one summary. A manifest written before it was
recorded has none, and is taken as it was. So is the ``code`` that ran the campaign
(:func:`hil.version.describe`), compared as a campaign's workers are with its driver
(:func:`hil.version.mismatch`, :func:`_check_code`)."""
CODE = "code"
"""campaign.json's record of the code that ran the campaign: ``{"version": ..., "revision": ...}``."""
SESSION = "session"
"""campaign.json's record of its last session: ``{"runs_asked": N, "state": ...}``, ``state`` one of
:data:`SESSION_STATES` (``interrupted`` with the ``signal``'s name, ``stopped`` with the ``error`` that
ended it). Written ``running`` as a session starts and rewritten as it ends; one that still says
``running`` with no session holding the directory's lock was killed (SIGKILL, a machine's crash). Without
it a campaign interrupted before its first summary.json — the runs.csv of 27 runs of 30 — was reported by
``hil report`` as a whole campaign of 27, exit 0: nothing on disk said how many runs were asked. A
campaign.json written before it was recorded has none: the runs asked are unknown, and said so."""
SESSION_STATES = ("running", "finished", "interrupted", "stopped")
MAX_RUNS = 10_000_000
"""The most runs a campaign may ask for (10⁷: a year of a thousand cores at the shipped scenarios' pace),
and so the most a session's record may say were asked. Nothing is allocated per run before the runs start
— indices and chunks are made as they are submitted — so the bound is about what a campaign directory and
its summary can hold, not the driver's memory."""


def manifest(
    scenario_name: str,
    scenario_text: str,
    dispersions_text: str,
    seed: int,
    duration_s: float,
    trace_hz: float,
    samples: int,
    parameter_columns: Sequence[str],
    check_columns: Sequence[str] = (),
    board: str = "emulator",
    code: Mapping[str, str | None] | None = None,
) -> dict[str, Any]:
    """What identifies a campaign's results (a re-run into the same directory must match, except for the
    number of runs); ``code`` the code that runs it (default: this process's,
    :func:`hil.version.describe`)."""
    return {
        "scenario": scenario_name,
        "board": board,
        CODE: dict(version.describe() if code is None else code),
        "scenario_sha256": _sha(scenario_text),
        "dispersions_sha256": _sha(dispersions_text),
        "seed": seed,
        "duration_s": duration_s,
        "trace_hz": trace_hz,
        "trace_samples": samples,
        "traces": list(TRACES),
        "columns": [*FIXED_COLUMNS, *parameter_columns, *METRICS, *check_columns],
        "scenario_toml": scenario_text,
        "dispersions_toml": dispersions_text,
    }


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def trace_dtype(samples: int) -> np.dtype:
    """One traces.bin record: the run index, then each trace's ``samples`` float32 values."""
    return np.dtype([("index", "<i4"), ("trace", "<f4", (len(TRACES), samples))])


class ResultStore:
    """Appends finished runs to an output directory (see the module docstring). ``open`` creates it, or
    checks an existing one against ``manifest`` and repairs a torn tail; ``finished`` are the run
    indices already there."""

    def __init__(self, out_dir: str | os.PathLike[str], manifest: Mapping[str, Any]) -> None:
        self.dir = Path(out_dir)
        self.manifest = dict(manifest)
        self.columns: list[str] = list(manifest["columns"])
        self.dtype = trace_dtype(int(manifest["trace_samples"]))
        make_dir(self.dir)
        self._lock: int | None = _lock_dir(self.dir, SESSION_HOLDER)
        try:
            self._open()
        except BaseException:
            self._unlock()
            raise

    def _open(self) -> None:
        """Check the directory against the manifest, repair a torn tail, read the finished runs, and open
        runs.csv and traces.bin for appending."""
        path = self.dir / MANIFEST
        runs, traces = self.dir / RUNS, self.dir / TRACE_FILE
        refuse_others_outputs(self.dir, MANIFEST, "a campaign's outputs")
        for file in (path, runs, traces):
            _regular_or_absent(file)
        self._on_disk: dict[str, Any] = self.manifest
        if path.exists():
            self._on_disk = self._check_manifest(path)
        else:
            for orphan in (runs, traces):
                if orphan.exists() and orphan.stat().st_size:
                    raise ConfigError(
                        f"{orphan.name} without a {MANIFEST}: not a campaign's directory this command "
                        "can resume (its runs' origin is unknown); give another --out",
                        str(orphan),
                    )
            tmp = path.with_suffix(".json.tmp")
            checked_write(tmp, lambda: tmp.write_text(json.dumps(self.manifest, indent=2) + "\n"))
            os.replace(tmp, path)
        if runs.exists():
            _cut_torn_tail(runs, _last_line_end)
            if runs.stat().st_size:
                self._check_header(runs)
        record = self.dtype.itemsize
        if traces.exists():
            _cut_torn_tail(traces, lambda f, size: size - size % record)
        # an empty runs.csv (a session stopped before its header reached the disk) is a new one
        new = not runs.exists() or runs.stat().st_size == 0
        self.finished: set[int] = set() if new else set(read_runs(self.dir).index.tolist())
        # UTF-8 as read_runs reads it, whatever the locale; a character UTF-8 cannot hold (a lone surrogate:
        # an undecodable file name in an error) escaped, not a UnicodeEncodeError ending the session
        self._rows = checked_write(
            runs, lambda: open(runs, "a", newline="", encoding="utf-8", errors="backslashreplace")
        )
        self._csv = csv.writer(self._rows, lineterminator="\n")
        if new:
            checked_write(runs, lambda: _write_flushed(self._rows, lambda: self._csv.writerow(self.columns)))
        self._traces = checked_write(traces, lambda: open(traces, "ab"))

    def record_session(self, runs_asked: int, state: str, **detail: str) -> None:
        """Rewrite campaign.json's :data:`SESSION` record (atomically, the rest of the file as it is):
        the runs this session asks for, and its ``state`` (:data:`SESSION_STATES`) with ``detail`` (the
        ``signal`` that interrupted it, the ``error`` that stopped it)."""
        if state not in SESSION_STATES:
            raise ValueError(f"not a session state: {state!r}")
        record: dict[str, Any] = {"runs_asked": runs_asked, "state": state, **detail}
        self._on_disk = {**self._on_disk, SESSION: record}
        path = self.dir / MANIFEST
        tmp = path.with_suffix(".json.tmp")
        text = json.dumps(self._on_disk, indent=2) + "\n"
        checked_write(tmp, lambda: tmp.write_text(text))
        checked_write(path, lambda: os.replace(tmp, path))

    def _check_manifest(self, path: Path) -> dict[str, Any]:
        """The campaign.json on disk, checked against this session's manifest (a ConfigError naming it)."""
        try:  # bounded: a manifest nested 100 000 deep or of 1 GB is refused, not a RecursionError
            old = load_json(read_text(path, limit=MAX_DOCUMENT_BYTES), str(path))
        except InputFormatError as exc:
            raise ConfigError(f"unreadable campaign manifest: {exc.detail}", str(path)) from exc
        if not isinstance(old, dict):
            kind = type(old).__name__
            raise ConfigError(f"unreadable campaign manifest: not a JSON object ({kind})", str(path))
        for key in _SAME:
            if old.get(key) == self.manifest[key] or (key == "board" and key not in old):
                continue
            if key in ("seed", "duration_s", "trace_hz", "board"):
                detail = f"{key} {old.get(key)!r}, not {self.manifest[key]!r}"
            else:
                detail = f"another {key.removesuffix('_sha256')}"
            raise ConfigError(
                f"this directory holds another campaign ({detail}); give another --out or the same options",
                str(path),
            )
        self._check_code(old, path)
        return old

    def _check_code(self, old: Mapping[str, Any], path: Path) -> None:
        """The code that wrote the campaign's runs must be this session's (:func:`hil.version.mismatch`:
        the versions, and the revisions when both are known). A campaign's workers were held to its
        driver's code, but a resume was not: an extension after an upgrade (``pip install -U``, a new
        commit) pooled the runs of two versions in one summary, unsaid. A manifest written before the code
        was recorded has none, and is taken as it was; a record that is not one is unreadable."""
        now = self.manifest.get(CODE)
        if CODE not in old or now is None:
            return
        then = old[CODE]
        if not (
            isinstance(then, dict)
            and set(then) == {"version", "revision"}
            and isinstance(then["version"], str)
            and (then["revision"] is None or isinstance(then["revision"], str))
        ):
            raise ConfigError(
                f"unreadable campaign manifest: {CODE} is not a version and a revision ({then!r:.200})",
                str(path),
            )
        why = version.mismatch(now, then)
        if why is not None:
            raise ConfigError(
                f"this directory holds a campaign run by other code ({why}: this session's against the "
                "directory's): its runs and this session's would be pooled in one summary; give another "
                "--out, or run it with the code that made it (hil report DIR summarises it as it is)",
                str(path),
            )

    def _check_header(self, runs: Path) -> None:
        """runs.csv's header must be the manifest's columns: rows appended under another header would be
        read back as malformed (dropped) or under the wrong names."""
        with open(runs, "rb") as f:
            first = f.readline(MAX_HEADER_BYTES).decode("utf-8-sig", errors="replace")
        try:
            header = next(csv.reader([first]), [])
        except csv.Error:
            header = []
        if header != self.columns:
            raise ConfigError(
                f"its header is not this campaign's columns ({_header_difference(header, self.columns)}); "
                "give another --out",
                str(runs),
            )

    def append(self, result: RunResult) -> None:
        """Write one finished run: its trace record (ok runs), then its row, each flushed to the OS. A
        write the OS refuses (a full disk, an I/O error) is a ConfigError naming the file: the run is not
        in ``finished``, and the next session runs it again."""
        if result.ok and result.trace is not None:
            rec = np.zeros((), dtype=self.dtype)
            rec["index"] = result.index
            rec["trace"] = result.trace
            checked_write(
                self.dir / TRACE_FILE,
                lambda: _write_flushed(self._traces, lambda: self._traces.write(rec.tobytes())),
            )
        row: dict[str, float | int | str] = {
            "index": result.index,
            "status": "ok" if result.ok else "failed",
            "error": result.error,
        }
        row.update(result.columns)
        row.update(result.metrics)
        row.update(result.checks)
        cells = [_cell(row.get(c)) for c in self.columns]
        cells = [_message(v) if c in MESSAGE_COLUMNS else v for c, v in zip(self.columns, cells, strict=True)]
        checked_write(self.dir / RUNS, lambda: _write_flushed(self._rows, lambda: self._csv.writerow(cells)))
        self.finished.add(result.index)

    def sync(self) -> None:
        """Push the written rows to the disk (survives a machine crash, not just a process crash)."""
        for f, name in ((self._rows, RUNS), (self._traces, TRACE_FILE)):
            checked_write(self.dir / name, partial(_synced, f))

    def close(self) -> None:
        for f in (self._rows, self._traces):
            if not f.closed:
                try:
                    f.close()
                except OSError as exc:  # a full disk refusing the buffered tail: the next session reruns it
                    logger.warning("%s: closing: %s", self.dir, exc.strerror or exc)
        self._unlock()

    def _unlock(self) -> None:
        if self._lock is not None:
            _let_go(self.dir, self._lock)
            self._lock = None

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


HOLDER = ".holder.json"
"""The record, in the campaign directory, of who holds its lock (:func:`_lock_dir`): ``{"by": ..., "pid":
N}``, written as the lock is taken and removed before it is let go. The lock is ``flock`` on the directory,
which says that someone holds it, not who: a ``hil montecarlo`` started while ``hil report`` drew the
campaign (seconds) was refused "another session is writing", with no session writing, and a second report
said "a session is writing this campaign" (and a campaign killed long before, "still running"). Advisory:
one left by a holder killed is stale, told by its process being gone (:func:`lock_holder`)."""
MAX_HOLDER_BYTES = 4096
"""The most of :data:`HOLDER` read (it is a line of JSON; anything longer is no holder's record)."""
SESSION_HOLDER = "hil montecarlo"
""":data:`HOLDER`'s ``by`` for a session writing the campaign's runs."""
REPORT_HOLDER = "hil report"
""":data:`HOLDER`'s ``by`` for ``hil report`` drawing the campaign's summary.json and plots."""


@dataclass(frozen=True)
class Holder:
    """Who holds a campaign directory's lock, as :data:`HOLDER` records it: ``by`` (:data:`SESSION_HOLDER`,
    :data:`REPORT_HOLDER`) and its process id."""

    by: str
    pid: int

    @property
    def is_session(self) -> bool:
        return self.by == SESSION_HOLDER

    def doing(self) -> str:
        """What the holder is doing, in words (``hil report (pid 4242) is drawing it``)."""
        if self.is_session:
            return f"a session ({self.by}, pid {self.pid}) is writing it"
        return f"{self.by} (pid {self.pid}) is drawing its summary.json and plots (it lets go when drawn)"


def lock_holder(path: str | os.PathLike[str]) -> Holder | None:
    """Who holds the campaign directory ``path``'s lock as its :data:`HOLDER` says, or None when it does
    not say: no record, not one a holder writes, or its process gone (a stale record of a holder killed).
    Asked only when the lock is held (:func:`~hil.files.writing.writer_holds`); never raises, never waits
    (a FIFO put there is not opened for reading)."""
    try:
        fd = os.open(Path(path) / HOLDER, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        data = os.read(fd, MAX_HOLDER_BYTES + 1)
    except OSError:
        return None
    finally:
        os.close(fd)
    try:
        record = json.loads(data.decode("utf-8")) if len(data) <= MAX_HOLDER_BYTES else None
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None
    if not isinstance(record, dict):
        return None
    by, pid = record.get("by"), record.get("pid")
    if by not in (SESSION_HOLDER, REPORT_HOLDER) or not (
        isinstance(pid, int) and not isinstance(pid, bool) and 0 < pid < 2**31
    ):
        return None
    try:
        os.kill(pid, 0)  # no signal sent: whether the process is there
    except ProcessLookupError:
        return None
    except OSError:
        pass  # there, another user's
    return Holder(by, pid)


def _record_holder(path: Path, by: str) -> None:
    """Write :data:`HOLDER` for this process, holding ``path``'s lock as ``by``: atomically (a reader never
    sees half a record), best effort — a directory that takes no file (read-only, a full disk) is held all
    the same, its holder then unsaid."""
    tmp = path / f"{HOLDER}.{os.getpid()}.tmp"
    try:
        tmp.write_text(json.dumps({"by": by, "pid": os.getpid()}) + "\n", encoding="utf-8")
        os.replace(tmp, path / HOLDER)
    except OSError as exc:
        logger.debug("%s: its holder not recorded: %s", path, exc.strerror or exc)
        with suppress(OSError):
            tmp.unlink()


def _let_go(path: Path, fd: int) -> None:
    """Let go of the lock ``fd`` on ``path`` (:func:`_lock_dir`): its :data:`HOLDER` record removed first,
    while it is still this process's."""
    with suppress(OSError):
        (path / HOLDER).unlink()
    os.close(fd)  # closing the descriptor releases the directory's lock


def _lock_dir(path: Path, by: str) -> int | None:
    """An exclusive lock on the campaign directory for ``by`` (:data:`SESSION_HOLDER`: a session;
    :data:`REPORT_HOLDER`: ``hil report`` drawing it) — ``flock`` on the directory itself, let go by the OS
    when the process ends, however it ends — and who holds it recorded (:data:`HOLDER`). Two sessions of
    one campaign in one directory (the command started again in another terminal) each ran the runs the
    directory lacked when it started, the same runs twice, and each said it had run them; the second is
    a ConfigError naming the directory and who holds it. A file system without locks (some network ones)
    goes without."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as exc:
        raise ConfigError(f"cannot open: {exc.strerror or exc}", str(path)) from exc
    from hil.files.writing import TRIES, TRY_PAUSE_S

    for _ in range(TRIES):
        # a reader's question (:func:`hil.files.writing.writer_holds`: ``hil report``, ``hil gcs``) holds a
        # shared lock for microseconds: taken at the moment a session started, the session was refused,
        # "another session is writing", with none writing. Asked again, as WriterLock does
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            time.sleep(TRY_PAUSE_S)
            continue
        except OSError:
            os.close(fd)
            return None
        _record_holder(path, by)
        return fd
    os.close(fd)
    holder = lock_holder(path)
    if holder is None:
        said = (
            "another process holds this campaign directory (a hil montecarlo session writing it, or hil "
            "report drawing it: it did not say which)"
        )
    elif holder.is_session:
        said = f"another session is writing this campaign directory ({holder.by}, pid {holder.pid})"
    else:
        said = f"this campaign directory is held: {holder.doing()}"
    raise ConfigError(f"{said}: let it finish, or give another --out", str(path))


@contextmanager
def holding_dir(path: str | os.PathLike[str]) -> Iterator[bool | None]:
    """The campaign directory ``path``'s lock held (:func:`_lock_dir`, by :data:`REPORT_HOLDER`) for what is
    written beside a session's files: ``hil report`` rewriting summary.json and the plots from the runs on
    disk. Yields True while it is held, False on a file system without locks, None when another holds it
    (nothing is to be written then: a summary written beside a session still appending described fewer
    runs than runs.csv came to hold, and could be the one left standing; :func:`lock_holder` says who).
    A directory that cannot be opened is a :class:`ConfigError` naming it."""
    from hil.files.writing import writer_holds

    try:
        fd = _lock_dir(Path(path), REPORT_HOLDER)
    except ConfigError:
        if writer_holds(path):  # not a directory that cannot be opened: held by another
            yield None
            return
        raise
    try:
        yield fd is not None
    finally:
        if fd is not None:
            _let_go(Path(path), fd)


def _regular_or_absent(path: Path) -> None:
    """Refuse a campaign file that exists and is not a regular file: a directory, a FIFO (opening it
    would wait for a writer for ever), a device (``/dev/zero`` never ends)."""
    regular_file_if_there(path, ConfigError, hint=" (a directory, a FIFO or a device): give another --out")


def checked_write(path: Path, action: Callable[[], T]) -> T:
    """``action()`` (an open, write, flush or fsync of ``path``), an OSError (no space left, an I/O
    error, no permission) a ConfigError naming the file; one of the project's errors that is an OSError
    too (:class:`~hil.files.output.OutputError`, which names its file already) passes as it is."""
    try:
        return action()
    except HilError:
        raise
    except OSError as exc:
        raise ConfigError(f"cannot write: {exc.strerror or exc}", str(path)) from exc


def _write_flushed(f: IO[Any], write: Callable[[], object]) -> None:
    """``write()`` into ``f``, then ``f`` flushed: a result reaches the file as it is made."""
    write()
    f.flush()


def _synced(f: IO[Any]) -> None:
    """``f`` flushed and fsynced: its rows survive a machine crash, not just a process crash."""
    f.flush()
    os.fsync(f.fileno())


def _last_line_end(f: BinaryIO, size: int) -> int:
    """Where the last whole line of ``f`` (``size`` bytes) ends: read backwards a block at a time, so a
    file of one endless line is not read whole."""
    end = size
    while end > 0:
        start = max(0, end - TAIL_BLOCK_BYTES)
        f.seek(start)
        at = f.read(end - start).rfind(b"\n")
        if at >= 0:
            return start + at + 1
        end = start
    return 0


def _cut_torn_tail(path: Path, keep: Callable[[BinaryIO, int], int]) -> None:
    """Cut ``path`` to ``keep(file, size)`` bytes (a torn last line or record)."""

    def cut() -> None:
        with open(path, "r+b") as f:
            size = os.fstat(f.fileno()).st_size
            end = keep(f, size)
            if end < size:
                f.truncate(end)

    checked_write(path, cut)


_LINE_BREAK_OR_NUL = re.compile(r"\r\n|[\r\n\x00]")


def _cell(value: Any) -> str:
    """One cell of runs.csv. A text cell is one line with no NUL: read back, csv refuses a NUL and a
    carriage return (an error quoting a device's ``\\r\\n``), and the row was dropped as damaged — a failed
    run missing from the summary; each is written visibly instead (a line break as `` | ``)."""
    if value is None:
        return ""
    if isinstance(value, float | np.floating):
        return "" if math.isnan(value) else repr(float(value))
    return _LINE_BREAK_OR_NUL.sub(lambda m: "\\x00" if m.group() == "\x00" else " | ", str(value))


def _message(text: str) -> str:
    """A message cell bounded to :data:`MAX_MESSAGE_CHARS`, what is cut said (with how much)."""
    if len(text) <= MAX_MESSAGE_CHARS:
        return text
    return f"{text[:MAX_MESSAGE_CHARS]} … [{len(text) - MAX_MESSAGE_CHARS} more characters not kept]"


# --------------------------------------------------------------------------- reading results back
@dataclass(frozen=True)
class Results:
    """A campaign's runs.csv read back, one entry per run in index order (the last row of an index wins):
    ``index`` (N,), ``ok`` (N,) bool, ``errors`` index → error text of the failed runs, ``values`` column
    → float array (N,) (NaN where empty: a failed run's metrics), ``text`` column → array of str for
    columns that are not numbers (e.g. ``link.outage_list``); ``dropped`` malformed lines, and rows of a
    run that has a later row too."""

    index: NDArray[np.int64]
    ok: NDArray[np.bool_]
    errors: dict[int, str]
    values: dict[str, NDArray[np.float64]]
    text: dict[str, NDArray[np.object_]]
    columns: list[str]
    dropped: int

    def __len__(self) -> int:
        return len(self.index)

    def parameter_columns(self) -> list[str]:
        """The drawn parameters that are numbers, in file order."""
        return [
            c
            for c in self.columns
            if c not in FIXED_COLUMNS and c not in METRICS and c not in CHECK_COLUMNS and c in self.values
        ]


def read_runs(out_dir: str | os.PathLike[str], columns: Sequence[str] | None = None) -> Results:
    """Read ``OUT/runs.csv``; with ``columns`` (campaign.json's, :func:`read_manifest`) its header must
    begin with them, in order, and name no column twice, else an :class:`InputFormatError` naming line 1
    and the first difference — a header edited by
    hand (a metric renamed, a column named twice) left that metric out of every figure, its runs said
    "not judged: no readable value", and drawing was a KeyError's traceback.

    A malformed line — the wrong number of cells, a run index that is not a plain number
    0..:data:`MAX_INDEX`, a metric that is not a number, an invariant's violations
    (:data:`~.runner.VIOLATION_COLUMNS`) that are not such a count, a line longer than
    :data:`~hil.files.bounded.MAX_LINE_BYTES`, a last row without its line break (torn: :func:`_text_lines`)
    — or a run's row with a later one, is dropped and counted (``dropped``).

    Streamed, a piece of the file at a time (:func:`~hil.files.bounded.read_lines`): memory holds the
    numbers of the columns that are numbers (a float per cell), the cells of the columns that are not
    (their equal cells shared) and the failed runs' errors — never the file's text or its rows' cells
    (a runs.csv of 196 MB took 2.1 GB). A column is numbers until a cell of it is not one: its cells
    before are then its text again (an empty cell empty, a number as ``repr`` gives it, a whole one
    without ``.0``). A column a run writes as text (:data:`TEXT_COLUMNS`) is text, its cells as written,
    whatever they hold."""
    path = Path(out_dir) / RUNS
    try:
        _regular_or_absent(path)
    except ConfigError as exc:
        raise InputFormatError(exc.detail, str(path)) from None
    input_kind(path, InputFormatError, "results")
    try:
        f = open(path, "rb")  # noqa: SIM115 — closed below
    except FileNotFoundError:
        raise InputFormatError("no such file results", str(path)) from None
    except OSError as exc:
        raise InputFormatError(f"cannot read results: {exc.strerror or exc}", str(path)) from exc
    with f:
        return _read_runs(csv.reader(_text_lines(f, path)), path, columns)


def _text_lines(f: BinaryIO, path: Path) -> Iterator[str]:
    """The lines of ``f`` as text (a BOM skipped), for :mod:`csv`; a line too long to keep is an empty
    one (a row of no cells: dropped); one that is not UTF-8 an InputFormatError naming its line.

    A last row without its line break is an empty one too: a row is a run's commit record once its line
    break is written (:class:`ResultStore` cuts such a line off and runs that run again). Read, a row torn
    inside its last cell — a campaign killed mid-write, a live one read between a row's pieces — gave that
    cell's first digits (``12.0`` read ``1``) as the run's value, said nowhere."""
    number = 0
    for batch in read_lines(f):
        torn = isinstance(batch, Unterminated)
        for line in batch:
            number += 1
            if line is None or (torn and number > 1):
                yield ""
                continue
            try:
                yield line.decode("utf-8-sig" if number == 1 else "utf-8")
            except UnicodeDecodeError as exc:
                raise InputFormatError(
                    f"not a text file (not UTF-8: {exc.reason}, line {number})", str(path), number
                ) from None


class _Column:
    """One column's cells as they are read: floats while every cell is a number (or empty), then text."""

    __slots__ = ("numbers", "text", "_shared")

    def __init__(self, text: bool = False) -> None:
        """``text``: a column of :data:`TEXT_COLUMNS`, text from its first cell."""
        self.numbers: array[float] | None = None if text else array("d")
        self.text: list[str] = []
        self._shared: dict[str, str] = {}

    def add(self, cell: str) -> None:
        if self.numbers is not None:
            try:
                self.numbers.append(float(cell) if cell != "" else math.nan)
                return
            except ValueError:
                self.text = [self._share(_as_text(x)) for x in self.numbers]
                self.numbers = None
        self.text.append(self._share(cell))

    def _share(self, cell: str) -> str:
        return self._shared.setdefault(cell, cell)


def _as_text(x: float) -> str:
    if math.isnan(x):
        return ""
    return str(int(x)) if x.is_integer() and abs(x) < 2**53 else repr(x)


def _read_runs(reader: Iterator[list[str]], path: Path, expected: Sequence[str] | None) -> Results:
    try:
        header = next(reader, None)
    except csv.Error as exc:
        raise InputFormatError(f"not a campaign's runs.csv ({exc})", str(path), 1) from None
    if not header or list(header[:3]) != list(FIXED_COLUMNS):
        raise InputFormatError(f"not a campaign's runs.csv (header {header!r:.200})", str(path), 1)
    twice = _named_twice(header)
    if expected is not None and (header[: len(expected)] != list(expected) or twice is not None):
        # columns after the campaign's (added by hand, by another tool) are read as they are
        why = f"{twice[:60]!r} named twice" if twice is not None else _header_difference(header, expected)
        raise InputFormatError(
            f"its header is not the campaign's columns in {MANIFEST} ({why})", str(path), 1
        )
    numeric = [j for j, name in enumerate(header) if name in METRICS]
    counts = [j for j, name in enumerate(header) if name in VIOLATION_COLUMNS]
    indices = array("q")
    ok = bytearray()
    errors: dict[int, str] = {}  # position in the file's rows → error text (failed runs)
    columns = [_Column(text=name in TEXT_COLUMNS) for name in header[3:]]
    dropped = 0
    while True:
        try:
            cells = next(reader, None)
        except csv.Error:  # a NUL byte, an unterminated quote at the end: the line is no row
            dropped += 1
            continue
        if cells is None:
            break
        if len(cells) != len(header) or not _INDEX.fullmatch(cells[0]) or int(cells[0]) > MAX_INDEX:
            dropped += 1
            continue
        if not all(_number_or_empty(cells[j]) for j in numeric):
            dropped += 1  # a damaged metric would turn its whole column into text, every figure gone
            continue
        if not all(_count_or_empty(cells[j]) for j in counts):
            # an invariant's violations that are no count: ``inf`` was an OverflowError's traceback from
            # the summary, ``-3`` subtracted from the others' violations, and ``nan`` or text (which turned
            # the whole column to text) hid every run's violations — a broken campaign summarised as clean
            dropped += 1
            continue
        if cells[1] != "ok":
            errors[len(indices)] = cells[2]
        indices.append(int(cells[0]))
        ok.append(cells[1] == "ok")
        for column, cell in zip(columns, cells[3:], strict=True):
            column.add(cell)
    # a run's row twice (the file was edited): the last kept, the rest counted
    index = np.frombuffer(indices, dtype=np.int64) if len(indices) else np.zeros(0, dtype=np.int64)
    by_index = np.lexsort((np.arange(len(index)), index))  # by index, then by position
    last = np.ones(len(by_index), dtype=bool)
    last[:-1] = index[by_index[1:]] != index[by_index[:-1]]
    keep = by_index[last]
    dropped += len(index) - len(keep)
    values: dict[str, NDArray[np.float64]] = {}
    text_cols: dict[str, NDArray[np.object_]] = {}
    for j, name in enumerate(header[3:]):
        column, columns[j] = columns[j], _Column()  # each freed once it is taken
        if column.numbers is None:
            cells = [column.text[k] for k in keep.tolist()]
            # its text only in rows left out (a run's earlier row): numbers, unless a run writes it as text
            numbers = None if name in TEXT_COLUMNS else _numbers(cells)
            if numbers is None:
                text_cols[name] = np.array(cells, dtype=object)
            else:
                values[name] = numbers
        elif len(keep):
            values[name] = np.frombuffer(column.numbers, dtype=float)[keep]  # a copy: fancy indexing
        else:
            values[name] = np.zeros(0)
        del column
    oks = np.frombuffer(bytes(ok), dtype=np.uint8).astype(bool)[keep] if len(keep) else np.zeros(0, bool)
    kept_errors = {int(index[k]): errors[k] for k in keep.tolist() if k in errors}
    return Results(index[keep].copy(), oks, kept_errors, values, text_cols, list(header), dropped)


def _numbers(cells: list[str]) -> NDArray[np.float64] | None:
    """``cells`` as numbers (an empty one NaN), or None if one is not a number."""
    try:
        return np.array([float(c) if c != "" else math.nan for c in cells], dtype=float)
    except ValueError:
        return None


def _count_or_empty(cell: str) -> bool:
    """Whether ``cell`` is a count as a run writes one (a plain whole number 0..:data:`MAX_INDEX`), or
    empty (a run that failed before its checks)."""
    return cell == "" or (_INDEX.fullmatch(cell) is not None and int(cell) <= MAX_INDEX)


def _number_or_empty(cell: str) -> bool:
    if cell == "":
        return True
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _named_twice(header: Sequence[str]) -> str | None:
    """The first column name ``header`` holds twice (the later column's cells would be read as the
    earlier's), or None."""
    seen: set[str] = set()
    for name in header:
        if name in seen:
            return name
        seen.add(name)
    return None


def _header_difference(header: Sequence[str], columns: Sequence[str]) -> str:
    """How runs.csv's ``header`` is not the campaign's ``columns``, for a message."""
    return f"{len(header)} columns, expected {len(columns)}: {_first_difference(header, columns)}"


def _first_difference(header: Sequence[str], columns: Sequence[str]) -> str:
    """Where ``header`` first differs from ``columns``, for a message."""
    for k, (a, b) in enumerate(zip(header, columns, strict=False)):
        if a != b:
            return f"column {k + 1} is {a[:60]!r}, not {b!r}"
    return "a column missing" if len(header) < len(columns) else "a column too many"


def read_manifest(out_dir: str | os.PathLike[str]) -> dict[str, Any]:
    """``OUT/campaign.json``, the figures a reader of the directory relies on checked: a JSON object
    (bounded, :func:`~hil.files.bounded.load_json`) whose ``duration_s`` (0..a day) and ``trace_hz``
    (0..the highest control rate) give its ``trace_samples``, and whose ``columns`` (runs.csv's header:
    :func:`read_runs` holds the file to them) are names, the fixed ones first, every metric among them,
    none twice. Anything else an :class:`InputFormatError` naming the file and the key (a manifest edited
    by hand had ``trace_samples: -5`` end in numpy's ValueError)."""
    path = Path(out_dir) / MANIFEST
    info = load_json(read_text(path, InputFormatError, limit=MAX_DOCUMENT_BYTES), str(path))
    if not isinstance(info, dict):
        raise InputFormatError("not a campaign manifest (a JSON object)", str(path))
    for key, (lo, hi) in {"duration_s": (0.0, MAX_DURATION_S), "trace_hz": (0.0, MAX_TRACE_HZ)}.items():
        value = info.get(key)
        if not (isinstance(value, int | float) and not isinstance(value, bool) and lo < value <= hi):
            raise InputFormatError(
                f"must be a number in ({lo:g}, {hi:g}], got {value!r}", str(path), None, key
            )
    columns = info.get("columns")
    if not (
        isinstance(columns, list)
        and all(isinstance(c, str) for c in columns)
        and columns[: len(FIXED_COLUMNS)] == list(FIXED_COLUMNS)
        and set(METRICS) <= set(columns)
        and len(set(columns)) == len(columns)
    ):
        raise InputFormatError(
            f"must be the results' column names, {', '.join(FIXED_COLUMNS)} first, each metric among them "
            f"and no name twice; got {columns!r:.200}",
            str(path),
            None,
            "columns",
        )
    samples = info.get("trace_samples")
    expected = trace_length(info["duration_s"], info["trace_hz"])
    if samples != expected or isinstance(samples, bool):
        raise InputFormatError(
            f"must be {expected} (duration_s × trace_hz), got {samples!r}", str(path), None, "trace_samples"
        )
    return info


@dataclass(frozen=True)
class SessionRecord:
    """campaign.json's :data:`SESSION` record as read back: ``runs_asked`` (None: a campaign.json written
    before it was recorded) and ``ended``, how the last session ended in words — ``finished``,
    ``interrupted (SIGINT)``, ``stopped: <error>``, ``killed`` (it says ``running`` and no session holds
    the directory), ``still running`` (one does), or None when unknown."""

    runs_asked: int | None
    ended: str | None


def read_session(
    out_dir: str | os.PathLike[str], info: Mapping[str, Any], locked_here: bool = False
) -> SessionRecord:
    """The :data:`SESSION` record of ``info`` (``out_dir``'s campaign.json, :func:`read_manifest`). One
    that is not what a session writes (edited by hand: not an object, runs asked that are not a whole
    number 1..:data:`MAX_RUNS`, a state not in :data:`SESSION_STATES`) is an
    :class:`InputFormatError` naming the file and the key; one that is absent is unknown, not an error.
    ``locked_here``: this process holds the directory's lock (:func:`holding_dir`), so a record that says
    ``running`` is no live session's — asked of the lock, it was this process's own hold, "still running"."""
    path = Path(out_dir) / MANIFEST
    if SESSION not in info:
        return SessionRecord(None, None)
    record = info[SESSION]
    if not isinstance(record, dict):
        raise InputFormatError(f"must be an object, got {record!r:.80}", str(path), None, SESSION)
    asked = record.get("runs_asked")
    if not (isinstance(asked, int) and not isinstance(asked, bool) and 1 <= asked <= MAX_RUNS):
        raise InputFormatError(
            f"must be a whole number in 1..{MAX_RUNS}, got {asked!r:.80}",
            str(path),
            None,
            f"{SESSION}.runs_asked",
        )
    state = record.get("state")
    if state not in SESSION_STATES:
        raise InputFormatError(
            f"must be one of {', '.join(SESSION_STATES)}, got {state!r:.80}",
            str(path),
            None,
            f"{SESSION}.state",
        )
    if state == "running":
        from hil.files.writing import writer_holds  # the same lock as _lock_dir's: flock on the directory

        holds = False if locked_here else writer_holds(out_dir)
        if holds and (holder := lock_holder(out_dir)) is not None and not holder.is_session:
            holds = False  # held by hil report drawing it: no session runs beside it (the lock is one)
        ended = "still running" if holds else "killed" if holds is False else "killed, or still running"
    else:
        ended = session_ended(state, record)
    return SessionRecord(asked, ended)


def session_ended(state: str, detail: Mapping[str, Any]) -> str:
    """How a session that recorded ``state`` (not ``running``) with ``detail`` (its ``signal``, its
    ``error``) ended, in the words :class:`SessionRecord` says it: one wording for the record read back and
    for the session that ends (whose record the disk may refuse)."""
    if state == "interrupted":
        return f"interrupted ({str(detail.get('signal', 'a signal'))[:20]})"
    if state == "stopped":
        return f"stopped: {str(detail.get('error', 'an error'))[:MAX_MESSAGE_CHARS]}"
    return "finished"


def read_traces(
    out_dir: str | os.PathLike[str], keep: Iterable[int] | None = None
) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """The traces of ``OUT``: run indices (M,) and traces (M, len(TRACES), samples), one per index (the
    last record wins), only for ``keep`` indices when given (e.g. the runs.csv rows). Read a chunk of
    records at a time, keeping only the traces asked for: the memory is theirs, whatever the file's size
    (a torn last record is left out).

    A record of zero bytes only is no run's: it is what a crash leaves where appended blocks were
    allocated and never written (a zero-filled tail), or a file grown by hand. Read as written it would be
    run 0's trace, all zeros, winning over run 0's own as the last record; such records are left out,
    counted in a warning."""
    out = Path(out_dir)
    dtype = trace_dtype(int(read_manifest(out)["trace_samples"]))
    wanted = None if keep is None else set(int(i) for i in keep)
    last: dict[int, NDArray[np.float32]] = {}
    path = out / TRACE_FILE
    try:
        _regular_or_absent(path)  # a FIFO would wait for a writer for ever
    except ConfigError as exc:
        raise InputFormatError(exc.detail, str(path)) from None
    per_chunk = max(1, TRACE_CHUNK_BYTES // dtype.itemsize) * dtype.itemsize
    zeroed = 0
    with open(path, "rb") if path.exists() else io.BytesIO() as f:
        while data := f.read(per_chunk):
            whole = data[: len(data) - len(data) % dtype.itemsize]
            records = np.frombuffer(whole, dtype=dtype)
            bytes_of = np.frombuffer(whole, np.uint8).reshape(len(records), dtype.itemsize)
            written: list[bool] = (np.count_nonzero(bytes_of, axis=1) > 0).tolist()
            zeroed += written.count(False)
            for k, i in enumerate(records["index"].tolist()):
                if written[k] and (wanted is None or i in wanted):
                    last[i] = records["trace"][k].copy()
    if zeroed:
        logger.warning(
            "%s: %d records of zero bytes only (no run's: a crash's unwritten tail?) left out", path, zeroed
        )
    order = sorted(last)
    traces = np.array([last[i] for i in order], dtype=np.float32).reshape(len(order), *dtype["trace"].shape)
    return np.array(order, dtype=np.int64), traces
