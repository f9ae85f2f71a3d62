"""A page whose stream the server refused (every stream slot taken: 503) tries again, and says why meanwhile.

``EventSource`` reconnects by itself after a network error, but a stream answered with anything but 200
(the 503 of a full ``MAX_STREAMS``, a 401) is failed for good: no further attempt. Before, the page
(``app.js``) did not look: a page opened, or reconnecting, while 16 other streams were open (other tabs,
a reconnect storm, streams not yet seen closed) said "reconnecting: nothing for N s" for ever and never
came back once slots were free. Now a stream failed for good is opened again by the page, 1 s, 2 s, ...
at most 10 s later, the badge saying "refused by the server"; a refusal of its token (401/403, asked of
``/api/info``) is said and not retried.

Through the real pieces: a station following a run directory the test writes, 16 streams held open by
raw sockets, the page in chromium.
"""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest
from browser_support import chromium, js, text
from gcs_support import wait_for

from hil.gcs import GroundStation
from hil.gcs.server import MAX_STREAMS


def _write_run(d: Path, rows: int) -> None:
    d.mkdir()
    (d / "telemetry.csv").write_text("t,x\n" + "".join(f"{k * 0.01:.2f},{k}\n" for k in range(rows)))
    (d / "events.jsonl").write_text('{"t": 0.0, "kind": "started"}\n')


def _open_stream(station: GroundStation) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", station.port), timeout=10)
    sock.sendall(
        f"GET /api/stream?token={station.token} HTTP/1.1\r\nHost: 127.0.0.1:{station.port}\r\n\r\n".encode()
    )
    return sock


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.mark.browser
def test_a_page_refused_a_stream_tries_again_and_comes_back_when_a_slot_is_free(browser, tmp_path):
    """Every stream slot held: the page opened meanwhile is refused (503); its badge says it was refused
    and that it tries again; once the slots are free it gets the run (its rows) by itself."""
    d = tmp_path / "run"
    _write_run(d, 200)
    with GroundStation.replay(d, bind="127.0.0.1:0") as station:
        held = [_open_stream(station) for _ in range(MAX_STREAMS)]
        try:
            wait_for(lambda: station.server.counters()["streams_open"] == MAX_STREAMS, 10, "the slots held")
            browser.get(station.url)
            wait_for(lambda: station.server.counters()["rejected"].get("streams"), 10, "the page refused")
            time.sleep(3.0)  # EventSource's own retry (1 s) would have come by now
            badge = text(browser, "feed")
            assert "refused" in badge, badge
            assert js(browser, "return window.gcs.state.info") is None
        finally:
            for sock in held:
                sock.close()
        wait_for(lambda: station.server.counters()["streams_open"] == 0, 15, "the slots free")
        wait_for(
            lambda: js(browser, "return window.gcs.state.store && window.gcs.state.store.n") == 200,
            15,
            "the page holding the run",
        )
        assert "refused" not in text(browser, "feed") and js(browser, "return window.gcs.state.connected")


@pytest.mark.browser
def test_a_page_with_a_wrong_token_says_so_and_does_not_retry(browser, tmp_path):
    """A page opened with a wrong token: its stream is refused (401); the badge says the token was refused
    and the page does not retry (each attempt would be a refusal logged in the run's events)."""
    d = tmp_path / "run"
    _write_run(d, 10)
    with GroundStation.replay(d, bind="127.0.0.1:0") as station:
        browser.get(station.url.replace(station.token, "wrong"))
        wait_for(lambda: "token" in text(browser, "feed"), 10, "the page saying its token was refused")
        refused = station.server.counters()["rejected"].get("token", 0)
        time.sleep(4.0)
        assert station.server.counters()["rejected"].get("token", 0) == refused
        assert js(browser, "return window.gcs.state.info") is None
