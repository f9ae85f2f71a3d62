"""A followed run directory whose writer is killed while rows are held: the page shows what was written and
says the run stopped being written.

Before, ``hil gcs`` following a run that another process writes held, for as long as it followed, what it
could not judge yet: the rows after a jump ahead (:class:`~hil.runtime.runlog.RowOrder` holds up to 32 until
they show whether the run went on from it) and a last line without its end. A writer killed then never
wrote the rows that would have let them go, nor a summary: the page stayed "following" (then "stale: run not
growing"), the held rows never drawn, the torn line never counted — the same as a run merely stalled. Now a
run holds an exclusive lock on its directory from its making to its summary (:mod:`hil.files.writing`, the
kernel lets go when the process dies); the reader, once it has read everything, asks whether the lock is
held: held, the run is stalled and the rows stay held; let go without a summary, the writer is gone — the
rows held are judged on what came and drawn, the torn line counted, the status ``stopped`` with why, the
page "stopped being written", greyed. A directory whose writer takes no lock is taken as stopped after
``QUIET_S`` without growth, and followed again if it grows.

Through the real pieces: ``hil run`` in its own process (paced lockstep), stopped with SIGSTOP, lines
appended to its ``telemetry.csv`` as it could have left them (rows after a stall, a line cut short), then
killed with SIGKILL; ``hil gcs``'s station on its directory, its stream, the page in chromium.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import StreamReader, wait_for

import hil.gcs.rundir as rundir
from hil.gcs import GroundStation, RunDirSource

JUMP_S = 3.0  # the appended rows start this far after the run's last: a stall (held until judged)
HELD = 5  # rows appended after the stall (fewer than the look-ahead: all held)


class _Writer:
    """``hil run`` in its own process, writing a run directory under ``out``."""

    def __init__(self, out: Path) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hil", "run", "--pace", "1", "--duration", "120", "--no-plots",
             "--out", str(out)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip

        def ready() -> Path | None:
            if self.proc.poll() is not None:
                raise RuntimeError("hil run ended early")
            found = sorted(out.glob("*/telemetry.csv"))
            return found[0].parent if found and found[0].read_bytes().count(b"\n") > 50 else None

        self.run_dir: Path = wait_for(ready, 120, "a run writing its telemetry")

    def stop_and_leave(self) -> tuple[float, float]:
        """SIGSTOP, then the lines a run stalled ``JUMP_S`` and killed could leave: ``HELD`` whole rows
        after the stall and one cut short. The first and last appended rows' times."""
        os.kill(self.proc.pid, signal.SIGSTOP)
        time.sleep(0.3)
        path = self.run_dir / "telemetry.csv"
        last = path.read_bytes().rstrip(b"\n").rsplit(b"\n", 1)[1].decode().split(",")
        t0, step = float(last[0]) + JUMP_S, 0.01
        rows = [",".join([f"{t0 + k * step:.4f}", *last[1:]]) for k in range(HELD)]
        torn = ",".join([f"{t0 + HELD * step:.4f}", *last[1:]])[:-7]
        with open(path, "a") as f:
            f.write("\n".join(rows) + "\n" + torn)
        return t0, t0 + (HELD - 1) * step

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)


def _last_t(reader: StreamReader) -> float:
    """The time of the last row the stream has sent (s), -1 before any."""
    rows = (row[0] for name, d in reader.events() if name == "rows" for row in d["rows"])
    return max(rows, default=-1)


def _status(reader: StreamReader) -> dict[str, Any]:
    """The stream's last status ({} before any)."""
    return next((d for name, d in reversed(reader.events()) if name == "status"), {})


