"""The page's stream dropped and came back: the history the server resends is history, never the run's
progress.

Before, every (re)connection began with ``info`` and the whole history again, and the page (``app.js``)
counted each of those messages — rows, events, link figures, statuses whose ``ticks`` differed from the
last it had — as the run making progress. A page whose stream dropped while the run's control thread hung
(or while a followed run directory had stopped growing) came back, within the 1 s the page allows, as
"receiving" / "live", its frozen value cells unmarked and its command buttons on, until the 1 s ran out.
Now the hub ends each reader's history with a ``caught_up`` message carrying how long ago the run last made
progress (``progress_age_s``); the page counts nothing before it as progress, and takes that age as the
feed's at that moment.

Through the real pieces: a paced lockstep run, the tornado server, its stream, the page in chromium; the
stream cut by the server closing every connection (as a network drop would), the page's ``EventSource``
reconnecting by itself.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import ControlStall, RunInThread, command, quick_scenario, read_stream, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions

STALL_AT_S = 2.0  # run time at which the control thread hangs


def _drop_connections(station: GroundStation) -> None:
    """Every connection of the server closed (the page's stream among them), as a network drop would."""
    server: Any = station.server
    server.loop.add_callback(server.guard.close_all)


def test_a_stream_ends_its_history_with_how_old_the_runs_progress_is(tmp_path):
    """Through the real stream of a hung run: a reader that connects gets ``info``, the history, then one
    ``caught_up`` whose ``progress_age_s`` is the time since the run's last progress (not since the
    connection); nothing but statuses after it while the run hangs."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        stall = ControlStall(station, STALL_AT_S)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=30.0, pace=1.0), station
        )
        try:
            assert stall.started.wait(60), "the run never reached its stall"
            time.sleep(2.0)
            messages = read_stream(station, 1.5)
        finally:
            stall.release.set()
        assert command(station, {"command": "abort"})[0] == 202
        runner.join()
    names = [name for name, _ in messages]
    assert names[0] == "info" and "rows" in names, names[:5]
    assert names.count("caught_up") == 1, names
    k = names.index("caught_up")
    assert "rows" in names[:k] and set(names[k + 1 :]) <= {"status"}, names[k:]
    age = messages[k][1]["progress_age_s"]
    assert 1.6 < age < 4.0, age  # the run stalled ~2 s before the reader came


# ---------------------------------------------------------------------------------------------- the page
try:
    from selenium.webdriver.common.by import By
except ImportError:  # then the browser tests are skipped by their marker
    pass

STALE_CELLS = ("board-mode", "tel-age", "battery", "point-err", "attitude", "u0-rotor", "u0-angle")

# Samples the page every 20 ms into window.samples: the feed badge, the mode badge, whether Hold is
# disabled, whether the attitude cell is marked stale, and whether the page has been told the end of a
# history since (a `caught_up`: the stream reconnected, resumed or sent afresh).
SAMPLER = """
window.samples = [];
window.historiesBefore = window.gcs.stats.histories;
window.sampler = setInterval(() => {
  window.samples.push({
    t: performance.now(),
    feed: document.getElementById("feed").textContent,
    mode: document.getElementById("mode").textContent,
    hold_off: document.querySelector("button[data-command=hold]").disabled,
    stale: document.getElementById("attitude").className.includes("stale"),
    reconnected: window.gcs.stats.histories > window.historiesBefore,
  });
}, 20);
"""


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.mark.browser
def test_a_reconnected_page_of_a_hung_run_shows_its_history_as_history(browser, tmp_path):
    """In chromium: a paced live run's control thread hangs; the page says so (stale, host lost, buttons
    off); its stream is dropped and comes back (the page gets the whole history again): from the drop
    until 2.5 s after the page has the history again, the page never says "receiving" or "live", Hold
    stays off and the attitude stays marked stale. Released, the run's new rows make it "receiving"."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        stall = ControlStall(station, STALL_AT_S)
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=30.0, pace=1.0), station
        )
        try:
            wait_for(lambda: text(browser, "feed") == "receiving", 30, "the page receiving")
            assert stall.started.wait(60), "the run never reached its stall"
            wait_for(lambda: text(browser, "feed").startswith("stale"), 5, "the page saying the host hangs")
            hold = browser.find_element(By.CSS_SELECTOR, "button[data-command=hold]")
            assert hold.get_attribute("disabled")
            rows = js(browser, "return window.gcs.state.store.n")
            js(browser, SAMPLER)
            _drop_connections(station)
            wait_for(
                lambda: js(browser, "return window.samples.some((s) => s.reconnected)"), 10, "a reconnection"
            )
            time.sleep(2.5)
            samples = js(browser, "clearInterval(window.sampler); return window.samples")
            assert js(browser, "return window.gcs.state.store.n") == rows  # every row, none twice
            browser.save_screenshot(str(tmp_path / "reconnected.png"))
        finally:
            stall.release.set()
        after = [s for s in samples if s["reconnected"]]
        assert len(after) > 50, len(after)
        live = [s for s in samples if s["feed"] == "receiving" or s["mode"].startswith("live")]
        assert not live, live[:3]
        assert all(s["hold_off"] for s in samples), [s for s in samples if not s["hold_off"]][:3]
        assert all(s["stale"] for s in after), [s for s in after if not s["stale"]][:3]
        assert after[-1]["feed"].startswith("stale"), after[-1]
        wait_for(lambda: text(browser, "feed") == "receiving", 10, "the page receiving once the run goes on")
        wait_for(lambda: not hold.get_attribute("disabled"), 5, "the buttons back")
        assert not any("stale" in _classes(browser, c) for c in STALE_CELLS)
        assert command(station, {"command": "abort"})[0] == 202
        runner.join()
    assert not page_errors(browser)


