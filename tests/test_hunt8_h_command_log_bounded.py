"""The uplink panel's command log on a page left open over a long live run, in chromium.

Each click of a command added a line to ``#cmd-log`` for good (and each answered command an entry in the
uplink's map of lines): a page left open for hours grew without bound. Now the log keeps this page's
newest ``LOG_MAX`` lines (the command history table has every command of the run), newest first, and the
newest line still follows what the run says of its command.
"""

from __future__ import annotations

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import RunInThread, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions

pytestmark = pytest.mark.browser

LOG_MAX = 100  # hil/gcs/static/uplink.js
CLICKS = 3 * LOG_MAX


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def _log(browser) -> list[dict[str, str]]:
    return js(
        browser,
        """return Array.from(document.querySelectorAll('#cmd-log li'),
                                            (li) => ({status: li.dataset.status, text: li.textContent}));""",
    )


def test_the_command_log_keeps_the_newest_lines_over_many_clicks(browser, tmp_path) -> None:
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=15.0, pace=1.0), station
        )
        wait_for(lambda: text(browser, "feed") == "receiving", 60, "the page receiving")
        slew_off = "return document.querySelector('button[data-command=slew]').disabled"
        wait_for(lambda: not js(browser, slew_off), 20, "the uplink on")
        # a slew whose roll is not a number of degrees: confirmed, then logged "not sent" (no request)
        clicks = """document.getElementById('slew-roll').value = '';
                    const b = document.querySelector('button[data-command=slew]');
                    for (let k = 0; k < arguments[0]; k++) { b.click(); b.click(); }"""
        js(browser, clicks, CLICKS)
        lines = _log(browser)
        assert len(lines) == LOG_MAX, len(lines)
        assert all(line["status"] == "error" and "not sent" in line["text"] for line in lines), lines[:3]
        js(browser, "document.querySelector('button[data-command=hold]').click()")
        wait_for(lambda: _log(browser)[0]["status"] not in ("sending", "queued"), 30, "the hold's outcome")
        lines = _log(browser)
        assert len(lines) == LOG_MAX and "hold" in lines[0]["text"], lines[:2]
        runner.join()
    assert not page_errors(browser)
