"""The ground-station page in a real browser: Debian's chromium, driven through chromedriver by Selenium,
headless. A short real-time run's page loads and its plots and 3D view follow the simulated attitude; a
Disarm click disarms the emulated board; a wrong token and a foreign origin are refused; a finished run
directory replays and its timeline scrubs. Screenshots go to each test's tmp directory.

Marker ``browser``: without chromium, chromedriver (Debian's, ``.ci/apt-packages``) or selenium every test
here is skipped, with one line in pytest's summary; with ``VSCMG_HIL_REQUIRE_ALL=1`` (CI: ``.ci/run``) the
run fails instead (tests/conftest.py, which checks the same two paths).
"""

from __future__ import annotations

import http.server
import subprocess
import sys
import threading

import numpy as np
import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import RunInThread, quick_scenario, replay_seen_at, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_events, read_telemetry
from protocol.messages import BoardState

pytestmark = pytest.mark.browser  # without chromium, chromedriver or selenium: skipped (tests/conftest.py)

try:
    from selenium.webdriver.common.by import By
except ImportError:  # then no test here runs: the marker skips them, with the one line for them all
    pass


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


_js, _page_errors, _text = js, page_errors, text


def test_a_live_real_time_run_follows_the_attitude_and_a_disarm_click_disarms_the_board(browser, tmp_path):
    sc = quick_scenario()
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(sc, RunOptions(out_root=tmp_path, lockstep=False, duration_s=4.0), station)
        wait_for(
            lambda: _js(browser, "return window.gcs.state.info && window.gcs.state.info.mode"), 20, "info"
        )
        wait_for(lambda: _text(browser, "board-state") == "ARMED", 20, "an armed board in the page")
        runner.wait_event(lambda e: e["kind"] == "slew_start", what="the slew")
        first = wait_for(
            lambda: browser.find_element(By.ID, "view3d").get_attribute("data-attitude"), 10, "3D"
        )
        plot_t = float(browser.find_element(By.ID, "plot-pointing").get_attribute("data-last-t"))
        attitude = _text(browser, "attitude")
        browser.save_screenshot(str(tmp_path / "live-1.png"))
        view = browser.find_element(By.ID, "view3d")

        def turned() -> float:  # rad, between the attitude the 3D view shows now and the first one
            return float(np.linalg.norm(np.array(view.get_attribute("data-attitude").split(","), float)
                                        - np.array(first.split(","), float)))  # fmt: skip

        wait_for(lambda: turned() > 2e-3, 10, "the 3D view to follow the slew")
        pointing = browser.find_element(By.ID, "plot-pointing")
        wait_for(
            lambda: float(pointing.get_attribute("data-last-t")) > plot_t + 0.5, 5, "the plot to move on"
        )
        wait_for(lambda: _text(browser, "attitude") != attitude, 5, "the attitude readout to change")
        assert int(browser.find_element(By.ID, "plot-est_att").get_attribute("data-points")) > 20
        rate = _js(browser, "return window.gcs.stats.updateHz")
        assert rate > 0  # the page redraws as data comes (its rate is measured in bench_gcs, not here)
        assert _text(browser, "phone-rate-gyr") not in ("", "—", "not recorded")

        disarm = browser.find_element(By.CSS_SELECTOR, "button[data-command=disarm]")
        disarm.click()
        assert "Confirm" in disarm.text  # a second click confirms
        disarm.click()
        item = wait_for(lambda: browser.find_elements(By.CSS_SELECTOR, "#cmd-log li[data-status=acked]"), 10,
                        "the page's confirmation of the board's ack")  # fmt: skip
        assert "disarm" in item[0].text
        wait_for(lambda: _text(browser, "board-state") == "DISARMED", 5, "the page to show DISARMED")
        browser.save_screenshot(str(tmp_path / "live-disarmed.png"))
        result = runner.join()
        # the run ended: the page says so (not "Replay"), and takes no more commands
        wait_for(lambda: "run has ended" in _text(browser, "uplink-off"), 10, "the page to say the run ended")
        assert _text(browser, "mode").startswith("live run ended")
        assert disarm.get_attribute("disabled")
    assert not _page_errors(browser)
    events = read_events(result.run_dir / "events.jsonl")[0]
    commands = [e for e in events if e["kind"] == "command"]
    assert [(e["command"], e["status"], e["origin"]) for e in commands] == [
        ("disarm", "sent", "gcs"), ("disarm", "acked", "gcs")]  # fmt: skip
    t_ack = commands[1]["t"]
    assert any(e["kind"] == "board_state" and e["old"] == "ARMED" and e["new"] == "DISARMED" for e in events)
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    after = tel["t"] > t_ack + 0.2
    assert after.any() and np.all(tel["board_state"][after] == int(BoardState.DISARMED))
    assert result.summary["mode"] == "realtime"


