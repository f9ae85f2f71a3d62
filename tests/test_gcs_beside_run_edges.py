"""The ground station at a run's edges: before it starts, when it fails to start, while the operator has it
suspended, after it ends, while its phone is silent, and with a full command inbox.

Before:

- a command POSTed while ``hil run --gcs`` was still opening its board was answered 202 ``queued``; when the
  board never came (the run failed to start) it was in neither ``events.jsonl`` nor the summary's
  ``operator``, and the page never learnt the run had failed: the hub gave a reader nothing until an
  ``info`` that never came, so the ``ended`` status with the run's error was published and never delivered.
  A page waiting for its run said "loaded", in green;
- a page following a run that ended (its way out disarming the board) showed the board ARMED, every cell
  live: the last row's, before the final Disarm;
- a run suspended by the operator's Disarm showed its phase as "—" (the page knew three phases) and raised
  a rotor-speed-low warning on every unit (the limit held "from the slew on", and suspended is phase 3);
- the attitude estimate of a run whose phone fell silent was drawn live, frozen, its pointing error too;
- a full command inbox answered a malformed request 503 "busy", not 400, and did not log it as rejected.

Everything here is the real thing: ``hil run --gcs`` in its own process or a run in a thread with the
station's real server, real HTTP, and the page in headless chromium (marker ``browser``).
"""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import (
    ControlStall,
    RunInThread,
    StreamReader,
    command,
    quick_scenario,
    replay_seen_at,
    request,
    wait_for,
)

from hil.gcs import GroundStation
from hil.gcs.info import enums
from hil.gcs.uplink import INBOX, Uplink, UplinkClosed, UplinkNotStarted
from hil.runtime import RunOptions
from hil.runtime.phases import Phase
from hil.runtime.runlog import read_events, read_telemetry
from protocol.messages import BoardState

try:
    from selenium.webdriver.common.by import By
except ImportError:  # then the browser tests are skipped by their marker
    pass


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


# ------------------------------------------------------------------------------ a run that fails to start
class _HilRun:
    """``hil run --gcs`` in its own process against a port that does not exist (the run tries to open it
    for ``recover_s`` and fails: exit 2); its station's URL, port and token once printed."""

    def __init__(self, tmp_path: Path, recover_s: float) -> None:
        self.out = tmp_path / "runs"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hil", "run", "--gcs", "127.0.0.1:0", "--no-plots", "--out", str(self.out),
             "--port", str(tmp_path / "no-such-device"), "--recover-within", str(recover_s),
             "--duration", "5"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        self.err: list[str] = []
        self._url = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()
        if not self._url.wait(120):
            self.proc.kill()
            raise RuntimeError(f"no URL from hil run: {''.join(self.err)[-2000:]}")
        url = next(line for line in self.err if "ground station: http" in line)
        found = re.search(r"http://127\.0\.0\.1:(\d+)/\?token=(\S+)", url)
        assert found is not None, url
        self.url = found[0]
        self.station = SimpleNamespace(port=int(found[1]), token=found[2])  # what gcs_support asks of one

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.err.append(line)
            if "ground station: http" in line:
                self._url.set()

    def wait(self) -> int:
        try:
            return self.proc.wait(60)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait(10)

    @property
    def run_dir(self) -> Path:
        [found] = [d for d in self.out.iterdir() if d.is_dir()]
        return found


