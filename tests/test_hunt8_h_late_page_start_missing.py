"""A page opened late on a long run, whose start the station's history no longer holds, in chromium.

The hub keeps the downlink's history up to a byte budget (64 MiB: some twenty minutes of a live run's
rows); past it the oldest chunks go. A page that connected after that got ``info`` and the history from
the middle of the run, and drew it as if that were the run's start: its timeline began there, the run's
first events, commands and alarms were missing, and nothing said so (only a page already open that fell
behind was told, ``skipped``). Now the hub tells a reader given the history how many of the run's first
chunks are gone (``skipped`` with ``history``, right after ``info``), and the page's note says the run's
start is missing and from where it has rows.

A real lockstep run through a live station whose budget is small (the same trimming, sooner); the page
opened once the run has ended.
"""

from __future__ import annotations

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import RunInThread, StreamReader, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.gcs.live import LiveFeed
from hil.runtime import RunOptions

pytestmark = pytest.mark.browser

BUDGET = 60_000  # bytes of history: a few seconds of this run's rows


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def test_a_late_page_says_the_runs_start_is_missing(browser, tmp_path) -> None:
    with GroundStation(LiveFeed(), bind="127.0.0.1:0", budget=BUDGET) as station:
        runner = RunInThread(quick_scenario(), RunOptions(out_root=tmp_path, duration_s=8.0), station)
        runner.join()
        wait_for(lambda: station.hub.stats.trimmed_chunks > 0, 10, "the history trimmed")  # the premise
        reader = StreamReader(station, timeout=30)
        try:
            messages = wait_for(lambda: (m := reader.events()) and len(m) >= 2 and m, 10, "the stream")
        finally:
            reader.close()
        assert messages[0][0] == "info", messages[:2]
        assert messages[1][0] == "skipped" and messages[1][1].get("history") is True, messages[1]
        assert messages[1][1]["chunks"] > 0, messages[1]
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "ended", 30, "the run's end")
        wait_for(lambda: js(browser, "return window.gcs.state.store.n") > 0, 10, "its rows")
        first_row_t = js(browser, "return window.gcs.state.store.tFirst")
        assert first_row_t > 0.5, first_row_t  # the premise: the page has the run from its middle
        wait_for(lambda: "start is missing" in text(browser, "note"), 10, "the missing start said")
        note = text(browser, "note")
        assert f"rows before t {first_row_t:.2f} s" in note, note
        assert "fell behind" not in note, note  # this page did not fall behind: it came late
    assert not page_errors(browser)
