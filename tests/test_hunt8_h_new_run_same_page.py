"""A page that outlives its station and is served another run, in chromium.

A station dies without saying goodbye (``hil gcs`` killed: no ``bye``), and a station at the same address
with the same token (``GroundStation(token=...)``, ``--bind``) serves another run: the page's
``EventSource`` reconnects and gets the new run's ``info``. The page merged each status into the one
before and never reset it, so the old run's ending (its ``exit``, its ``summary``: the badge, the note, the
board's state "at the run's end") stayed — the new run, still being written, read as the old one had
ended. Now a new run starts from an empty status; the same run described again (a reconnection) keeps its.
The events table was keyed by its counts alone: a new run with as many events kept the old run's rows.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from browser_support import chromium, js, page_errors, text
from fault_support import short_scenario
from gcs_support import wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run

pytestmark = pytest.mark.browser

OLD_EXIT = "lost: the board (no telemetry for 0.5 s)"
TOKEN = "hunt8-h-same-token"

STATION = """
import sys, time
from hil.gcs import GroundStation
station = GroundStation.replay(sys.argv[1], bind=sys.argv[2], token=sys.argv[3])
print(station.url, flush=True)
time.sleep(600)
"""


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path]:
    """An old run whose summary says it was lost, and a new run still being written (no summary yet)."""
    out = tmp_path_factory.mktemp("runs")
    result = run(short_scenario(), RunOptions(out_root=out / "made"))
    assert result.run_dir is not None
    old = out / "old" / "run-old"
    shutil.copytree(result.run_dir, old)
    summary = json.loads((old / "summary.json").read_text())
    summary["exit"] = OLD_EXIT
    summary["final_disarm"] = {"ok": True, "state": "OLD_RUN_STATE"}
    (old / "summary.json").write_text(json.dumps(summary))
    new = out / "new" / "run-new"
    shutil.copytree(result.run_dir, new)
    (new / "summary.json").unlink()
    return old, new


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def _served_after(browser, old: Path, new: Path) -> Iterator[GroundStation]:
    """``old`` served by a station in another process, seen by ``browser`` to its end; that process
    killed (no goodbye) and ``new`` served at the same address with the same token, seen by the page."""
    port = _free_port()
    bind = f"127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    proc = subprocess.Popen(
        [sys.executable, "-c", STATION, str(old), bind, TOKEN], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        url = proc.stdout.readline().strip()  # type: ignore[union-attr]
        assert url.endswith(f"?token={TOKEN}"), url
        browser.get(url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the old run")
        wait_for(lambda: "lost" in text(browser, "feed"), 10, "the old run's ending said")
        assert "OLD_RUN_STATE" in browser.page_source
    finally:
        proc.kill()  # gone without a goodbye: the page reconnects
        proc.wait(10)
    with GroundStation.replay(new, bind=bind, token=TOKEN) as station:
        wait_for(lambda: js(browser, "return window.gcs.state.info.run") == new.name, 30, "the new run")
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "following", 10, "following")
        wait_for(lambda: js(browser, "return window.gcs.state.store.n") > 0, 10, "its rows")
        yield station


def test_a_new_run_on_the_same_page_does_not_show_the_old_runs_ending(browser, runs) -> None:
    old, new = runs
    with _served_after(browser, old, new) as station:
        status = js(browser, "return window.gcs.state.status")
        assert "exit" not in status and "summary" not in status, status
        assert "lost" not in text(browser, "note"), text(browser, "note")
        assert "lost" not in text(browser, "feed"), text(browser, "feed")
        assert "OLD_RUN_STATE" not in browser.page_source
        assert station.stats()["run_dir"]["state"] == "following"
    assert not page_errors(browser)


def test_a_new_run_with_as_many_events_shows_its_own(browser, runs, tmp_path) -> None:
    old, new = runs
    marked = tmp_path / "run-marked"
    shutil.copytree(new, marked)
    events = [json.loads(line) for line in (marked / "events.jsonl").read_text().splitlines()]
    marks = "".join(json.dumps({**e, "which": "NEW_RUN"}) + "\n" for e in events)
    (marked / "events.jsonl").write_text(marks)
    with _served_after(browser, old, marked):
        n_events = lambda: js(browser, "return window.gcs.state.store.events.length")  # noqa: E731
        wait_for(lambda: n_events() == len(events), 10, "its events")
        shown = lambda: js(browser, "return document.querySelector('#events tbody').textContent")  # noqa: E731
        wait_for(lambda: "NEW_RUN" in shown(), 10, "the new run's events in the table")
        assert "(" in text(browser, "event-count")
    assert not page_errors(browser)
