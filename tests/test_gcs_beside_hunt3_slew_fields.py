"""A slew commanded from the page with an angle field that holds no number: nothing is sent, the command log
says which field.

The page's uplink (``static/uplink.js``) read each angle as ``Number(input.value)``. A number field the
operator has cleared, or whose text the browser cannot read as a number (``1e``, ``-``, ``1e400``: its value
is then ``""``), gave ``Number("") == 0``: the Slew button, confirmed, sent a slew to 0° on that axis — a
well-formed command the server accepted, the run carried out, and the operator never typed. Now such a
field is no angle: the slew is not sent, the log line names the field.

Through the real pieces: a paced lockstep run with a live ground station, the page in chromium, each angle
field typed into with selenium's keys, the run's ``events.jsonl`` read for what it carried out.
"""

from __future__ import annotations

import time

import pytest
from browser_support import chromium, js, page_errors
from gcs_support import RunInThread, command, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions

pytestmark = pytest.mark.browser

try:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
except ImportError:  # then no test here runs: the marker skips them
    pass

UNREADABLE = ("", "1e", "-", "1e400", "e", "--5")  # typed into a number field: its value is "" (or ±inf)
AXES = ("roll", "pitch", "yaw")


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def _type(browser, axis: str, typed: str) -> None:
    field = browser.find_element(By.ID, f"slew-{axis}")
    field.send_keys(Keys.CONTROL, "a")
    field.send_keys(Keys.DELETE)
    if typed:
        field.send_keys(typed)


def _click_twice(browser) -> None:
    js(browser, "const b = document.querySelector('button[data-command=slew]'); b.click(); b.click();")


def _gcs_slews(runner: RunInThread) -> list[dict]:
    return [e for e in runner.events() if e["kind"] == "command" and e.get("command") == "slew"]


def test_a_slew_with_an_angle_field_that_holds_no_number_is_not_sent(browser, tmp_path):
    """For each unreadable text in each of the three fields (the other two numbers): the confirmed Slew sends
    nothing — no command in the run's events, the log's newest line "not sent" naming the field; then three
    numbers typed: the slew goes out with exactly those angles."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        options = RunOptions(out_root=tmp_path, duration_s=120.0, pace=1.0)
        runner = RunInThread(quick_scenario(), options, station)
        slew = "button[data-command=slew]"
        try:
            wait_for(lambda: browser.find_element(By.CSS_SELECTOR, slew).is_enabled(), 60, "the uplink on")
            for axis in AXES:
                for typed in UNREADABLE:
                    for other in AXES:
                        _type(browser, other, typed if other == axis else "10")
                    _click_twice(browser)
                    line = js(
                        browser, "const li = document.querySelector('#cmd-log li'); return li?.textContent"
                    )
                    assert line and "not sent" in line and f"{axis} not a number" in line, (axis, typed, line)
            time.sleep(1.0)  # a command sent would be queued and logged by the run's next tick
            assert _gcs_slews(runner) == [], _gcs_slews(runner)
            for axis, typed in zip(AXES, ("12", "-7.5", "0"), strict=True):
                _type(browser, axis, typed)
            _click_twice(browser)
            first = runner.wait_event(lambda e: e["kind"] == "command" and e.get("command") == "slew", 30,
                                      "the slew typed in full")  # fmt: skip
            assert first.get("target_euler_deg") in (None, [12, -7.5, 0]), first
            assert {e.get("id") for e in _gcs_slews(runner)} == {first["id"]}
        finally:
            command(station, {"command": "abort"})
            runner.join(120)
    assert not page_errors(browser)
