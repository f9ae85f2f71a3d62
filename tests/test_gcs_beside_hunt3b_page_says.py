"""What the ground station's page shows of a record beside the path walked: in chromium, through ``hil
gcs``'s replay station. A ``command`` record whose ``command`` (or ``origin``, ``reason``) is an object or a
list — JSON that parses, in a run directory's events — was marked on the plots and listed in the command
history as "[object Object]", and so was a summary's ``exit`` in the page's note: now as its content (the
events table's way, panels.js ``shortText``).
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


OBJECTS: list[Any] = [{"name": "slew", "to": [1, 2]}, ["arm", "now"], {}]


def test_a_command_named_by_an_object_is_shown_as_its_content(browser, tmp_path_factory) -> None:
    out = tmp_path_factory.mktemp("object-commands")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=3.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    t0 = float(tel["t"][2])
    path = result.run_dir / "events.jsonl"
    own = [json.loads(line) for line in path.read_text().splitlines()]
    records = []
    for k, value in enumerate(OBJECTS):
        base = {"t": t0 + 0.1 * k, "kind": "command", "id": 100 + k, "origin": "gcs", "command": "arm"}
        records += [
            {**base, "command": value, "status": "refused", "reason": value},
            {**base, "id": 200 + k, "origin": value, "status": "applied"},
        ]
    keyed = sorted([*own, *records], key=lambda e: e["t"])
    path.write_text("".join(json.dumps(e) + "\n" for e in keyed))
    summary_path = result.run_dir / "summary.json"
    summary = json.loads(summary_path.read_text())
    summary_path.write_text(json.dumps({**summary, "exit": {"code": 3, "why": ["lost", "board"]}}))
    with GroundStation.replay(result.run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(lambda: js(browser, "return window.gcs.state.store.events.length") == len(keyed), 10,
                 "the events")  # fmt: skip
        js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                       s.dispatchEvent(new Event('input'));""", float(tel["t"][-1]))  # fmt: skip
        wait_for(lambda: "(" in text(browser, "cmd-history-count"), 10, "the command history")
        labels = js(browser, """return import('/static/markers.js').then((m) =>
                      m.runMarkers(window.gcs.state.store.events).map((x) => x.label));""")  # fmt: skip
        history = text(browser, "cmd-history")
        note = text(browser, "note")
    shown = " ".join(labels) + " " + history + " " + note
    assert "[object Object]" not in shown, shown
    assert "name slew, to [1, 2]" in " ".join(labels) and "[arm, now]" in history, shown
    assert "exit: code 3, why [lost, board]" in note, note  # a summary's exit is any JSON
    assert not page_errors(browser)