def test_a_run_that_fails_to_start_took_no_command_and_its_stream_says_why(tmp_path):
    """Commands and acknowledgements before the run has started are refused (409 ``no_run``), never
    queued; the run fails to start (its port never opens), and the stream — which has no ``info`` — carries
    its ``ended`` status with the run's error before it closes. The run's record has no command: none was
    taken, so none was lost."""
    hil = _HilRun(tmp_path, recover_s=3.0)
    try:
        reader = StreamReader(hil.station, timeout=60)  # type: ignore[arg-type]
        status, answer = command(hil.station, {"command": "disarm"})  # type: ignore[arg-type]
        assert (status, answer["reason"]) == (409, "no_run") and "no run yet" in answer["error"], answer
        ack = {"alarm": "point_err_deg:high", "raised_t": 1.0}
        status, answer = request(hil.station, "POST", "/api/ack", ack)  # type: ignore[arg-type]
        assert (status, answer["reason"]) == (409, "no_run"), answer
        stats = request(hil.station, "GET", f"/api/stats?token={hil.station.token}")[1]  # type: ignore[arg-type]
        assert stats["uplink"]["no_run"] == 2 and stats["uplink"]["accepted"] == 0
        assert hil.wait() == 2
        wait_for(lambda: any(name == "bye" for name, _ in reader.events()), 10, "the stream's end")
    finally:
        hil.wait()
    messages = reader.events()
    assert "info" not in {name for name, _ in messages}
    statuses = [data for name, data in messages if name == "status"]
    assert statuses[0]["state"] == "waiting" and statuses[-1]["state"] == "ended", statuses
    assert statuses[-1]["exit"].startswith("error:") and "no-such-device" in statuses[-1]["exit"]
    summary = json.loads((hil.run_dir / "summary.json").read_text())
    assert summary["exit"] == statuses[-1]["exit"] and not summary.get("operator")
    events = read_events(hil.run_dir / "events.jsonl")[0]
    assert not [e for e in events if e["kind"] == "command"]  # none taken: none lost


def test_the_uplink_takes_requests_only_between_the_runs_start_and_end():
    uplink = Uplink()
    with pytest.raises(UplinkNotStarted) as refused:
        uplink.submit(b'{"command": "hold"}')
    assert refused.value.reason == "no_run"
    with pytest.raises(UplinkNotStarted):
        uplink.acknowledge(b'{"alarm": "point_err_deg:high", "raised_t": 1}')
    uplink.open()
    command_ = uplink.submit(b'{"command": "hold"}')
    assert command_ is not None and command_.id == 1
    uplink.seal()  # a run's end (its summary written)
    with pytest.raises(UplinkClosed) as closed:
        uplink.submit(b'{"command": "hold"}')
    assert closed.value.reason == "ended" and uplink.stats.no_run == 2


@pytest.mark.browser
def test_the_page_of_a_run_that_fails_to_start_waits_neutrally_then_says_it_failed(browser, tmp_path):
    """In chromium: while the run opens its board the feed badge says "waiting for the run", not green
    (it said "loaded", as live), and the buttons are off; once the run has failed to start the page says so
    and why — the badge, the note with the run's error, the uplink panel."""
    hil = _HilRun(tmp_path, recover_s=4.0)
    try:
        browser.get(hil.url)
        wait_for(lambda: text(browser, "feed") == "waiting for the run", 10, "the page waiting")
        badge = browser.find_element(By.ID, "feed").get_attribute("class").split()
        assert "live" not in badge and "bad" not in badge, badge
        assert "Waiting for the run" in text(browser, "uplink-off")
        assert hil.wait() == 2
        wait_for(lambda: text(browser, "feed") == "the run failed to start", 10, "the page saying so")
        note = text(browser, "note")
        assert note.startswith("the run failed to start: error:") and "no-such-device" in note, note
        assert "The run failed to start" in text(browser, "uplink-off")
        assert browser.find_element(By.CSS_SELECTOR, "button[data-command=arm]").get_attribute("disabled")
        browser.save_screenshot(str(tmp_path / "failed-to-start.png"))
    finally:
        hil.wait()
    assert not page_errors(browser)