class _ForeignSite(http.server.BaseHTTPRequestHandler):
    """Another origin (another port): a page whose script tries to command the ground station."""

    def do_GET(self):  # noqa: N802
        body = b"<!doctype html><title>elsewhere</title>"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        """Quiet: the test's own server logs nothing to stderr."""


def test_a_wrong_token_and_a_foreign_origin_are_refused(browser, tmp_path):
    with GroundStation.live(bind="127.0.0.1:0") as station:
        base = f"http://127.0.0.1:{station.port}"
        browser.get(f"{base}/?token=guessed")
        wait_for(lambda: station.stats()["server"]["rejected"].get("token"), 10, "the stream refused")
        assert _js(browser, "return window.gcs.state.info") is None  # nothing of the run reached the page
        status = browser.execute_async_script("""
            const done = arguments[arguments.length - 1];
            fetch('/api/command', {method: 'POST', body: '{"command": "disarm"}',
                  headers: {'Content-Type': 'application/json', 'Authorization': 'token guessed'}})
              .then(r => done(r.status));
        """)
        assert status == 401
        browser.save_screenshot(str(tmp_path / "wrong-token.png"))

        site = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _ForeignSite)
        threading.Thread(target=site.serve_forever, daemon=True).start()
        try:
            browser.get(f"http://127.0.0.1:{site.server_address[1]}/")
            outcome = browser.execute_async_script(
                """
                const [url, token, done] = arguments;
                const out = [];
                // a simple cross-site POST (no preflight): it reaches the server, with the page's Origin
                await fetch(url, {method: 'POST', mode: 'no-cors', body: '{"command": "disarm"}'})
                  .then(() => out.push('sent'), (e) => out.push('error'));
                // with the token (as if leaked): the browser asks first (a CORS preflight), which is refused
                await fetch(url, {method: 'POST', headers: {'Content-Type': 'application/json',
                                  'Authorization': 'token ' + token}, body: '{"command": "disarm"}'})
                  .then((r) => out.push(r.status), (e) => out.push('blocked'));
                done(out);
                """,
                f"{base}/api/command",
                station.token,
            )
        finally:
            site.shutdown()
            site.server_close()
        assert outcome == ["sent", "blocked"]
        st = station.stats()
        assert st["server"]["rejected"]["origin"] == 2 and st["uplink"]["accepted"] == 0
        # the stream's wrong token, the page's one question why (/api/info: not retried), the command's,
        # the two foreign origins: each logged into the run's events on its next control tick (a refused
        # stream is an attempt too: issue 26)
        assert st["uplink"]["rejected"] == 5


