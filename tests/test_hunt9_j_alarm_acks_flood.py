"""A flood of ``alarm_ack`` events that name no alarm, in chromium.

The page keeps an acknowledgement that matches no occurrence yet (``Alarms.acks``: its alarm's row may
come later) — with no limit: a run directory whose ``events.jsonl`` holds thousands of acknowledgements of
alarms that never happen (corrupt, hostile, or a client POSTing in a loop) grew the page's memory by every
one, and every later batch of events matched them all again. Now at most ``MAX_WAITING_ACKS`` wait, the
oldest dropped past it, counted and said beside the alarm count.

Through the real pieces: a real run's directory with the acknowledgements spliced into its events in time
order, ``hil gcs``'s replay station, the page in chromium.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry

pytestmark = pytest.mark.browser

FLOOD = 6000  # acknowledgements naming no alarm
WAITING_AT_MOST = 1000  # alarms.js MAX_WAITING_ACKS


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def flooded_run(tmp_path_factory) -> tuple[Path, int]:
    """A real run's directory with ``FLOOD`` acknowledgements of an alarm no limit names spliced into its
    events in time order; (the directory, the number of events)."""
    out = tmp_path_factory.mktemp("ack-flood")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=3.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    times = np.linspace(float(tel["t"][1]), float(tel["t"][-2]), FLOOD).tolist()
    path = result.run_dir / "events.jsonl"
    own = [json.loads(line) for line in path.read_text().splitlines()]
    keyed = [(e["t"], json.dumps(e)) for e in own]
    acks = [
        {"t": t, "kind": "alarm_ack", "alarm": f"no_such_alarm_{k}", "raised_t": t / 2, "origin": "gcs"}
        for k, t in enumerate(times)
    ]
    keyed += [(e["t"], json.dumps(e)) for e in acks]
    path.write_text("".join(line + "\n" for _, line in sorted(keyed, key=lambda pair: pair[0])))
    return result.run_dir, len(keyed)


def test_acknowledgements_of_no_alarm_are_bounded_and_said(browser, flooded_run):
    run_dir, count = flooded_run
    with GroundStation.replay(run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(
            lambda: js(browser, "return window.gcs.state.store.events.length") == count, 10, "the events"
        )
        waiting = js(browser, "return window.gcs.state.alarms.acks.length")
        dropped = js(browser, "return window.gcs.state.alarms.acksDropped")
        said = wait_for(lambda: "dropped" in text(browser, "alarm-count") and text(browser, "alarm-count"),
                        10, "the alarm count saying what was dropped")  # fmt: skip
    assert waiting <= WAITING_AT_MOST, waiting
    assert waiting + dropped == FLOOD, (waiting, dropped)  # every one kept or counted: none lost unsaid
    assert f"{dropped} acknowledgements naming no alarm dropped" in said, said
    assert not page_errors(browser)


PAIRS = 30000  # another phone heard, then quiet: one occurrence of the event alarm each
OCCURRENCES_AT_MOST = 20000  # alarms.js MAX_OCCURRENCES
EVENT_KEY = "phone_other:streaming"  # hil/gcs/alarms.py event_alarms


@pytest.fixture(scope="module")
def flapping_run(tmp_path_factory) -> tuple[Path, int, float]:
    """A real run's directory with ``PAIRS`` ``phone_other`` / ``phone_others_quiet`` pairs spliced into its
    events in time order, the last one left raised; (the directory, the number of events, the last one's
    time)."""
    out = tmp_path_factory.mktemp("alarm-flapping")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=3.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    times = np.linspace(float(tel["t"][1]), float(tel["t"][-2]), 2 * PAIRS).tolist()
    path = result.run_dir / "events.jsonl"
    own = [json.loads(line) for line in path.read_text().splitlines()]
    keyed = [(e["t"], json.dumps(e)) for e in own]
    for k, t in enumerate(times[:-1]):
        kind = "phone_other" if k % 2 == 0 else "phone_others_quiet"
        keyed.append((t, json.dumps({"t": t, "kind": kind, "sender": "10.0.0.9:5555", "other_phones": 1})))
    path.write_text("".join(line + "\n" for _, line in sorted(keyed, key=lambda pair: pair[0])))
    return result.run_dir, len(keyed), times[-2]


def test_a_flood_of_occurrences_is_bounded_said_and_keeps_the_newest(browser, flapping_run):
    """At most ``MAX_OCCURRENCES`` kept, the oldest cleared ones dropped and counted (kept + dropped: every
    one raised), said beside the alarm count, and the newest — raised last, still active — listed."""
    run_dir, count, last_raised = flapping_run
    with GroundStation.replay(run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(
            lambda: js(browser, "return window.gcs.state.store.events.length") == count, 20, "the events"
        )
        kept = js(browser, "return window.gcs.state.alarms.list.length")
        others = js(  # the run's own occurrences (a limit on its telemetry, raised and still active)
            browser,
            "return window.gcs.state.alarms.list.filter((o) => o.key !== arguments[0]).length",
            EVENT_KEY,
        )
        dropped = js(browser, "return window.gcs.state.alarms.occurrencesDropped")
        newest = js(browser, "const l = window.gcs.state.alarms.list; return [l[l.length - 1].raised_t, "
                             "l[l.length - 1].cleared_t]")  # fmt: skip
        said = wait_for(
            lambda: (
                "older cleared alarms dropped" in text(browser, "alarm-count")
                and text(browser, "alarm-count")
            ),
            10,
            "the alarm count saying what was dropped",
        )
    assert kept <= OCCURRENCES_AT_MOST, kept
    assert kept - others + dropped == PAIRS, (kept, others, dropped)  # every one raised: kept or counted
    assert newest[0] == pytest.approx(last_raised) and newest[1] is None, newest
    assert f"{dropped} older cleared alarms dropped by this page" in said, said
    assert not page_errors(browser)
