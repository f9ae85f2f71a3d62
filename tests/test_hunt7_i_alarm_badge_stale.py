"""The header's alarm badge when the host falls silent, in chromium. The page follows a paced live run
whose control thread then hangs (``ControlStall``, as a blocked write would hold it): the feed badge says
"stale: …", the value cells are marked stale — but the alarm badge beside them went on saying
"alarms: none active" in green (class ``live``), an alarm state as of the last row shown as live. Now it
says how old that state is ("alarms: none active, as of 2.1 s ago") and is not green; it is live again
when the run goes on."""

from __future__ import annotations

import pytest
from browser_support import chromium, js, text
from gcs_support import ControlStall, RunInThread, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def _classes(browser, element_id: str) -> list[str]:
    return js(browser, "return document.getElementById(arguments[0]).className", element_id).split()


def _aged(badge: str) -> str | None:
    """The badge's text if it says how old the alarm state is."""
    return badge if "s ago" in badge else None


def test_the_alarm_badge_is_not_live_while_the_host_is_silent(browser, tmp_path) -> None:
    with GroundStation.live(bind="127.0.0.1:0") as station:
        stall = ControlStall(station, 2.0)
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=8.0, pace=1.0), station
        )
        try:
            wait_for(lambda: text(browser, "feed") == "receiving", 30, "the page receiving")
            assert stall.started.wait(60), "the run never reached its stall"
            wait_for(
                lambda: text(browser, "feed").startswith("stale"), 5, "the page saying the feed is stale"
            )
            badge = wait_for(lambda: _aged(text(browser, "alarm-badge")), 3, "the alarm badge saying its age")
            assert badge.startswith("alarms: ") and "live" not in _classes(browser, "alarm-badge"), badge
        finally:
            stall.release.set()
        wait_for(lambda: text(browser, "feed") == "receiving", 10, "the page receiving again")
        wait_for(lambda: "ago" not in text(browser, "alarm-badge"), 5, "the alarm badge live again")
        runner.join()