def test_a_finished_run_directory_replays_and_its_timeline_scrubs(browser, tmp_path):
    result = run(quick_scenario(), RunOptions(out_root=tmp_path, duration_s=4.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    with GroundStation.replay(result.run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: _js(browser, "return window.gcs.state.status.state") == "finished", 20, "the replay")
        wait_for(lambda: _js(browser, "return window.gcs.state.store.n") == tel.rows, 10, "every row")
        assert _text(browser, "mode") == "replay" and _text(browser, "feed") == "finished"
        assert browser.find_element(By.CSS_SELECTOR, "button[data-command=disarm]").get_attribute("disabled")
        end_attitude = browser.find_element(By.ID, "view3d").get_attribute("data-attitude")
        assert int(_js(browser, "return document.querySelectorAll('#events tbody tr').length")) > 5
        browser.save_screenshot(str(tmp_path / "replay-end.png"))
        slew_start = next(
            e["t"] for e in read_events(result.run_dir / "events.jsonl")[0] if e["kind"] == "slew_start"
        )
        mid = slew_start + 1.0
        _js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                        s.dispatchEvent(new Event('input'));""", mid)  # fmt: skip
        wait_for(lambda: _text(browser, "cursor-time").startswith(f"{mid:.2f}"), 5, "the cursor to move")
        wait_for(lambda: browser.find_element(By.ID, "view3d").get_attribute("data-attitude") != end_attitude,
                 5, "the 3D view at the cursor")  # fmt: skip
        shown = np.array(
            browser.find_element(By.ID, "view3d").get_attribute("data-attitude").split(","), float
        )
        i = int(np.searchsorted(tel["t"], mid, side="right")) - 1
        truth = np.array([tel["true_rx"][i], tel["true_ry"][i], tel["true_rz"][i]])
        np.testing.assert_allclose(shown, truth, atol=1e-4)  # the attitude of the row at the cursor
        last_t = float(browser.find_element(By.ID, "plot-pointing").get_attribute("data-last-t"))
        assert last_t == pytest.approx(tel["t"][i], abs=1e-3)
        browser.save_screenshot(str(tmp_path / "replay-scrubbed.png"))
    assert not _page_errors(browser)


def test_a_replayed_outage_shows_the_board_unknown_and_its_values_empty(browser, tmp_path):
    """Rows without a live board (a hung MCU: telemetry stale, then the reset's handshake) carry no board
    value: at a cursor inside the outage the page says the board state is unknown and why, and shows no
    rotor speed — not the last one, as if fresh."""
    sc = quick_scenario().with_changes(fault_options={"hang_at": ["4.0"]})
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=3.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    blind = np.nonzero((tel["board_link"] == 1) & (tel["t"] > 4.0))[0]
    assert len(blind) > 5
    inside = float(tel["t"][blind[len(blind) // 2]])
    with replay_seen_at(browser, result.run_dir, tel.rows, inside):
        wait_for(lambda: _text(browser, "board-state").startswith("UNKNOWN"), 5, "the board state unknown")
        assert _text(browser, "board-state") == "UNKNOWN (no telemetry)"
        assert "bad" in browser.find_element(By.ID, "board-state").get_attribute("class")
        assert _text(browser, "u0-rotor") == "—"
        assert "ms ago" in _text(browser, "tel-age")
        browser.save_screenshot(str(tmp_path / "replay-outage.png"))
    assert not _page_errors(browser)


STALE_CELLS = ("board-mode", "faults", "link-age", "tel-age", "battery", "ubec", "power", "point-err",
               "attitude", "u0-rotor", "u0-angle", "phone-rate-gyr")  # fmt: skip


def test_after_its_host_dies_the_page_shows_every_value_stale_and_takes_no_commands(browser, tmp_path):
    """``hil run --gcs`` in its own process, killed (SIGKILL) while the page follows it: within a few
    seconds the badge says the host is lost, every value cell is marked stale (the host's telemetry age
    among them), the uplink's buttons are disabled and the panel says why — no "Failed to fetch" from a
    click on a dead host."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil", "run", "--gcs", "127.0.0.1:0", "--duration", "120", "--no-plots",
         "--out", str(tmp_path)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        url = wait_for(lambda: _url_line(proc), 120, "the ground station's URL")
        browser.get(url)
        wait_for(lambda: _text(browser, "board-state") == "ARMED", 60, "an armed board in the page")
        hold = browser.find_element(By.CSS_SELECTOR, "button[data-command=hold]")
        assert not hold.get_attribute("disabled") and _text(browser, "mode").startswith("live")
        assert "stale" not in browser.find_element(By.ID, "tel-age").get_attribute("class")
        proc.kill()
        proc.wait(10)
        wait_for(lambda: hold.get_attribute("disabled"), 10, "the buttons disabled")
        wait_for(
            lambda: _text(browser, "mode").startswith("host lost"), 5, "the badge to say the host is lost"
        )
        assert "No word from the host" in _text(browser, "uplink-off")
        for name in ("arm", "disarm", "abort", "slew"):
            assert browser.find_element(By.CSS_SELECTOR, f"button[data-command={name}]").get_attribute(
                "disabled"
            )
        wait_for(lambda: all("stale" in _classes(browser, c) for c in STALE_CELLS), 10, "every cell stale")
        assert browser.find_element(By.ID, "tel-age").get_attribute("data-age").endswith("old")
        _js(browser, "arguments[0].click()", hold)  # disabled: nothing is sent, nothing fails
        assert not browser.find_elements(By.CSS_SELECTOR, "#cmd-log li")
        browser.save_screenshot(str(tmp_path / "host-died.png"))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert not [e for e in _page_errors(browser) if "Failed to fetch" in e or "TypeError" in e]


def _classes(driver, element_id: str) -> str:
    return driver.find_element(By.ID, element_id).get_attribute("class") or ""


def _url_line(proc: subprocess.Popen) -> str | None:
    """The URL ``hil run --gcs`` prints on stderr (read a line at a time; None until it comes)."""
    if proc.poll() is not None:
        raise RuntimeError(f"hil run ended early: {proc.stderr.read()[-2000:]}")
    line = proc.stderr.readline()
    return line.split(": ", 1)[1].strip() if line.startswith("ground station: ") else None
