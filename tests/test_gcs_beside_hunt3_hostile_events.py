"""A run directory whose ``events.jsonl`` and ``summary.json`` hold JSON that parses but is no record a run
writes: objects whose own ``toString`` / ``valueOf`` is a value, and kinds named as a JavaScript object's
inherited properties (``constructor``, ``__proto__``, ``toString``).

Before, the page (``hil/gcs/static``) used the records' fields as text and numbers as they came:
``String(e.command)``, a template, ``e.t > t``, ``tr.dataset.kind = e.kind`` of such an object threw a
TypeError ("Cannot convert object to primitive value") on every redraw — the command history, the stats
and whatever came after the throw were never drawn again; and a kind was looked up in the markers' tables
with ``in``, which also finds inherited names: a record of kind ``constructor`` was marked on every plot as
"function Object() { [native code] }", one of kind ``__proto__`` as "[object Object]". Now the downlink's
messages are parsed as data (such keys kept under another name) and a kind is looked up among the tables'
own names.

Through the real pieces: a real run's directory with the records spliced into its events in time order and
its summary given such values, ``hil gcs``'s replay station, the page in chromium, its timeline moved over
every record.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry

pytestmark = pytest.mark.browser

HOSTILE: list[Any] = [
    {"toString": 1},
    {"valueOf": 1},
    {"toString": 1, "valueOf": 1},
    [{"toString": 1, "valueOf": 1}],  # an array is made text through its elements
    {"a": {"toString": "x", "valueOf": "y"}},  # nested
]
FIELDS = (
    "t", "kind", "command", "status", "reason", "origin", "remote", "id", "after_ms", "new", "severity",
    "sender", "other_phones", "alarm", "raised_t", "target_r", "target_euler_deg", "detail",
)  # fmt: skip
KINDS = (
    "command", "alarm_ack", "phone_other", "phone_others_quiet", "phone_switch", "phone_following",
    "board_state", "disarmed", "slew_start", "constructor", "__proto__", "toString", "hasOwnProperty",
    "valueOf", "isPrototypeOf",
)  # fmt: skip
INHERITED = ("constructor", "__proto__", "toString", "hasOwnProperty", "valueOf", "isPrototypeOf")
MARKER_LABELS = {
    "slew start", "slew end", "board reset", "link lost", "ESC dead", "phone gap", "board silent",
    "phone switched", "FAILSAFE",
}  # fmt: skip


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def hostile_run(tmp_path_factory) -> tuple[Path, list[float], int]:
    """A real run's directory with a record of every kind × every field given every hostile value (and each
    inherited name as a plain record), spliced in time order; its summary's phone and final Disarm given
    hostile values too. (The directory, the spliced records' times, the number of records.)"""
    out = tmp_path_factory.mktemp("hostile-events")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=4.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    records: list[dict[str, Any]] = [{"kind": kind} for kind in INHERITED]
    for kind in KINDS:
        for field in FIELDS:
            for value in HOSTILE:
                base = {"kind": kind, "id": 7, "origin": "gcs", "status": "applied", "command": "slew"}
                records.append({**base, field: value})
    times = np.linspace(float(tel["t"][1]) + 0.1, float(tel["t"][-2]) - 0.1, len(records)).tolist()
    path = result.run_dir / "events.jsonl"
    own = [json.loads(line) for line in path.read_text().splitlines()]
    keyed = [(e["t"], json.dumps(e)) for e in own]
    keyed += [(t, json.dumps({"t": t, **r})) for t, r in zip(times, records, strict=True)]  # r's t first
    path.write_text("".join(line + "\n" for _, line in sorted(keyed, key=lambda pair: pair[0])))
    summary_path = result.run_dir / "summary.json"
    summary = json.loads(summary_path.read_text())
    summary["phone"] = {**(summary.get("phone") or {}), "following": {"toString": 1, "valueOf": 1},
                        "other_phones": 0, "other_phone_messages": 0, "phone_switches": 0}  # fmt: skip
    summary["final_disarm"] = {"state": {"toString": 1}, "ok": {"valueOf": 1}}
    summary["exit"] = {"toString": 1, "valueOf": 1}
    summary_path.write_text(json.dumps(summary))
    return result.run_dir, times, len(own) + len(records)


def _move_to(browser, t: float) -> None:
    js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                   s.dispatchEvent(new Event('input'));""", t)  # fmt: skip


def test_hostile_records_neither_break_the_page_nor_draw_made_up_markers(browser, hostile_run):
    """Every record listed, the page drawn again at each moment the timeline is moved to (its render
    count grows), no error in the page, and only the run's own kinds of marker on the plots."""
    run_dir, times, count = hostile_run
    with GroundStation.replay(run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(
            lambda: js(browser, "return window.gcs.state.store.events.length") == count, 10, "the events"
        )
        for t in [*times[:: max(len(times) // 12, 1)], times[-1] + 1.0]:
            before = js(browser, "return window.gcs.stats.renders")
            _move_to(browser, t)
            wait_for(
                lambda before=before: js(browser, "return window.gcs.stats.renders") > before,
                5,
                f"the page drawn at {t:.2f} s (errors: {page_errors(browser)[:1]})",
            )
        assert text(browser, "event-count").endswith(f" of {count})")  # the run's last ones: after its rows
        assert text(browser, "phone-following"), "the phone followed, at the run's end"
        labels = js(
            browser,
            """return import('/static/markers.js').then((m) => m.runMarkers(window.gcs.state.store.events)
                 .filter((x) => x.kind !== 'command').map((x) => x.label));""",
        )
        drawn = js(
            browser, "return [...document.querySelectorAll('.plot')].map((p) => p.dataset.markers || '')"
        )
    assert set(labels) <= MARKER_LABELS, sorted(set(labels) - MARKER_LABELS)
    assert not any("native code" in d for d in drawn), drawn
    assert not page_errors(browser)
