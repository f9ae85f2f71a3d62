"""What a page says when the live feed drops what the run made, in chromium. The live feed's queue is
bounded (``hil.gcs.live.LiveFeed``: an item past its capacity between two pump cycles is dropped and
counted, never waited for). Rows dropped were said in the page's note; events and link figures dropped were
counted (``/api/stats``) but the page showed nothing: a page missing a failsafe's record, a command's
status or the record that clears an alarm looked complete. Now the status carries each count and the note
says each. The feed's capacity is made small (a parameter of the real class) so that a lockstep run, as
fast as it goes, outruns the 30 Hz pump, as a starved pump would."""

from __future__ import annotations

import re

import pytest
from browser_support import chromium, text
from gcs_support import RunInThread, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.gcs.live import LiveFeed
from hil.gcs.uplink import Uplink
from hil.runtime import RunOptions

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def test_events_the_feed_dropped_are_said_in_the_page(browser, tmp_path) -> None:
    uplink = Uplink()
    feed = LiveFeed(uplink, capacity=8)
    with GroundStation(feed, bind="127.0.0.1:0", uplink=uplink) as station:
        browser.get(station.url)
        wait_for(lambda: text(browser, "feed") == "waiting for the run", 20, "the page waiting")
        runner = RunInThread(quick_scenario(), RunOptions(out_root=tmp_path, duration_s=6.0), station)
        runner.join()
        dropped = feed.stats.dropped_events
        assert dropped > 0, feed.stats  # the scenario's own premise: the feed outran
        wait_for(lambda: text(browser, "feed").startswith("ended"), 20, "the page saying the run ended")
        note = text(browser, "note")
        said = re.search(r"(\d+) events dropped by the feed", note)
        assert said and int(said.group(1)) == dropped, note
        if feed.stats.dropped_link:
            assert f"{feed.stats.dropped_link} link figures dropped" in note, note