def test_a_killed_writers_held_rows_are_shown_and_the_run_said_stopped(tmp_path, monkeypatch):
    """Through ``hil gcs``'s stream: while ``hil run`` is stopped (SIGSTOP: a stalled run, its lock held)
    the rows after its stall stay held and the status stays ``following``, for longer than ``QUIET_S``;
    killed, within seconds the held rows come (the last whole one's time), the status is ``stopped`` saying
    the writer is gone, and the line cut short is counted as unreadable."""
    monkeypatch.setattr(rundir, "QUIET_S", 1.0, raising=False)  # (the tree before had none)
    writer = _Writer(tmp_path)
    try:
        with GroundStation.replay(writer.run_dir, bind="127.0.0.1:0") as station:
            reader = StreamReader(station)
            wait_for(lambda: _status(reader).get("state") == "following", 10, "the run followed")
            first, last = writer.stop_and_leave()
            time.sleep(3.0)  # stalled, its lock held: longer than QUIET_S, nothing given out
            assert _last_t(reader) < first and _status(reader)["state"] == "following", _status(reader)
            writer.kill()
            wait_for(lambda: _status(reader).get("state") == "stopped", 5, "the run said stopped")
            wait_for(lambda: abs(_last_t(reader) - last) < 1e-6, 5, "the held rows")
            status = _status(reader)
            assert "writer is gone" in status["stopped"] and status["exit"] is None, status
            assert status["bad_rows"] == 1, status  # the line cut short
            assert station.stats()["run_dir"]["stopped"] is True
    finally:
        writer.kill()


def test_a_directory_whose_writer_takes_no_lock_is_stopped_after_a_quiet_and_followed_again(tmp_path):
    """A directory written by a program that holds no lock (the test itself): after ``QUIET_S`` without
    growth the rows held are given out and the status is ``stopped`` with the torn line counted; the line
    completed and more written, it is ``following`` again and the run goes on."""
    now = [0.0]
    d = tmp_path / "run"
    d.mkdir()
    header = "t,x\n"
    rows = "".join(f"{k * 0.01:.2f},{k}\n" for k in range(50))
    held = "".join(f"{5 + k * 0.01:.2f},{k}\n" for k in range(3))
    (d / "telemetry.csv").write_text(header + rows + held + "5.03,")
    (d / "events.jsonl").write_text("")
    source = RunDirSource(d, clock=lambda: now[0])
    taken = [row[0] for row in source.poll().rows]
    for _ in range(3):
        taken += [row[0] for row in source.poll().rows]
    assert len(taken) == 50 and source.status["state"] == "following"
    now[0] += rundir.QUIET_S + 0.1
    batch = source.poll()
    assert [row[0] for row in batch.rows] == [5.0, 5.01, 5.02]
    assert batch.status["state"] == "stopped" and batch.status["bad_rows"] == 1, batch.status
    assert "no writer holds the run's lock" in batch.status["stopped"]
    with open(d / "telemetry.csv", "a") as f:
        f.write("3\n5.04,4\n")
    now[0] += 0.1
    rows_after = [row[0] for b in (source.poll(), source.poll()) for row in b.rows]
    assert rows_after == [5.03, 5.04]
    assert source.status["state"] == "following" and source.status["bad_rows"] == 0, source.status


# ---------------------------------------------------------------------------------------------- the page
@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.mark.browser
def test_the_page_shows_a_killed_writers_rows_and_says_the_run_stopped_being_written(browser, tmp_path):
    """In chromium, on ``hil gcs``'s page: "following" while ``hil run`` writes; killed with rows held and a
    line cut short, the page draws the held rows (its last row the last whole one written), its feed badge
    says "stopped being written" (stale: the page greyed), its note says why and counts the torn line."""
    writer = _Writer(tmp_path)
    try:
        with GroundStation.replay(writer.run_dir, bind="127.0.0.1:0") as station:
            browser.get(station.url)
            wait_for(lambda: text(browser, "feed") == "following", 20, "the page following")
            first, last = writer.stop_and_leave()
            writer.kill()
            wait_for(lambda: text(browser, "feed") == "stopped being written", 10, "the page saying stopped")
            wait_for(lambda: abs(js(browser, "return window.gcs.state.store.tLast") - last) < 1e-6, 5, "rows")
            assert "feed-stale" in (browser.find_element("tag name", "body").get_attribute("class") or "")
            note = text(browser, "note")
            assert "the run stopped being written" in note and "1 unreadable rows" in note, note
            browser.save_screenshot(str(tmp_path / "stopped.png"))
    finally:
        writer.kill()
    assert not page_errors(browser)
