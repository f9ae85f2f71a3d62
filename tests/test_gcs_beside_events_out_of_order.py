"""A run directory whose events are far out of time order does not freeze the page.

The page keeps a run's events in time order (``store.js``, ``pushEvents``). Before, each event was walked
back from the end to its place and spliced in — nothing for a run's own events, which come in order, but
O(n) apiece for events that do not: an ``events.jsonl`` damaged, spliced or hostile (bad input from a run
directory), 150 000 records in reverse order, froze the page's only thread for ~20 s (400 000: minutes),
its timeline, keys and buttons dead meanwhile. Now a batch out of order is sorted and merged in one pass.

Through the real pieces: a real run's directory with 150 000 records appended in reverse time order,
``hil gcs``'s station, the page in chromium.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from browser_support import chromium, js, page_errors
from gcs_support import quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run

EXTRA = 150_000


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def reversed_run(tmp_path_factory) -> tuple[Path, int, float]:
    """A real run's directory with ``EXTRA`` records appended, their times running backwards from the end."""
    out = tmp_path_factory.mktemp("reversed")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=2.0))
    path = result.run_dir / "events.jsonl"
    own = path.read_text().splitlines()
    end = max(json.loads(line)["t"] for line in own)
    extra = (json.dumps({"t": round(end * (1 - k / EXTRA), 6), "kind": "note", "k": k}) for k in range(EXTRA))
    with open(path, "a") as f:
        f.write("\n".join(extra) + "\n")
    return result.run_dir, len(own) + EXTRA, end


@pytest.mark.browser
def test_events_far_out_of_order_load_at_once_and_in_time_order(browser, reversed_run):
    """Every record is in the page within 6 s of the replay's end, in time order (the run's own among
    them), and the page still answers (a script round trip under 1 s)."""
    run_dir, records, end = reversed_run
    with GroundStation.replay(run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: station.source.finished, 30, "the run read")
        start = time.monotonic()
        wait_for(
            lambda: (
                js(browser, "return window.gcs.state.store ? window.gcs.state.store.events.length : 0")
                == records
            ),
            6,
            "every record in the page",
        )
        took = time.monotonic() - start
        ordered = js(
            browser,
            """const ev = window.gcs.state.store.events;
               for (let i = 1; i < ev.length; i++) if (ev[i].t < ev[i - 1].t) return i;
               return -1;""",
        )
        assert ordered == -1, ordered
        first = js(browser, "return window.gcs.state.store.events[0].t")
        assert first == 0.0 or first <= end / EXTRA, first
        t0 = time.monotonic()
        js(browser, "return 1")
        assert time.monotonic() - t0 < 1.0
    assert took < 6.0
    assert not page_errors(browser)
