"""The page's link snapshots over a long live run, in chromium: bounded.

A live run sends a link snapshot (some thirty figures) every 0.2 s of run time (``hil/gcs/live.py``,
``LINK_PERIOD_S``), and the page's store kept every one: a page left open on a day's run held 430 000 of
them — its rows are bounded (``MAX_ROWS``, decimated), its link figures were not. Now they are bounded as
the rows are (``MAX_LINK``: past it every other one dropped, then 1 in 2, 4, ... kept, evenly over the run),
and the newest is always held (the link panel shows it while following).

The page's own ``store.js`` module, imported by the page served by a real station, fed as the downlink
feeds it (``link`` messages of a few snapshots each) over a run several times ``MAX_LINK`` long.
"""

from __future__ import annotations

import pytest
from browser_support import chromium, js, page_errors
from gcs_support import wait_for
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation
from hil.gcs.live import LINK_PERIOD_S

pytestmark = pytest.mark.browser

MAX_LINK = 20000  # hil/gcs/static/store.js

FEED = """
const [count, batch, period, done] = arguments;
import('/static/store.js').then(({ Store }) => {
  const store = new Store(['t']);
  let k = 0, worst = 0;
  while (k < count) {
    const list = [];
    for (let j = 0; j < batch && k < count; j++, k++) list.push({ t: k * period, frames_in: k });
    store.pushLink(list);
    worst = Math.max(worst, store.link.length);
    const newest = store.link[store.link.length - 1];
    if (newest.frames_in !== k - 1) { done({ error: `newest ${newest.frames_in}, sent ${k - 1}` }); return; }
  }
  const ts = store.link.map((s) => s.t);
  const ordered = ts.every((t, i) => i === 0 || t > ts[i - 1]);
  done({ n: store.link.length, worst, first: ts[0], last: ts[ts.length - 1], ordered,
         at: store.linkAt(count * period / 2).t });
});
"""


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def page(browser):
    """A live station's page (waiting for its run): the page's own modules, served."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return Boolean(window.gcs)"), 20, "the page")
        yield browser
    assert not page_errors(browser)


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(count=st.integers(MAX_LINK + 1, 4 * MAX_LINK), batch=st.integers(1, 40))
def test_a_long_runs_link_snapshots_are_bounded_and_the_newest_kept(page, count: int, batch: int) -> None:
    out = page.execute_async_script(FEED, count, batch, LINK_PERIOD_S)
    assert "error" not in out, out
    assert out["worst"] <= MAX_LINK + 1 and out["n"] <= MAX_LINK + 1, out  # bounded
    assert out["n"] >= MAX_LINK // 4, out  # the run kept at a resolution, not cut
    assert out["first"] == 0 and out["ordered"], out  # from the run's start, in time order
    assert out["last"] == pytest.approx((count - 1) * LINK_PERIOD_S), out  # the newest held
    assert abs(out["at"] - count * LINK_PERIOD_S / 2) < 8 * LINK_PERIOD_S * count / MAX_LINK, out
