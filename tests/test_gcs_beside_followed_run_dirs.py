"""``hil gcs RUN_DIR`` following a run directory that changes under it in ways a run's own writer never
does, but the machine around it may: the directory replaced by a new run of the same name (a second
``hil run --label`` into the same second, a script that rm -rf's and reruns), ``telemetry.csv`` truncated
and rewritten in place, ``events.jsonl`` rotated (renamed away, or truncated in place as logrotate's
``copytruncate`` does), a run killed mid-line, a FIFO where a file should be.

The reader names its files by path, and read on from its offset into whatever is there now: the new run's
rows were drawn on the old run's plots (or dropped as "out of order", counted as the old run's damage),
the new run's ``summary.json`` made the page say the old, killed run had "finished" with the new run's exit,
a rotated events log was read from the middle of its first line, and a FIFO hung ``hil gcs`` before it
printed its URL. These go through :class:`~hil.gcs.RunDirSource` (the page's source) and a real station's
``/api/stream``; moments and sizes are drawn by Hypothesis.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from gcs_support import wait_for
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation, RunDirSource
from hil.gcs.wire import Batch

HEADER = "t,phase,point_err_deg\n"
FAST = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def rows_text(n: int, start: int = 0, marker: int = 1) -> str:
    """``n`` telemetry lines from row ``start``, 50 rows a second, ``phase`` = ``marker``: which run."""
    return "".join(f"{k / 50},{marker},{30 - k}\n" for k in range(start, start + n))


def write_run(d: Path, rows: int, marker: int, summary: str | None = None) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    (d / "telemetry.csv").write_text(HEADER + rows_text(rows, marker=marker))
    (d / "events.jsonl").write_text(f'{{"t": 0.0, "kind": "armed", "run": {marker}}}\n')
    if summary is not None:
        (d / "summary.json").write_text(json.dumps({"exit": summary}))
    return d


def drain(source: RunDirSource, polls: int = 4) -> list[Batch]:
    return [source.poll() for _ in range(polls)]


def statuses(batches: list[Batch]) -> list[dict]:
    return [b.status for b in batches if b.status is not None]


# --------------------------------------------------------------------------- the directory replaced
@FAST
@given(
    old_rows=st.integers(1, 200),
    new_rows=st.integers(0, 400),
    new_summary=st.sampled_from([None, "completed", "aborted"]),
    how=st.sampled_from(["rmtree", "rename"]),
)
def test_a_run_directory_replaced_by_another_run_is_never_drawn_over_it_nor_called_finished(
    tmp_path_factory, old_rows, new_rows, new_summary, how
):
    root = tmp_path_factory.mktemp("replaced")
    d = write_run(root / "20260101-120000-cubesat-1u", old_rows, marker=1)  # killed: no summary
    source = RunDirSource(d)
    first = source.poll()
    assert len(first.rows) == old_rows and first.status["state"] == "following"
    if how == "rmtree":
        shutil.rmtree(d)
        write_run(d, new_rows, marker=2, summary=new_summary)
    else:
        write_run(root / "new", new_rows, marker=2, summary=new_summary)
        shutil.rmtree(d)
        os.rename(root / "new", d)
    after = drain(source)
    assert not [r for b in after for r in b.rows], "the new run's rows drawn on the old run's plots"
    assert not [e for b in after for e in b.events], "the new run's events shown as the old run's"
    told = statuses(after)
    assert told and all(s["state"] != "finished" for s in told) and not source.finished
    assert told[-1]["state"] == "read" and told[-1]["exit"] is None and "after" in told[-1]["error"]
    assert source.bad_rows == 0 and source.rows == old_rows  # the new run is not the old one's damage


@FAST
@given(
    rows=st.integers(2, 200),
    cut=st.floats(0.0, 1.0),
    rewrite_rows=st.integers(0, 600),
    same_inode=st.booleans(),
)
def test_a_telemetry_truncated_and_rewritten_is_not_read_on_from_the_old_offset(
    tmp_path_factory, rows, cut, rewrite_rows, same_inode
):
    d = write_run(tmp_path_factory.mktemp("rewritten") / "run", rows, marker=1)
    source = RunDirSource(d)
    assert len(source.poll().rows) == rows
    tel = d / "telemetry.csv"
    kept = tel.read_bytes()[: int(cut * (tel.stat().st_size - 1))]  # not all: then it is only appended to
    text = kept + (HEADER + rows_text(rewrite_rows, marker=3)).encode()
    if same_inode:
        with tel.open("r+b") as f:  # in place: the same inode, shorter or longer than what was read
            f.truncate(0)
            f.write(text)
    else:
        tel.unlink()
        tel.write_bytes(text)
    after = drain(source)
    assert not [r for b in after for r in b.rows if r[1] == 3], "rows of the rewritten file drawn"
    told = statuses(after)
    assert told[-1]["state"] == "read" and "telemetry.csv was" in told[-1]["error"]
    assert source.bad_rows == 0


def test_the_station_s_stream_says_the_directory_was_replaced_and_never_finished(tmp_path):
    """What the page gets (``/api/stream``): the old run's rows, then a status that is not ``finished``
    and says why; the new run's rows and its ``summary.json``'s exit never."""
    d = write_run(tmp_path / "run", 40, marker=1)
    with GroundStation.replay(d, bind="127.0.0.1:0") as station:
        wait_for(lambda: station.stats()["run_dir"]["rows"] == 40, 10, "the old run read")
        shutil.rmtree(d)
        write_run(d, 400, marker=2, summary="completed")
        wait_for(lambda: station.source._done, 10, "the replacement seen")  # type: ignore[attr-defined]
        data = _stream_until(station, b'"state":"read"')
    messages = [m for m in data.decode().split("\n\n") if m.startswith("event:")]
    rows = [
        r
        for m in messages
        if m.startswith("event: rows")
        for r in json.loads(m.split("data: ", 1)[1])["rows"]
    ]
    told = [json.loads(m.split("data: ", 1)[1]) for m in messages if m.startswith("event: status")]
    assert len(rows) == 40 and {r[1] for r in rows} == {1}
    assert all(s["state"] != "finished" for s in told) and "completed" not in data.decode()
    assert told[-1]["state"] == "read" and told[-1]["exit"] is None


def _stream_until(station: GroundStation, needle: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", station.port), timeout=10) as s:
        s.sendall(f"GET /api/stream?token={station.token} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode())
        data = b""
        while needle not in data:
            chunk = s.recv(65536)
            assert chunk, data[-300:]
            data += chunk
    return data.partition(b"\r\n\r\n")[2]


@FAST
@given(
    rows=st.integers(1, 100),
    pad=st.integers(1, 150),
    torn=st.floats(0.0, 1.0),
    more=st.integers(0, 50),
    finish=st.booleans(),
)
def test_a_torn_line_its_writer_cuts_back_is_forgotten_and_the_run_followed_on(
    tmp_path_factory, rows, pad, torn, more, finish
):
    """A run's own writer (:class:`hil.files.appending.LineAppender`, ``\\r\\n`` lines as ``CsvLog``'s)
    cuts a write the OS refused half-way back to the end of its last whole line: a reader that read the
    torn part before the cut has a file shorter than what it read, or other bytes there once the writer
    went on. That is the run's file still — the rows before stay, the ones after are read from the cut, the
    run's summary says how it ended — not a file truncated or rewritten by someone else. ``pad`` digits
    in a last column make the torn line shorter or longer than the bytes the reader compares."""

    def lines(text: str) -> str:
        return "".join(f"{line},{'1' * pad}\r\n" for line in text.splitlines())

    d = write_run(tmp_path_factory.mktemp("cut") / "run", 0, marker=1)
    tel = d / "telemetry.csv"
    whole = "t,phase,point_err_deg,pad\r\n" + lines(rows_text(rows))
    tel.write_text(whole, newline="")
    line = lines(rows_text(1, start=rows, marker=9))  # a row the writer then cut
    with tel.open("a", newline="") as f:
        f.write(line[: 1 + int(torn * (len(line) - 3))])  # torn before its line break
    source = RunDirSource(d)
    assert len(source.poll().rows) == rows
    os.truncate(tel, len(whole))  # what LineAppender._cut does
    with tel.open("a", newline="") as f:
        f.write(lines(rows_text(more, start=rows)))
    if finish:
        (d / "summary.json").write_text(json.dumps({"exit": "output error"}))
    batches = drain(source)
    drawn = [r for b in batches for r in b.rows]
    assert len(drawn) == more and source.rows == rows + more and all(r[1] == 1 for r in drawn)
    assert source.bad_rows == 0 and all("error" not in s for s in statuses(batches))
    assert source.finished == finish and (not finish or statuses(batches)[-1]["exit"] == "output error")


# --------------------------------------------------------------------------- events.jsonl rotated
@FAST
@given(
    before=st.integers(0, 30),
    unread=st.integers(0, 5),
    after=st.integers(0, 30),
    how=st.sampled_from(["rename", "copytruncate"]),
)
def test_a_rotated_events_log_is_read_from_the_start_of_the_new_file(
    tmp_path_factory, before, unread, after, how
):
    """Rotated while the run goes on (its telemetry still growing): every event of the new file arrives
    whole, none is read from the middle of a line, and the telemetry is still followed."""
    d = write_run(tmp_path_factory.mktemp("rotated") / "run", 10, marker=1)
    events = d / "events.jsonl"
    events.write_text("".join(json.dumps({"t": k / 10, "kind": "old", "k": k}) + "\n" for k in range(before)))
    source = RunDirSource(d)
    assert len(source.poll().events) == before
    with events.open("a") as f:  # written after the last poll, before the rotation
        f.write("".join(json.dumps({"t": 9.0, "kind": "old", "k": k}) + "\n" for k in range(unread)))
    new = "".join(json.dumps({"t": 10 + k / 10, "kind": "new", "k": k}) + "\n" for k in range(after))
    if how == "rename":
        events.rename(d / "events.jsonl.1")
        events.write_text(new)
    else:
        shutil.copy(events, d / "events.jsonl.1")
        with events.open("r+") as f:
            f.truncate(0)
            f.write(new)
    with (d / "telemetry.csv").open("a") as f:
        f.write(rows_text(5, start=10))
    batches = drain(source)
    got = [e for b in batches for e in b.events]
    assert [e["k"] for e in got if e["kind"] == "new"] == list(range(after))
    assert all(e["kind"] in ("old", "new") for e in got) and source.bad_events == 0
    assert sum(len(b.rows) for b in batches) == 5
    assert all(s["state"] == "following" for s in statuses(batches)) and not source.finished


# --------------------------------------------------------------------------- killed mid-line
@FAST
@given(rows=st.integers(1, 100), cut=st.floats(0.0, 1.0), summary=st.booleans(), follow=st.booleans())
def test_a_line_torn_by_a_kill_is_counted_once_reading_stops(tmp_path_factory, rows, cut, summary, follow):
    """A run killed at a drawn byte of its telemetry (and of its events): each torn last line is counted as
    damaged once nothing more will be read — finished, or read without following — as ``hil report``
    counts it; while following it waits (it may yet be completed)."""
    d = tmp_path_factory.mktemp("killed") / "run"
    whole = HEADER + rows_text(rows)
    at = len(HEADER) + int(cut * (len(whole) - len(HEADER)))
    write_run(d, 0, marker=1)
    (d / "telemetry.csv").write_text(whole[:at])
    (d / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n{"t": 0.1, "ki')
    if summary:
        (d / "summary.json").write_text(json.dumps({"exit": "completed"}))
    source = RunDirSource(d, follow=follow)
    drawn = sum(len(b.rows) for b in drain(source))
    torn = not whole[:at].endswith("\n")
    assert drawn == whole[:at].count("\n") - 1 and source.events == 1
    if summary or not follow:
        assert (source.bad_rows, source.bad_events) == (int(torn), 1)
        assert source.poll().status is None  # counted once
    else:
        assert (source.bad_rows, source.bad_events) == (0, 0)


# --------------------------------------------------------------------------- not a file
def test_a_fifo_for_telemetry_is_refused_at_once_not_waited_on(tmp_path):
    """``hil gcs`` on a directory whose telemetry.csv is a FIFO hung in its first read (the open waits for
    a writer), before printing its URL: now exit 2, naming it."""
    d = tmp_path / "run"
    d.mkdir()
    os.mkfifo(d / "telemetry.csv")
    done = subprocess.run(
        [sys.executable, "-m", "hil", "gcs", "--no-follow", "--gcs", "127.0.0.1:0", str(d)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and "telemetry.csv: not a regular file" in done.stderr


def test_an_events_log_that_becomes_a_fifo_while_followed_is_an_error_not_a_hang(tmp_path):
    d = write_run(tmp_path / "run", 5, marker=1)
    source = RunDirSource(d)
    source.poll()
    (d / "events.jsonl").unlink()
    os.mkfifo(d / "events.jsonl")
    outcome: list[BaseException | Batch] = []

    def poll() -> None:
        try:
            outcome.append(source.poll())
        except Exception as exc:  # the pump's error: stored and shown on the page
            outcome.append(exc)

    thread = threading.Thread(target=poll, daemon=True)
    thread.start()
    thread.join(5.0)
    assert not thread.is_alive(), "the poll waits on the FIFO"
    assert "not a regular file" in str(outcome[0])


@pytest.mark.parametrize("name", ["summary.json", "scenario.toml"])
def test_a_fifo_for_the_summary_or_the_scenario_is_not_waited_on(tmp_path, name):
    """A summary.json or scenario.toml that is a FIFO hung ``hil gcs`` in the pump's first read, before it
    printed its URL (their reader takes a FIFO: a user's ``<(…)``): a run directory holds files only. The
    summary stands as unreadable, the scenario as not drawn, each saying why."""
    d = write_run(tmp_path / "run", 5, marker=1)
    os.mkfifo(d / name)
    source = RunDirSource(d)
    batches: list[Batch] = []
    thread = threading.Thread(target=lambda: batches.extend(drain(source)), daemon=True)
    thread.start()
    thread.join(10.0)
    assert not thread.is_alive(), f"the poll waits on the FIFO {name}"
    said = json.dumps([b.info for b in batches if b.info] + [b.status for b in batches if b.status])
    assert "not a regular file" in said, said