# ------------------------------------------------------------------------------ a full inbox
def test_a_full_inbox_answers_a_malformed_request_400_and_logs_it(tmp_path):
    """A run's control thread held (its inbox not drained) with :data:`INBOX` commands and as many
    acknowledgements waiting: one more good one is 503 (busy, not logged: the sender may retry), a
    malformed command or acknowledgement is a 400 saying what is wrong, each logged as ``rejected``
    (``format``) once the run ticks again — before, both were 503 "busy", never logged."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        stall = ControlStall(station, 1.0)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=30.0, pace=1.0), station
        )
        try:
            assert stall.started.wait(60), "the run never reached its stall"
            assert all(command(station, {"command": "hold"})[0] == 202 for _ in range(INBOX))
            for k in range(INBOX):
                ack = {"alarm": "point_err_deg:high", "raised_t": float(k)}
                assert request(station, "POST", "/api/ack", ack)[0] == 202
            assert command(station, {"command": "hold"})[1]["reason"] == "busy"
            ack = {"alarm": "point_err_deg:high", "raised_t": 99.0}
            assert request(station, "POST", "/api/ack", ack)[1]["reason"] == "busy"
            status, answer = command(station, {"command": "warp"})
            assert (status, answer["reason"]) == (400, "format") and "command must be one of" in answer[
                "error"
            ]
            status, answer = request(station, "POST", "/api/ack", {"alarm": "NOT A KEY"})
            assert (status, answer["reason"]) == (400, "format") and "alarm must be" in answer["error"]
        finally:
            stall.release.set()
        rejected = runner.wait_event(lambda e: e["kind"] == "command" and e["status"] == "rejected")
        assert command(station, {"command": "abort"})[0] == 202
        runner.join()
    mine = [e for e in runner.events() if e["kind"] == "command" and e["status"] == "rejected"]
    assert [e["reason"] for e in mine] == ["format", "format"] and rejected in mine
    assert "command must be one of" in mine[0]["detail"] and "alarm must be" in mine[1]["detail"]
    assert station.stats()["uplink"]["inbox_full"] == 2


# ------------------------------------------------------------------------------ the pages
def _cell(driver: Any, element_id: str) -> dict[str, Any]:
    return js(driver, """const e = document.getElementById(arguments[0]);
        return {text: e.textContent, stale: e.classList.contains('stale'), age: e.dataset.age || ''};""",
              element_id)  # fmt: skip


@pytest.mark.browser
def test_after_the_run_ends_the_page_shows_the_board_as_the_runs_end_left_it(browser, tmp_path):
    """In chromium, a page following a paced live run to its end: the run's last row says ARMED, its way
    out then disarms the board (``disarmed``, the summary's ``final_disarm``). The page shows the board
    DISARMED — what the run's end said — and every board cell marked as of the run's end, never live."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=1.0, pace=2.0), station
        )
        result = runner.join()
        wait_for(lambda: text(browser, "feed") == "ended", 20, "the page saying the run ended")
        wait_for(lambda: _cell(browser, "board-state")["text"] == "DISARMED", 5, "the final state")
        cells = {c: _cell(browser, c) for c in ("board-state", "board-mode", "tel-age", "battery", "phase",
                                                "u0-rotor", "watchdog", "attitude", "point-err")}  # fmt: skip
        browser.save_screenshot(str(tmp_path / "ended.png"))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    assert tel["board_state"][-1] == int(BoardState.ARMED)  # the last row: before the way out's Disarm
    assert result.summary["final_disarm"]["state"] == "DISARMED"
    events = read_events(result.run_dir / "events.jsonl")[0]
    assert [e["reason"] for e in events if e["kind"] == "disarmed"] == ["run ended"]
    for name, cell in cells.items():
        assert cell["stale"] and cell["age"] == "at the run's end", (name, cell)
    assert not page_errors(browser)


