"""A live feed that comes steadily late, in chromium. Every message reaches the page, but seconds after the
host made it (a starved pump, a page reading behind): the run's progress keeps arriving, so the page judged
the feed by it said "receiving" and drew seconds-old values as live — a status carried no host clock, and
the page could not tell late from live. Now each live status carries the host's wall clock and each stream's
``caught_up`` sets the page's clock against it: the badge says the feed is stale and by how much.

The lag is made where it arises, between the run's feed and the station's pump: the real feed's batches are
handed to the real pump a drawn few seconds after the feed made them, in order, none lost."""

from __future__ import annotations

import re
import time
from collections import deque

import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import RunInThread, quick_scenario, wait_for
from hypothesis import Phase, given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation
from hil.gcs.live import LiveFeed
from hil.gcs.wire import Batch
from hil.runtime import RunOptions

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def lag_the_pump(feed: LiveFeed, lag_s: float) -> None:
    """The pump gets each of ``feed``'s batches ``lag_s`` after the feed made it, whatever the pump's cadence
    (the batches due at a poll merged in order: rows, events and link figures all kept, the newest status)."""
    real_poll = feed.poll
    held: deque[tuple[float, Batch]] = deque()

    def poll() -> Batch:
        now = time.monotonic()
        held.append((now, real_poll()))
        due = Batch()
        while held and now - held[0][0] >= lag_s:
            batch = held.popleft()[1]
            due.info = due.info or batch.info
            due.rows += batch.rows
            due.events += batch.events
            due.link += batch.link
            due.status = batch.status or due.status
        return due

    feed.poll = poll  # type: ignore[method-assign]


@settings(
    max_examples=2, deadline=None, phases=[Phase.explicit, Phase.generate]
)  # a failing run stays bounded
@given(lag_s=st.floats(2.0, 4.0))
def test_a_feed_that_comes_late_is_said_stale_with_its_lag(browser, tmp_path_factory, lag_s) -> None:
    out = tmp_path_factory.mktemp("lag")
    feed = LiveFeed()
    lag_the_pump(feed, lag_s)
    with GroundStation(feed, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(quick_scenario(), RunOptions(out_root=out, duration_s=3.0, pace=1.0), station)
        wait_for(lambda: (js(browser, "return window.gcs.stats.rows") or 0) > 60, 30, "rows, late")
        said = []
        for _ in range(6):  # the run goes on, its rows arriving steadily, lag_s late
            if runner.result is not None or text(browser, "feed").startswith("ended"):
                break
            said.append(text(browser, "feed"))
            time.sleep(0.2)
        runner.join()
        assert said, "the run ended before the page was looked at"
        for feed_text in said:
            lagging = re.fullmatch(r"stale: lagging (\d+\.\d) s behind the host", feed_text)
            assert lagging, said  # never "receiving"
            assert lag_s - 0.6 <= float(lagging.group(1)) <= lag_s + 1.5, (lag_s, said)
        wait_for(lambda: text(browser, "feed").startswith("ended"), 30, "the page saying the run ended")
    assert not page_errors(browser)
