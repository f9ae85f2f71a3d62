"""The ground station's operator tools in a real browser (headless chromium, tests/browser_support.py):
alarms raised, cleared and acknowledged as a lockstep run crosses a limit; commands and events marked on
the plots; the command history and a plot exported; keyboard scrubbing; light and dark; runs compared.

Each run here is lockstep (the simulated clock does not depend on the machine's load); every wait is on a
condition, with a generous deadline for a loaded 2-CPU machine.
"""

from __future__ import annotations

import numpy as np
import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import RunInThread, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions
from hil.runtime.runlog import read_events, read_telemetry

pytestmark = pytest.mark.browser  # without chromium, chromedriver or selenium: skipped (tests/conftest.py)

try:
    from selenium.webdriver.common.by import By
except ImportError:  # then no test here runs: the marker skips them, with the one line for them all
    pass


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


POINTING = "point_err_deg:high"


def test_an_alarm_is_raised_and_cleared_as_a_run_crosses_a_limit_and_acknowledged_from_the_page(
    browser, tmp_path
):
    """A pointing requirement of 15° (the scenario's ``settle_deg``): the 30° slew's pointing error is above
    it from the start and falls below it during the slew. The page lists the alarm (warning, raised at the
    first row past the limit), colours the pointing-error cell, sends the operator's acknowledgement (logged
    in events.jsonl with the occurrence's raised time), and marks the alarm cleared at the first row back
    inside the limit's hysteresis band — and raises no other."""
    sc = quick_scenario().with_changes(settle_deg=15.0)
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(sc, RunOptions(out_root=tmp_path, duration_s=5.0, pace=1.0), station)
        selector = f'#alarms tr[data-key="{POINTING}"]'
        wait_for(lambda: browser.find_elements(By.CSS_SELECTOR, selector), 60, "the pointing alarm listed")
        row = browser.find_element(By.CSS_SELECTOR, selector)
        assert "active" in row.get_attribute("class") and "warning" in row.get_attribute("class")
        assert text(browser, "alarm-badge") == "alarms: 1 active"
        wait_for(lambda: "alarm-warning" in (browser.find_element(By.ID, "point-err").get_attribute("class")),
                 10, "the pointing error cell coloured")  # fmt: skip
        raised = float(row.get_attribute("data-raised"))
        browser.save_screenshot(str(tmp_path / "alarm-raised.png"))
        js(browser, "document.querySelector(arguments[0] + ' button').click()", selector)
        ack = runner.wait_event(lambda e: e["kind"] == "alarm_ack", what="the acknowledgement logged")
        assert ack["alarm"] == POINTING and ack["origin"] == "gcs" and ack["remote"] == "127.0.0.1"
        assert ack["raised_t"] == pytest.approx(raised, abs=1e-6)
        wait_for(lambda: "✓" in browser.find_element(By.CSS_SELECTOR, f"{selector} td.ack").text, 20,
                 "the page to show the acknowledgement")  # fmt: skip
        wait_for(lambda: "cleared" in browser.find_element(By.CSS_SELECTOR, selector).get_attribute("class"),
                 60, "the alarm cleared")  # fmt: skip
        cleared = float(browser.find_element(By.CSS_SELECTOR, f"{selector} td.cleared").text)
        assert text(browser, "alarm-badge") == "alarms: none active"
        assert "alarm-warning" not in browser.find_element(By.ID, "point-err").get_attribute("class")
        browser.save_screenshot(str(tmp_path / "alarm-cleared.png"))
        result = runner.join()
        assert len(browser.find_elements(By.CSS_SELECTOR, "#alarms tbody tr[data-key]")) == 1
        limits = browser.find_element(By.ID, "plot-pointing").get_attribute("data-limits")
        assert "pointing error max=15" in limits  # the limit drawn on its plot
    assert not page_errors(browser)
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    t, err = tel["t"], tel["point_err_deg"]
    first_out = int(np.nonzero(err > 15.0)[0][0])
    assert raised == pytest.approx(t[first_out], abs=1e-6)
    back = int(np.nonzero((t > raised) & (err <= 15.0 * 0.95))[0][0])
    assert cleared == pytest.approx(t[back], abs=0.006)  # the page shows two decimals
    assert np.all(err[back:] <= 15.0)  # and it stayed inside: one occurrence
    events = read_events(result.run_dir / "events.jsonl")[0]
    assert [e["alarm"] for e in events if e["kind"] == "alarm_ack"] == [POINTING]