@pytest.mark.browser
def test_a_reconnected_page_of_a_running_run_takes_up_where_it_left_off(browser, tmp_path):
    """In chromium: the stream of a run that goes on is dropped (after 6 s of rows); the page's
    ``EventSource`` reconnects with the last id it had, and the stream takes up there: no ``info`` and no
    history resent (the page's run description is the one it had; the server sends a fraction of what it
    had sent), the rows it missed and then the new ones — every row the run wrote, none twice —, the page
    "receiving" with its buttons on. Before, each reconnection resent the whole history (up to 64 MiB) and
    the page rebuilt its store from it."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=30.0, pace=1.0), station
        )
        wait_for(lambda: text(browser, "feed") == "receiving", 30, "the page receiving")
        time.sleep(6.0)
        js(browser, "window.gcs.state.info.__before_drop = true;" + SAMPLER)
        sent = station.hub.stats.bytes_sent
        _drop_connections(station)
        wait_for(
            lambda: js(browser, "return window.samples.some((s) => s.reconnected)"), 10, "a reconnection"
        )
        resent = station.hub.stats.bytes_sent - sent
        wait_for(lambda: text(browser, "feed") == "receiving", 5, "the page receiving again")
        hold = browser.find_element(By.CSS_SELECTOR, "button[data-command=hold]")
        wait_for(lambda: not hold.get_attribute("disabled"), 5, "the buttons back")
        js(browser, "clearInterval(window.sampler)")
        assert js(browser, "return window.gcs.state.info.__before_drop") is True  # no info sent again
        assert station.hub.stats.streams_resumed == 1
        assert resent < sent / 2, (resent, sent)  # the rows of the ~1 s away; before: all and more
        assert command(station, {"command": "abort"})[0] == 202
        result = runner.join()
        time.sleep(0.5)
        written = sum(1 for _ in open(result.run_dir / "telemetry.csv")) - 1
        assert js(browser, "return window.gcs.state.store.seen") == written
        assert js(browser, "return window.gcs.state.store.n") == written
    assert not page_errors(browser)


def _classes(driver: Any, element_id: str) -> str:
    return driver.find_element(By.ID, element_id).get_attribute("class") or ""
