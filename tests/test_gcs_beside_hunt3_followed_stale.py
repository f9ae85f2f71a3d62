"""A run directory followed while another process writes it (``hil gcs RUN_DIR``), whose writer stops: the
newest row's values are marked stale with their age, as a live run's are, never shown live.

Before, the page (``app.js``) gave the feed's age to the cells only on a live station (``info.mode ==
"live"``): following a run whose writer hung (a stalled ``hil run``) or died, the header said "stale: run not
growing for N s" (later "stopped being written") while the board state said ARMED in green, the battery, the
units, the phase and the attitude unmarked — the last row's values shown as live, for as long as the page
stayed open. Now the feed's age applies wherever the newest row is what the run made last: a live run, a
followed directory ``following`` or ``stopped``; the cells come back live when the directory grows again.

The verdict itself (the status turning ``stopped``) is no progress of the run: counted as progress, it made
the newest row's age start again from 0 — the page's cells flicked back to live for a moment, and a page
(re)connecting afterwards was told (``caught_up``'s ``progress_age_s``) that the run last progressed at the
verdict, not at its last row.

Through the real pieces: a real run's telemetry, written into a directory line by line by the test (a
writer that takes no lock, as another program's), ``hil gcs``'s station following it, the page in chromium;
the row at which the writer stops is drawn across the run's phases (warm-up, slew, hold).
"""

from __future__ import annotations

import shutil
import threading
import time
from pathlib import Path

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import StreamReader, quick_scenario, wait_for

import hil.gcs.rundir as rundir
from hil.gcs import GroundStation
from hil.runtime import RunOptions, run

CELLS = ("board-state", "battery", "ubec", "phase", "watchdog", "faults", "u0-rotor", "attitude", "point-err")
QUIET_S = 3.0  # the directory is taken as stopped after this long without growth (rundir.QUIET_S, shortened)


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def source_run(tmp_path_factory) -> Path:
    """A finished real run (lockstep, 6 s: warm-up, slew, hold) whose files the tests write again."""
    out = tmp_path_factory.mktemp("followed-stale-source")
    return run(quick_scenario(), RunOptions(out_root=out, duration_s=6.0)).run_dir


class _Writer:
    """Writes ``source``'s telemetry into ``target`` a few rows every 50 ms (as a run flushes it) until
    :meth:`stop`, or until ``stop_row``; :meth:`resume` writes on from where it stopped."""

    def __init__(self, source: Path, target: Path, stop_row: int) -> None:
        target.mkdir()
        shutil.copy(source / "scenario.toml", target)
        (target / "events.jsonl").write_text("")
        self.lines = (source / "telemetry.csv").read_text().splitlines(keepends=True)
        self.path = target / "telemetry.csv"
        self.path.write_text("".join(self.lines[:20]))
        self.k = 20
        self.stop_row = stop_row
        self.thread = threading.Thread(target=self._write, daemon=True)
        self.thread.start()

    def _write(self) -> None:
        while self.k < min(self.stop_row, len(self.lines)):
            end = min(self.k + 3, self.stop_row)
            with open(self.path, "a") as f:
                f.write("".join(self.lines[self.k : end]))
            self.k = end
            time.sleep(0.05)

    def resume(self, rows: int) -> None:
        self.thread.join()
        self.stop_row = self.k + rows
        self.thread = threading.Thread(target=self._write, daemon=True)
        self.thread.start()


def _cells(browser) -> dict[str, tuple[bool, str]]:
    """Each cell's (stale, the age it says)."""
    return js(
        browser,
        """const out = {};
           for (const id of arguments[0]) {
             const el = document.getElementById(id);
             out[id] = [el.classList.contains('stale'), el.dataset.age || ''];
           }
           return out;""",
        list(CELLS),
    )


@pytest.mark.browser
@pytest.mark.parametrize("stop_at", [0.12, 0.5, 0.9], ids=["warmup", "slew", "hold"])
def test_a_followed_runs_newest_values_turn_stale_when_its_writer_stops(
    browser, source_run, tmp_path, monkeypatch, stop_at
):
    """Following: the cells live. The writer stops at a drawn row: within seconds the header says stale
    and every board, unit and attitude cell is marked stale with its age ("N s old"), also once the run
    is ``stopped being written``; it writes again: the cells are live again."""
    monkeypatch.setattr(rundir, "QUIET_S", QUIET_S)
    rows = len((source_run / "telemetry.csv").read_text().splitlines())
    writer = _Writer(source_run, tmp_path / "run", stop_row=int(rows * stop_at))
    with GroundStation.replay(tmp_path / "run", bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: text(browser, "feed") == "following", 20, "the page following")
        assert not any(stale for stale, _ in _cells(browser).values()), _cells(browser)
        writer.thread.join(60)
        wait_for(lambda: text(browser, "feed").startswith("stale: "), 10, "the header saying stale")
        time.sleep(0.6)  # an age past the page's redraw of the stale cells (every 0.25 s)
        cells = _cells(browser)
        for cell, (stale, age) in cells.items():
            assert stale and age.endswith(" s old"), (cell, stale, age, text(browser, "feed"))
        assert js(browser, "return document.getElementById('view3d').dataset.stale").startswith("stale: ")
        wait_for(lambda: text(browser, "feed") == "stopped being written", 10, "the run said stopped")
        time.sleep(0.3)
        cells = _cells(browser)
        for cell, (stale, age) in cells.items():
            assert stale and age.endswith(" s old"), (cell, stale, age, "stopped")
        writer.resume(40)
        wait_for(lambda: text(browser, "feed") == "following", 10, "the page following again")
        wait_for(lambda: not any(stale for stale, _ in _cells(browser).values()), 5, "the cells live again")
    assert not page_errors(browser)


def test_a_stream_opened_after_the_verdict_is_told_the_age_of_the_last_row_not_of_the_verdict(
    source_run, tmp_path, monkeypatch
):
    """The writer stops; ``QUIET_S`` later the status says ``stopped``; a stream opened a while after is
    told (``caught_up``) that the run last made progress when its last rows came, not at the verdict."""
    monkeypatch.setattr(rundir, "QUIET_S", 1.0)
    writer = _Writer(source_run, tmp_path / "run", stop_row=60)
    with GroundStation.replay(tmp_path / "run", bind="127.0.0.1:0") as station:
        writer.thread.join(60)
        last_rows_at = time.monotonic()
        wait_for(lambda: station.stats()["run_dir"]["stopped"], 10, "the run said stopped")
        time.sleep(1.0)
        reader = StreamReader(station, 30)
        try:
            caught = wait_for(
                lambda: next((d for name, d in reader.events() if name == "caught_up"), None), 10, "caught_up"
            )
        finally:
            reader.close()
        opened_after = time.monotonic() - last_rows_at
        # the stream was opened ~QUIET_S + 1 s after the last rows; the verdict came ~1 s before it
        assert caught["progress_age_s"] >= opened_after - 0.5, (caught, opened_after)