@pytest.mark.browser
def test_a_run_suspended_by_the_operator_shows_its_phase_and_raises_no_rotor_speed_alarm(browser, tmp_path):
    """The operator's Disarm suspends a run (phase 3): its rotors run down below their minimum speed. A
    replay of the run in chromium — the same alarm rules and names as the live page — names the phase
    (from the run's ``info``, built from :class:`hil.runtime.phases.Phase`) and lists no rotor-speed-low
    alarm: that limit holds in the slew and the hold only."""
    sc = quick_scenario()
    with GroundStation.live(bind="127.0.0.1:0") as station:
        runner = RunInThread(sc, RunOptions(out_root=tmp_path, duration_s=60.0, pace=4.0), station)
        runner.wait_event(lambda e: e["kind"] == "slew_start", what="the slew's start")
        assert command(station, {"command": "disarm"})[0] == 202
        suspended = runner.wait_event(lambda e: e["kind"] == "suspended", what="the suspension")
        low = sc.spacecraft.limits.min_rotor_speed

        def run_down() -> bool:
            tel = read_telemetry(runner.run_dir / "telemetry.csv")
            rows = (tel["phase"] == int(Phase.SUSPENDED)) & (tel["rotor_speed_0"] < low)
            return bool(rows.sum() > 10)

        wait_for(run_down, 60, "the rotors run down below their minimum while suspended")
        assert command(station, {"command": "abort"})[0] == 202
        result = runner.join()
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    below = (tel["phase"] == int(Phase.SUSPENDED)) & (tel["rotor_speed_0"] < low)
    inside = float(tel["t"][np.nonzero(below)[0][-1]])
    assert inside > suspended["t"]
    with replay_seen_at(browser, result.run_dir, tel.rows, inside):
        wait_for(lambda: text(browser, "phase") == "SUSPENDED", 5, "the phase named")
        assert enums()["phase"][int(Phase.SUSPENDED)] == "SUSPENDED"
        keys = js(browser, "return Array.from(document.querySelectorAll('#alarms tr[data-key]'))"
                           ".map((r) => r.dataset.key)")  # fmt: skip
        browser.save_screenshot(str(tmp_path / "suspended.png"))
    assert not [k for k in keys if k.startswith("rotor_speed_") and k.endswith(":low")], keys
    assert not page_errors(browser)


@pytest.mark.browser
def test_the_estimate_is_marked_stale_while_the_phone_is_silent(browser, tmp_path):
    """A real-time run against a spawned ``firmware-sim`` whose world's phone is silent from 8 s to 12 s
    (the host has no truth: the page's attitude is the estimate). While the phone is silent the attitude,
    its source, the pointing error and the 3D view are marked stale with the phone's silence, not drawn
    live; before the gap and after it they are live."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a free port for the phone
        s.bind(("127.0.0.1", 0))
        phone = f"udp://127.0.0.1:{s.getsockname()[1]}"
    port = f"spawn://firmware-sim?world=cubesat-1u&phone={phone}&phone_gap=8:4"
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, port=port, phone=phone, duration_s=12.0), station
        )
        samples: list[dict[str, Any]] = []
        end = time.monotonic() + 120
        while time.monotonic() < end and runner.thread.is_alive():
            sample = js(browser, """const c = (id) => { const e = document.getElementById(id);
                return {text: e.textContent, stale: e.classList.contains('stale')}; };
                const store = window.gcs.state.store;
                return {t: store && store.n ? store.tLast : null,
                        feed: document.getElementById('feed').textContent,
                        source: c('attitude-source'), attitude: c('attitude'), point: c('point-err'),
                        view: document.getElementById('view3d').dataset.stale || ''};""")  # fmt: skip
            samples.append(sample)
            if sample["t"] is not None and sample["t"] > 14.0:
                break
            time.sleep(0.2)
        assert command(station, {"command": "abort"})[0] == 202
        result = runner.join()
    events = read_events(result.run_dir / "events.jsonl")[0]
    [gap_event] = [e for e in events if e["kind"] == "phone_gap"]
    [back] = [e for e in events if e["kind"] == "phone_back"]
    receiving = [s for s in samples if s["feed"] == "receiving" and s["source"]["text"] == "estimate"]
    gap = [s for s in receiving if gap_event["since"] + 0.6 < s["t"] < back["t"] - 0.1]
    before = [s for s in receiving if 5.0 < s["t"] < gap_event["since"] - 0.3]
    assert len(gap) >= 3 and len(before) >= 3, samples
    for s in gap:
        assert s["attitude"]["stale"] and s["point"]["stale"] and s["source"]["stale"], s
        assert s["view"].startswith("stale:"), s
    assert not any(s["attitude"]["stale"] or s["point"]["stale"] for s in before), before
    assert not page_errors(browser)
