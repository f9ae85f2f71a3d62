"""A run that floods events, in the ground station's page (chromium, ``hil gcs``'s replay station): the page
keeps at most ``MAX_EVENTS`` of them (hil/gcs/static/store.js) — the oldest dropped, counted and said in the
page's note and the events table's count, never silently — and the target an applied slew among the dropped
ones set is still the page's target. Before, ``store.events`` grew with every event the run logged (a phone
on the port logged per message, a script's refused requests, a hostile ``events.jsonl``): the page's memory
without bound."""

from __future__ import annotations

import json

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry

pytestmark = pytest.mark.browser

FLOOD = 240_000  # events appended: more than the page keeps (MAX_EVENTS)


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def test_a_flood_of_events_is_bounded_and_said_on_the_page(browser, tmp_path_factory) -> None:
    out = tmp_path_factory.mktemp("event-flood")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=2.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    t0, t1 = float(tel["t"][1]), float(tel["t"][-1])
    path = result.run_dir / "events.jsonl"
    own = [json.loads(line) for line in path.read_text().splitlines()]
    target = [0.1, -0.2, 0.3]
    slew = {"t": t0, "kind": "command", "id": 7, "origin": "gcs", "command": "slew", "status": "applied",
            "target_r": target}  # fmt: skip
    flood = [{"t": t0 + (t1 - t0) * k / FLOOD, "kind": "phone_other", "k": k} for k in range(FLOOD)]
    records = sorted([*own, slew, *flood], key=lambda e: e["t"])
    path.write_text("".join(json.dumps(e) + "\n" for e in records))
    with GroundStation.replay(result.run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 60, "the replay")
        held = js(browser, "return import('/static/store.js').then((m) => m.MAX_EVENTS)") or 200_000
        kept = js(browser, "return window.gcs.state.store.events.length")
        dropped = js(browser, "return window.gcs.state.store.eventsDropped")
        assert kept <= held < len(records), (kept, held)
        assert kept + dropped == len(records)
        newest = js(
            browser, "return window.gcs.state.store.events.filter((e) => e.kind === 'phone_other').at(-1).k"
        )
        assert newest == FLOOD - 1  # the newest are the ones kept
        wait_for(lambda: "older events dropped" in text(browser, "note"), 10, "the note")
        assert f"{dropped} older events dropped by this page" in text(browser, "note")
        wait_for(lambda: "older dropped" in text(browser, "event-count"), 10, "the events' count")
        assert js(browser, "return window.gcs.state.store.droppedTarget") == target
        assert not page_errors(browser)
