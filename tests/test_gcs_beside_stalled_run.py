"""A live run whose control thread hangs while the station's server stays up and a client's requests keep
being refused: the page must say the host is not ticking, never "receiving".

Before, the page (``app.js``) took any downlink message within 1 s as the run being alive, and the feed
(``LiveFeed.poll``) sent a ``status`` each pump cycle in which one of its counters changed — the refused
requests' (``uplink_rejected``) among them, which move without the run. A client sending a wrong-token
``GET /api/info`` twice a second kept a hung run's page "receiving"/"live", its frozen values unmarked and
its command buttons on, with no row arriving. Now every ``status`` carries the run's own progress (its
control ticks, ``ticks``, and the run time of the last, ``tick_t``), and the page counts as progress only
what the run makes: rows, events, link figures, a status whose ``ticks`` moved or whose state changed.

The hang is the control thread held inside the station's tick hook (as a blocked write would hold it);
everything else — the run, the tornado server, its stream, the page in chromium — is the real one.
"""

from __future__ import annotations

import http.client
import threading
import time
from typing import Any

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import ControlStall, RunInThread, StreamReader, command, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions

STALL_AT_S = 2.0  # run time at which the control thread hangs


class _Refused:
    """A client whose requests are turned away (a wrong token), one every ``period_s``, in a thread."""

    def __init__(self, station: GroundStation, period_s: float = 0.25) -> None:
        self.station, self.period_s, self.sent = station, period_s, 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            conn = http.client.HTTPConnection("127.0.0.1", self.station.port, timeout=5)
            conn.request("GET", "/api/info?token=wrong", headers={"Host": f"127.0.0.1:{self.station.port}"})
            assert conn.getresponse().status == 401
            conn.close()
            self.sent += 1
            self.stop.wait(self.period_s)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(10)


def test_a_hung_runs_stream_claims_no_progress_while_refused_requests_keep_coming(tmp_path):
    """Through the real stream: while the control thread hangs, the only messages are the statuses the
    refused requests cause, each with the same ``ticks`` — the run's last — and no rows, events or link
    figures; once it runs again its ticks move on."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        stall = ControlStall(station, STALL_AT_S)
        reader = StreamReader(station, timeout=60)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=30.0, pace=1.0), station
        )
        assert stall.started.wait(60), "the run never reached its stall"
        time.sleep(0.5)  # the rows written before the stall have gone out
        begin = time.monotonic()
        refused = _Refused(station)
        time.sleep(2.5)
        refused.close()
        end = time.monotonic()
        stall.release.set()
        assert command(station, {"command": "abort"})[0] == 202
        runner.join()
        time.sleep(0.3)
    during = reader.between(begin, end)
    assert refused.sent >= 5
    assert {name for name, _ in during} == {"status"}, during  # the refused requests' counter moved ...
    ticks = {data.get("ticks") for _, data in during}
    assert len(ticks) == 1 and None not in ticks, during  # ... and each says the run has not
    [stalled_at] = ticks
    assert stalled_at > 0 and {data["tick_t"] for _, data in during} == {during[0][1]["tick_t"]}
    assert during[0][1]["tick_t"] < STALL_AT_S
    after = [data for name, data in reader.between(end, time.monotonic()) if name == "status"]
    assert any((data.get("ticks") or 0) > stalled_at for data in after), after


# ---------------------------------------------------------------------------------------------- the page
try:
    from selenium.webdriver.common.by import By
except ImportError:  # then the browser test is skipped by its marker
    pass

STALE_CELLS = ("board-mode", "tel-age", "battery", "point-err", "attitude", "u0-rotor", "u0-angle")


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.mark.browser
def test_a_hung_runs_page_says_the_host_is_not_ticking_although_refused_requests_keep_coming(
    browser, tmp_path
):
    """In chromium: the page follows a paced live run; its control thread hangs and a client's requests are
    refused four times a second (so statuses keep coming): within 2 s the feed badge says the host is not
    ticking, the mode badge "host lost", the value cells are marked stale and the command buttons are off;
    when the run goes on, the page says "receiving" again and the buttons come back."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        stall = ControlStall(station, STALL_AT_S)
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=30.0, pace=1.0), station
        )
        wait_for(lambda: text(browser, "feed") == "receiving", 30, "the page receiving")
        hold = browser.find_element(By.CSS_SELECTOR, "button[data-command=hold]")
        assert stall.started.wait(60), "the run never reached its stall"
        refused = _Refused(station)
        try:
            messages = js(browser, "return window.gcs.stats.messages")
            badge = wait_for(
                lambda: "not ticking" in text(browser, "feed") and text(browser, "feed"), 5, "stale"
            )
            assert badge.startswith("stale: host not ticking for"), badge
            assert text(browser, "mode").startswith("host lost")
            assert hold.get_attribute("disabled") and "No word from the host" in text(browser, "uplink-off")
            wait_for(lambda: all("stale" in _classes(browser, c) for c in STALE_CELLS), 5, "the cells stale")
            time.sleep(1.0)
            assert "not ticking" in text(browser, "feed")  # still, while ...
            assert js(browser, "return window.gcs.stats.messages") > messages  # ... statuses keep coming
            assert "requests refused" in text(browser, "note")
            browser.save_screenshot(str(tmp_path / "hung.png"))
        finally:
            refused.close()
            stall.release.set()
        wait_for(lambda: text(browser, "feed") == "receiving", 10, "the page receiving again")
        wait_for(lambda: not hold.get_attribute("disabled"), 5, "the buttons back")
        assert not any("stale" in _classes(browser, c) for c in STALE_CELLS)
        assert command(station, {"command": "abort"})[0] == 202
        runner.join()
    assert not page_errors(browser)


def _classes(driver: Any, element_id: str) -> str:
    return driver.find_element(By.ID, element_id).get_attribute("class") or ""
