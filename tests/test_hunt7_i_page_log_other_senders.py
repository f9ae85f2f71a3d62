"""The uplink panel's command log in chromium, on a run where another sender commands too: a scripted
operator (``hil.runtime.operator.ScheduledOperator``, origin ``campaign``: a fault campaign's drawn commands,
a test's script) beside the page. Each sender numbers its own commands from 1, so the run's events hold a
``campaign`` command 1 and the page's (``gcs``) command 1. The page's log line for *its* command followed
every ``command`` event with that id, whoever sent it: the page's Hold, refused by the host, then showed
"#1 arm … acked" — another sender's command and status on the operator's own line. Now the line follows
only the ground station's own records (origin ``gcs``); the command history (every sender) is unchanged."""

from __future__ import annotations

import pytest
from browser_support import chromium, js, text
from gcs_support import RunInThread, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions
from hil.runtime.observer import Observers
from hil.runtime.operator import OperatorCommand, ScheduledOperator

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def _log(browser) -> list[dict[str, str]]:
    return js(
        browser,
        """return [...document.querySelectorAll('#cmd-log li')].map((li) =>
             ({id: li.dataset.id || '', status: li.dataset.status, text: li.textContent}));""",
    )


def test_the_pages_log_line_follows_its_own_command_not_anothers_with_the_same_id(browser, tmp_path) -> None:
    campaign_at = 3.0  # s: after the page's command (an Arm of the armed board: acked, the run goes on)
    schedule = [(campaign_at, OperatorCommand(1, "arm", origin="campaign"))]
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        options = RunOptions(out_root=tmp_path, duration_s=4.0, pace=1.0)
        options.observer = Observers(station.observer, ScheduledOperator(schedule))
        runner = RunInThread(quick_scenario(), options)
        wait_for(lambda: text(browser, "feed") == "receiving", 30, "the page receiving")
        assert not [e for e in runner.events() if e.get("origin") == "campaign"], "the page came too late"
        js(browser, "document.querySelector('button[data-command=hold]').click()")
        mine = runner.wait_event(
            lambda e: e.get("origin") == "gcs" and e.get("status") in ("applied", "refused"),
            what="the page's hold carried out",
        )
        assert mine["id"] == 1 and mine["command"] == "hold"
        runner.wait_event(lambda e: e.get("origin") == "campaign" and e.get("status") == "acked",
                          what="the campaign's arm acked")  # fmt: skip
        wait_for(lambda: any(li["id"] == "1" and li["status"] == mine["status"] for li in _log(browser)), 10,
                 "the page's line saying its hold's status")  # fmt: skip
        runner.join()
        # every event has reached the page by now: its line must still be its own command's
        wait_for(lambda: text(browser, "feed").startswith("ended"), 20, "the page saying the run ended")
        (line,) = [li for li in _log(browser) if li["id"] == "1"]
        assert line["status"] == mine["status"] and line["text"].startswith("#1 hold"), line
