"""A run directory's event whose ``t`` parses but is no time — a number written as a string ("1e9",
"Infinity"), an array ([1e9]) — in the ground station's page (chromium, ``hil gcs``'s replay station).

The page places such an event with the one before it (store.js, ``pushEvents``), but its walks over the
events stop at the first one later than the cursor with ``e.t > t`` — which JavaScript's comparison makes
true of "1e9" and [1e9]: one such record early in a run hid every later command from the command history
(and from the target the page draws), every later phone record. Now the store gives such an event the
time it is placed at (its own ``t`` kept as "t (as sent)", shown in the table), so every walk sees it where
it is."""

from __future__ import annotations

import json

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry

pytestmark = pytest.mark.browser

NOT_TIMES = ["1e9", "Infinity", [1e9], "12"]


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def test_events_whose_time_is_no_number_hide_nothing_after_them(browser, tmp_path_factory) -> None:
    out = tmp_path_factory.mktemp("untimed-events")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=2.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    t0, t_end = float(tel["t"][2]), float(tel["t"][-1])
    path = result.run_dir / "events.jsonl"
    own = [json.loads(line) for line in path.read_text().splitlines()]
    early = [e for e in own if e["t"] <= t0]
    late = [e for e in own if e["t"] > t0]
    spliced = []
    for k, bad in enumerate(NOT_TIMES):
        spliced.append({"t": bad, "kind": "command", "id": 400 + k, "origin": "script", "command": "hold",
                        "status": "sent"})  # fmt: skip
        spliced.append({"t": t0 + 0.01 * (k + 1), "kind": "command", "id": 300 + k, "origin": "script",
                        "command": "hold", "status": "applied"})  # fmt: skip
    records = [*early, *spliced, *late]
    path.write_text("".join(json.dumps(e) + "\n" for e in records))
    with GroundStation.replay(result.run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(lambda: js(browser, "return window.gcs.state.store.events.length") == len(records), 10,
                 "the events")  # fmt: skip
        js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                       s.dispatchEvent(new Event('input'));""", t_end)  # fmt: skip
        wait_for(lambda: "(" in text(browser, "cmd-history-count"), 10, "the command history")
        ids = js(
            browser, "return [...document.querySelectorAll('#cmd-history tbody tr')].map((r) => r.dataset.id)"
        )
        cursor = js(browser, "return window.gcs.state.cursor")
        count = text(browser, "event-count")
        table = text(browser, "events")
        assert not page_errors(browser)
    assert {str(300 + k) for k in range(len(NOT_TIMES))} <= set(ids), ids
    shown_events = sum(1 for e in records if not isinstance(e["t"], float) or e["t"] <= cursor)
    assert count.startswith(f"({shown_events} of {len(records)}"), (count, shown_events)
    assert "t (as sent): 1e9" in table, table
