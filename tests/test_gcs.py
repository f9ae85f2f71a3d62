"""The ground station without a browser: its parts (address, access checks, the downlink's format and
history, commands, the live feed, the run-directory follower), its HTTP server over real sockets, and the
uplink end to end through a lockstep run and the emulated board. The page in a real browser:
tests/test_gcs_browser.py."""

from __future__ import annotations

import json
import math
import re
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from gcs_support import RunInThread, command, quick_scenario, request, wait_for

from hil import so3
from hil.gcs import GroundStation, LiveFeed, RunDirSource, parse_bind
from hil.gcs.access import Access
from hil.gcs.hub import Hub, caught_up
from hil.gcs.uplink import INBOX, parse_command
from hil.gcs.wire import encode_rows, number
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_events, read_telemetry
from hil.so3 import euler_zyx
from protocol.errors import ConfigError, InputFormatError
from protocol.messages import BoardState


# ----------------------------------------------------------------------------------------- address, access
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (None, ("127.0.0.1", 8470, False)),
        ("", ("127.0.0.1", 8470, False)),
        (":9000", ("127.0.0.1", 9000, True)),
        ("9000", ("127.0.0.1", 9000, True)),
        ("0.0.0.0:0", ("0.0.0.0", 0, True)),
        ("localhost", ("localhost", 8470, False)),
        ("[::1]:8471", ("::1", 8471, True)),
    ],
)
def test_bind_addresses(text, expected):
    assert parse_bind(text) == expected


@pytest.mark.parametrize("text", ["127.0.0.1:http", "127.0.0.1:70000", "::1:80", "[::1", "[::1]x"])
def test_bad_bind_addresses_say_what_is_wrong(text):
    with pytest.raises(ConfigError) as info:
        parse_bind(text)
    assert info.value.where == "--gcs"


def test_access_checks_token_origin_and_host():
    a = Access("s3cret", "127.0.0.1", 8470)
    assert a.token_ok("s3cret") and not a.token_ok("s3creT") and not a.token_ok(None) and not a.token_ok("")
    assert a.host_ok("127.0.0.1:8470") and a.host_ok("localhost:8470") and a.host_ok("[::1]:8470")
    assert not a.host_ok("evil.example:8470")  # DNS rebinding: a foreign name resolving to loopback
    assert not a.host_ok("127.0.0.1:8471") and not a.host_ok(None)
    assert a.origin_ok(None, "127.0.0.1:8470")  # not a browser: the token decides
    assert a.origin_ok("http://127.0.0.1:8470", "127.0.0.1:8470")
    assert a.origin_ok("http://localhost:8470", "localhost:8470")
    assert not a.origin_ok("http://localhost:8470", "127.0.0.1:8470")
    assert not a.origin_ok("http://127.0.0.1:9999", "127.0.0.1:8470")
    assert not a.origin_ok("https://evil.example", "127.0.0.1:8470")
    assert not a.origin_ok("null", "127.0.0.1:8470")
    wide = Access("t", "0.0.0.0", 8470)
    assert wide.host_ok("groundstation.lab:8470")  # a server asked to listen beyond loopback
    assert wide.origin_ok("http://groundstation.lab:8470", "groundstation.lab:8470")


# ----------------------------------------------------------------------------------------- downlink format
def test_numbers_are_json_and_compact():
    assert [number(v) for v in (None, math.nan, math.inf, -math.inf, True, 3, np.int64(4))] == [
        "null", "null", "null", "null", "1", "3", "4"]  # fmt: skip
    assert number(0.1234567891) == "0.1234568" and number(np.float32(2.5)) == "2.5"
    assert number(12345.678912, 10) == "12345.67891" and number(1e-9) == "1e-09"
    rows = json.loads(encode_rows([[1234.56789012, math.nan, 2.0], [1.5, None, np.float64(-0.25)]]))
    assert rows == {"rows": [[1234.56789, None, 2], [1.5, None, -0.25]]}


def _read(reader: Any) -> bytes | None:
    """A hub reader's next read without its ``id:`` lines (where it is, for a browser to resume from)."""
    data = reader.read(0.01)
    return None if data is None else re.sub(rb"id: [^\n]*\n\n", b"", data)


def test_hub_history_late_and_slow_readers():
    now = [100.0]
    hub = Hub(budget=1000, clock=lambda: now[0])
    early = hub.reader()
    assert _read(early) == b""  # nothing before the run is described
    hub.set_info(b"I")
    for k in range(5):
        hub.publish(bytes([65 + k]) * 100)
    now[0] += 2.5
    history = b"I" + b"A" * 100 + b"B" * 100 + b"C" * 100 + b"D" * 100 + b"E" * 100
    assert _read(early) == history + caught_up(2.5)  # the history, then how old the progress is
    assert _read(early) == b""  # waited, nothing new
    hub.publish(b"s" * 10, progress=False)  # a counter of the server's: not the run's progress
    assert _read(early) == b"s" * 10  # the history was ended once
    late = hub.reader()
    now[0] += 1.0
    assert _read(late) == history + b"s" * 10 + caught_up(3.5)  # a late joiner gets the whole history
    hub.publish(b"F" * 100)
    assert _read(early) == _read(late) == b"F" * 100
    late = hub.reader()
    assert _read(late).startswith(b"IAAA")
    for k in range(10):  # past the budget: the oldest go, trimmed to 90 %
        hub.publish(bytes([71 + k]) * 100)
    assert hub.stats.trimmed_chunks >= 6 and hub.stats.skipped_chunks == 0
    data = _read(early)  # this reader had read up to F; G.. were published, the oldest trimmed
    assert hub.stats.skipped_chunks > 0 and data.endswith(b"P" * 100) and len(data) <= 1000
    hub.close()
    assert early.read(0.01) is None and late.read(0.01) is not None and late.read(0.01) is None


def test_a_reader_resumes_where_its_browser_left_off_without_the_history():
    now = [0.0]
    hub = Hub(budget=10_000, clock=lambda: now[0])
    hub.set_info(b"I")
    first = hub.reader()
    hub.publish(b"A" * 100)
    last_id = re.findall(rb"id: ([^\n]*)\n\n", first.read(0.01))[-1].decode()
    hub.publish(b"B" * 100)  # while the browser was away
    hub.publish(b"C" * 100)
    now[0] = 1.5
    again = hub.reader()
    assert hub.resume(again, last_id) and hub.stats.streams_resumed == 1
    assert _read(again) == b"B" * 100 + b"C" * 100 + caught_up(1.5)  # what it missed, no info, no history
    stale = last_id.rsplit(".", 1)[0] + ".99"  # a place past the newest chunk
    other = "f" * 16 + "." + last_id.split(".", 1)[1]  # another hub's (a server started again)
    for bad in (None, "", "x", stale, other, last_id + "0" * 20, f" {last_id}x"):
        fresh = hub.reader()
        assert not hub.resume(fresh, bad)
        assert _read(fresh).startswith(b"IAAAA")  # afresh: info and the whole history


# ----------------------------------------------------------------------------------------- commands
@pytest.mark.parametrize(
    ("body", "message"),
    [
        (b"{", "not JSON"),
        (b"[]", "expected a JSON object"),
        (b'{"command": "selfdestruct"}', "command must be one of"),
        (b'{"command": "arm", "force": true}', "unknown field(s) for arm: force"),
        (b'{"command": "slew", "roll_deg": 0, "pitch_deg": 0}', "yaw_deg must be a number"),
        (b'{"command": "slew", "roll_deg": 0, "pitch_deg": 95, "yaw_deg": 0}', "pitch_deg must lie within"),
        (b'{"command": "slew", "roll_deg": "0", "pitch_deg": 0, "yaw_deg": 0}', "roll_deg must be a number"),
        (b'{"command": "slew", "roll_deg": true, "pitch_deg": 0, "yaw_deg": 0}', "roll_deg must be a number"),
        (b'{"command": "disarm", "pad": "' + b"x" * 5000 + b'"}', "at most 4096"),
        # UTF-16 (json.loads of bytes takes it): its bytes hid brackets from the nesting check
        ('{"command": "hold"}'.encode("utf-16"), "not UTF-8"),
    ],
)
def test_malformed_commands_say_what_is_wrong(body, message):
    with pytest.raises(InputFormatError, match=message.replace("(", r"\(").replace(")", r"\)")):
        parse_command(body, 1)


def test_a_slew_command_is_the_yaw_pitch_roll_attitude():
    cmd = parse_command(b'{"command": "slew", "roll_deg": 10, "pitch_deg": -20, "yaw_deg": 135}', 7, "me")
    assert (cmd.id, cmd.name, cmd.target, cmd.remote) == (7, "slew", (10.0, -20.0, 135.0), "me")
    R = euler_zyx(*cmd.target)
    rx, ry, rz = (so3.exp(np.radians(a) * np.eye(3)[i]) for i, a in enumerate(cmd.target))
    np.testing.assert_allclose(R, rz @ ry @ rx, atol=1e-12)  # Rz(yaw) Ry(pitch) Rx(roll)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


# ----------------------------------------------------------------------------------------- the live feed
class _NoHost:
    columns = ("t", "x")


def test_the_live_feed_drops_and_counts_instead_of_waiting():
    feed = LiveFeed(capacity=10)
    for k in range(25):  # no pump draining it: the control path must never wait
        feed.row({"t": float(k), "x": 1.0})
    feed.event({"t": 0.0, "kind": "armed"})
    assert feed.stats.rows == 10 and feed.stats.dropped_rows == 15 and feed.stats.dropped_events == 1
    batch = feed.poll()
    assert len(batch.rows) == 10 and batch.status["feed_dropped_rows"] == 15
    feed.event({"t": 1.0, "kind": "armed"})
    assert feed.poll().events == [{"t": 1.0, "kind": "armed"}]
    assert not feed.poll()  # nothing new, counters unchanged: no message at all


# ----------------------------------------------------------------------------------------- run directories
def _write_run_dir(d: Path, rows: int, summary: bool = True) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    (d / "telemetry.csv").write_text(
        "t,phase,point_err_deg\n" + "".join(f"{k / 50},1,{30 - k}\n" for k in range(rows))
    )
    (d / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n')
    if summary:
        (d / "summary.json").write_text(
            json.dumps({"exit": "completed", "link": {"frames_in": 9, "rtt": {"p99_ms": 1.5}}})
        )
    return d


def test_a_run_directory_is_followed_while_it_is_written(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    tel = d / "telemetry.csv"
    tel.write_text("t,phase,point_err_deg\n0.0,0,")  # the header and half a row
    src = RunDirSource(d)
    batch = src.poll()
    assert batch.info["columns"] == ["t", "phase", "point_err_deg"] and batch.rows == []
    assert batch.info["mode"] == "replay" and batch.info["uplink"] is False
    assert "no scenario.toml" in batch.info["note"] and batch.status["state"] == "following"
    with tel.open("a") as f:
        f.write("5.0\n0.02,0,4.5\n0.04,oops,1\n0.06,1")  # completes the row, one more, a bad one, half one
    (d / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\nnot json\n{"t": 0.1, "kind": "sp')
    batch = src.poll()
    assert batch.rows == [[0.0, 0.0, 5.0], [0.02, 0.0, 4.5]] and batch.events == [{"t": 0.0, "kind": "armed"}]
    assert src.bad_rows == 1 and src.bad_events == 1 and batch.status["bad_rows"] == 1
    assert not src.finished
    with tel.open("a") as f:
        f.write(",\n")
    with (d / "events.jsonl").open("a") as f:
        f.write('in_up"}\n')
    (d / "summary.json").write_text(
        json.dumps({"exit": "completed", "link": {"frames_in": 9, "rtt": {"p99_ms": 1.5}}})
    )
    batch = src.poll()
    assert batch.rows == [[0.06, 1.0, None]] and batch.events == [{"t": 0.1, "kind": "spin_up"}]
    assert src.finished and batch.status["state"] == "finished" and batch.status["exit"] == "completed"
    assert batch.link == [{"t": 0.06, "frames_in": 9, "rtt.p99_ms": 1.5}]
    assert not src.poll()  # finished: nothing more, ever


def test_a_killed_run_directory_replays_what_it_holds(tmp_path):
    d = _write_run_dir(tmp_path / "killed", 20, summary=False)
    with (d / "telemetry.csv").open("a") as f:
        f.write("0.4,1,")  # torn by SIGKILL
    src = RunDirSource(d, follow=False)
    batch = src.poll()
    assert len(batch.rows) == 20 and batch.status["state"] == "read" and not src.finished


def test_what_is_not_a_run_directory_is_a_clear_error(tmp_path):
    with pytest.raises(InputFormatError, match="not a directory"):
        RunDirSource(tmp_path / "nowhere")
    with pytest.raises(InputFormatError, match="not a run directory"):
        RunDirSource(tmp_path)


# ----------------------------------------------------------------------------------------- the server
@pytest.fixture
def replay_station(tmp_path):
    d = _write_run_dir(tmp_path / "20260101-000000-test", 120)
    with GroundStation.replay(d, bind="127.0.0.1:0") as station:
        wait_for(lambda: station.info, 10, "the run directory read")
        yield station


def test_a_run_directory_s_info_is_there_when_the_station_is(tmp_path):
    """Asked at once, as a script does after reading the printed URL (a CI run on a busy machine asked
    before the pump's first pass and got an empty answer): the first pass is done before serving."""
    d = _write_run_dir(tmp_path / "run", 10)
    with GroundStation.replay(d, bind="127.0.0.1:0") as station:
        status, info = request(station, "GET", f"/api/info?token={station.token}", token=None)
    assert status == 200 and info["mode"] == "replay" and info["run"] == "run"


def test_a_live_station_before_its_run_says_it_is_waiting():
    with GroundStation.live(bind="127.0.0.1:0") as station:
        status, body = request(station, "GET", f"/api/info?token={station.token}", token=None)
    assert status == 503 and body == {"state": "waiting", "error": "no run has started yet"}


def test_the_page_and_its_vendored_libraries_are_served_without_a_token(replay_station):
    status, page = request(replay_station, "GET", "/", token=None)
    assert status == 200 and "/static/vendor/uPlot.iife.min.js" in page and "//cdn" not in page
    for name in ("app.js", "store.js", "plots.js", "view3d.js", "panels.js", "uplink.js", "gcs.css",
                 "vendor/uPlot.iife.min.js", "vendor/uPlot.min.css", "vendor/uPlot.LICENSE.txt"):  # fmt: skip
        status, body = request(replay_station, "GET", f"/static/{name}", token=None)
        assert status == 200 and body, name
        assert "http://" not in body.replace("http://www.", "") or name.startswith("vendor"), name
    for bad in ("/static/../station.py", "/static/%2e%2e/station.py", "/static/vendor", "/static/nope.js"):
        assert request(replay_station, "GET", bad, token=None)[0] == 404, bad


def test_the_api_needs_the_token_and_the_pages_own_origin(replay_station):
    port = replay_station.port
    assert request(replay_station, "GET", "/api/info", token=None)[0] == 401
    assert request(replay_station, "GET", "/api/info", token="guess")[0] == 401
    status, info = request(replay_station, "GET", f"/api/info?token={replay_station.token}", token=None)
    assert status == 200 and info["mode"] == "replay" and info["columns"][:2] == ["t", "phase"]
    foreign = {"Origin": "http://evil.example"}
    assert request(replay_station, "GET", "/api/info", headers=foreign)[0] == 403
    assert (
        request(replay_station, "GET", "/api/info", headers={"Origin": f"http://127.0.0.1:{port}"})[0] == 200
    )
    assert request(replay_station, "GET", "/api/info", headers={"Host": f"rebind.example:{port}"})[0] == 403
    assert request(replay_station, "POST", "/api/command", {"command": "disarm"})[0] == 409  # a replay
    assert request(replay_station, "OPTIONS", "/api/command", headers=foreign)[0] == 403
    rejected = replay_station.stats()["server"]["rejected"]
    assert rejected == {"token": 2, "origin": 2, "host": 1}


def test_the_stream_of_a_finished_run_directory(replay_station):
    with socket.create_connection(("127.0.0.1", replay_station.port), timeout=10) as s:
        s.sendall(
            f"GET /api/stream?token={replay_station.token} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode()
        )
        data = b""
        while b'"state":"finished"' not in data:
            chunk = s.recv(65536)
            assert chunk, data[-300:]
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    assert b"200" in head.split(b"\r\n")[0] and b"text/event-stream" in head
    messages = [m for m in body.decode().split("\n\n") if m.startswith("event:")]
    kinds = [m.split("\n")[0].removeprefix("event: ") for m in messages]
    assert kinds[0] == "info" and "rows" in kinds and "events" in kinds and "link" in kinds
    rows = [
        r
        for m in messages
        if m.startswith("event: rows")
        for r in json.loads(m.split("data: ", 1)[1])["rows"]
    ]
    assert len(rows) == 120 and rows[0] == [0, 1, 30] and rows[-1][2] == 30 - 119


def test_commands_are_checked_before_they_are_queued(tmp_path):
    with GroundStation.live(bind="127.0.0.1:0") as station:
        assert command(station, {"command": "disarm"}, token="guess")[0] == 401
        assert command(station, {"command": "disarm"}, headers={"Origin": "http://evil.example"})[0] == 403
        status, answer = command(station, {"command": "hold"})  # no run yet: nothing would carry it out
        assert (status, answer["reason"]) == (409, "no_run") and "no run yet" in answer["error"]
        assert station.uplink is not None and station.uplink.stats.no_run == 1
        station.uplink.open()  # what the run's start does (LiveFeed.started)
        status, answer = command(station, {"command": "warp"})
        assert status == 400 and "command must be one of" in answer["error"]
        status, _ = request(
            station, "POST", "/api/command", b'{"command": "arm"}', headers={"Content-Type": "text/plain"}
        )
        assert status == 415
        ids = []
        for _ in range(INBOX):
            status, answer = command(station, {"command": "hold"})
            assert status == 202 and answer["status"] == "queued"
            ids.append(answer["id"])
        assert ids == list(range(1, INBOX + 1))
        assert command(station, {"command": "hold"})[0] == 503  # nobody drains the inbox: refused, not queued
        # a full inbox still answers a malformed request as such (400, logged), not "busy"
        status, answer = command(station, {"command": "warp"})
        assert status == 400 and "command must be one of" in answer["error"]
        st = station.stats()["uplink"]
        assert st["accepted"] == INBOX and st["inbox_full"] == 1 and st["rejected"] == 5


# ----------------------------------------------------------------------------------------- end to end
def test_the_uplink_through_a_lockstep_run_and_the_emulated_board(tmp_path):
    """Disarm, arm, slew, hold and abort from the ground, each acknowledged by the board (or applied by the
    host), logged with its origin; a request with a wrong token is logged as rejected."""
    sc = quick_scenario()
    with GroundStation.live(bind="127.0.0.1:0") as station:
        runner = RunInThread(sc, RunOptions(out_root=tmp_path, duration_s=60.0, pace=2.0), station)
        runner.wait_event(lambda e: e["kind"] == "slew_start", what="the slew's start")
        assert command(station, {"command": "disarm"})[0] == 202
        acked = runner.wait_event(lambda e: e["kind"] == "command" and e["status"] == "acked", what="the ack")
        assert acked["origin"] == "gcs" and acked["command"] == "disarm" and acked["id"] == 1
        disarmed = runner.wait_event(lambda e: e["kind"] == "board_state" and e["old"] == "ARMED")
        assert command(station, {"command": "arm"}, token="wrong")[0] == 401
        assert command(station, {"command": "arm"})[0] == 202
        runner.wait_event(lambda e: e["kind"] == "command" and e["id"] == 2 and e["status"] == "acked")
        runner.wait_event(
            lambda e: e["kind"] == "board_state" and e["new"] == "ARMED" and e["t"] > acked["t"]
        )
        # a slew sent in the Arm's warm-up is deferred to its end (docs/gcs.md): sent once steering again
        runner.wait_event(
            lambda e: e["kind"] == "resume" and e["t"] > acked["t"], what="the Arm's warm-up end"
        )
        assert command(station, {"command": "slew", "roll_deg": 5, "pitch_deg": -3, "yaw_deg": 40})[0] == 202
        slew = runner.wait_event(
            lambda e: e["kind"] == "command" and e["id"] == 3 and e["status"] != "received"
        )
        assert slew["status"] == "applied" and slew["target_euler_deg"] == [5.0, -3.0, 40.0]
        np.testing.assert_allclose(so3.exp(np.array(slew["target_r"])), euler_zyx(5, -3, 40), atol=1e-9)
        assert command(station, {"command": "hold"})[0] == 202
        hold = runner.wait_event(lambda e: e["kind"] == "command" and e["id"] == 4)
        assert hold["status"] == "applied" and hold["slew_s"] < 1e-6  # hold here: a slew of no angle
        assert command(station, {"command": "abort"})[0] == 202
        result = runner.join()
    assert result.summary["exit"] == (
        "aborted: from the ground station (command 5: board disarmed, telemetry says DISARMED)"
    )
    events = read_events(result.run_dir / "events.jsonl")[0]
    mine = [e for e in events if e["kind"] == "command"]
    assert all(e["origin"] == "gcs" for e in mine)
    assert [(e["id"], e["status"]) for e in mine if e["id"] is not None] == [
        (1, "sent"), (1, "acked"), (2, "sent"), (2, "acked"), (3, "applied"), (4, "applied"), (5, "sent"),
        (5, "acked")]  # fmt: skip
    assert [e["reason"] for e in mine if e["status"] == "rejected"] == ["token"]
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    t, state = tel["t"], tel["board_state"]
    after_disarm = (t > disarmed["t"]) & (t < next(e["t"] for e in mine if e["id"] == 2))
    assert after_disarm.any() and np.all(state[after_disarm] == int(BoardState.DISARMED))
    assert state[-1] == int(BoardState.DISARMED)  # the abort left the board disarmed
    assert result.summary["sim_s"] < 30.0  # the abort ended the run long before its 60 s


def test_a_slew_before_the_warm_up_ends_is_refused(tmp_path):
    with GroundStation.live(bind="127.0.0.1:0") as station:
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=0.5, pace=1.0), station
        )
        runner.wait_event(lambda e: e["kind"] == "armed", what="arming")
        assert command(station, {"command": "slew", "roll_deg": 0, "pitch_deg": 0, "yaw_deg": 0})[0] == 202
        refused = runner.wait_event(lambda e: e["kind"] == "command" and e["id"] == 1)
        result = runner.join()
    assert refused["status"] == "refused" and "warm-up" in refused["reason"]
    assert result.summary["exit"] == "completed"


def test_the_stream_carries_every_row_of_a_live_run_and_a_stalled_browser_holds_nothing_up(tmp_path):
    with GroundStation.live(bind="127.0.0.1:0") as station:
        stalled = socket.create_connection(("127.0.0.1", station.port))  # opens a stream, never reads it
        stalled.sendall(f"GET /api/stream?token={station.token} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode())
        reader = socket.create_connection(("127.0.0.1", station.port), timeout=30)
        reader.sendall(f"GET /api/stream?token={station.token} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode())
        result = run(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=3.0, observer=station.observer)
        )
        station.close()  # a last pump cycle first
        data = b""
        while chunk := reader.recv(1 << 20):
            data += chunk
        stalled.close()
        reader.close()
    rows = [r for m in data.decode().split("\n\n") if m.startswith("event: rows")
            for r in json.loads(m.split("data: ", 1)[1])["rows"]]  # fmt: skip
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    assert len(rows) == tel.rows and station.stats()["feed"]["dropped_rows"] == 0
    np.testing.assert_allclose([r[0] for r in rows], tel["t"], rtol=1e-9)
    assert station.stats()["hub"]["streams_opened"] == 2


def test_pacing_holds_a_lockstep_run_to_the_wall_clock(tmp_path):
    sc = quick_scenario()
    start = time.monotonic()
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=1.0, pace=4.0))
    wall = time.monotonic() - start
    sim = result.summary["sim_s"]
    assert wall >= sim / 4.0 * 0.95  # never ahead of 4x the wall clock
    assert "pace" in result.summary["tasks"]
    with pytest.raises(ConfigError, match="is for lockstep runs"):
        run(sc, RunOptions(out_root=tmp_path, lockstep=False, pace=2.0))
    with pytest.raises(ConfigError, match="a factor of the wall clock of at least 0.001"):
        run(sc, RunOptions(out_root=tmp_path, pace=-1.0))


def _hil(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *args], capture_output=True, text=True, **kw)


def test_the_command_line_says_what_is_wrong(tmp_path):
    bad = _hil("gcs", str(tmp_path / "nowhere"), timeout=60)
    assert bad.returncode == 2 and "not a directory" in bad.stderr
    bad = _hil("run", "--realtime", "--pace", "2", "--out", str(tmp_path), "--no-plots", timeout=60)
    assert bad.returncode == 2 and "--pace" in bad.stderr
    bad = _hil("run", "--gcs", "127.0.0.1:http", "--out", str(tmp_path), "--no-plots", timeout=60)
    assert bad.returncode == 2 and "the port must be a number" in bad.stderr


def test_hil_gcs_serves_a_run_directory_at_the_url_it_prints(tmp_path):
    d = _write_run_dir(tmp_path / "run", 10)
    proc = subprocess.Popen([sys.executable, "-m", "hil", "gcs", str(d), "--gcs", "127.0.0.1:0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert line.startswith("ground station: http://127.0.0.1:"), line
        url = line.split(": ", 1)[1].strip()
        import urllib.request

        api = url.replace("/?token=", "/api/info?token=")
        with urllib.request.urlopen(api, timeout=10) as answer:
            info = json.loads(answer.read())
        assert info["mode"] == "replay" and info["run"] == "run"
    finally:
        proc.terminate()
        proc.wait(10)


def test_hil_run_gcs_prints_the_url_and_serves_the_run(tmp_path):
    done = _hil("run", "--gcs", "127.0.0.1:0", "--pace", "0", "--duration", "0.5", "--out", str(tmp_path),
                "--no-plots", timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    line = next(x for x in done.stderr.splitlines() if x.startswith("ground station: "))
    assert line.startswith("ground station: http://127.0.0.1:") and "/?token=" in line
    assert "exit              completed" in done.stdout


def test_an_alarm_acknowledgement_is_checked_queued_and_logged_as_an_event(tmp_path):
    """``POST /api/ack`` during a live run: a malformed one is refused (400, logged as rejected); a good
    one is answered 202 and becomes an ``alarm_ack`` record in ``events.jsonl`` with who sent it."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=60.0, pace=1.0), station
        )
        runner.wait_event(lambda e: e["kind"] == "armed", what="arming")
        status, answer = request(station, "POST", "/api/ack", {"alarm": "Pointing Error!"})
        assert status == 400 and "alarm must be an alarm's key" in answer["error"]
        status, answer = request(station, "POST", "/api/ack", {"alarm": "point_err", "raised_t": 3.5})
        assert status == 202 and answer == {"alarm": "point_err", "status": "queued"}
        assert request(station, "POST", "/api/ack", {"alarm": "x"}, token="guess")[0] == 401
        ack = runner.wait_event(lambda e: e["kind"] == "alarm_ack", what="the acknowledgement logged")
        assert (ack["alarm"], ack["raised_t"], ack["origin"], ack["remote"]) == (
            "point_err", 3.5, "gcs", "127.0.0.1")  # fmt: skip
        assert command(station, {"command": "abort"})[0] == 202
        runner.join()
    reasons = [e["reason"] for e in runner.events() if e["kind"] == "command" and e["status"] == "rejected"]
    assert reasons == ["format", "token"]


def test_every_command_answered_queued_has_a_status_even_as_the_run_ends(tmp_path):
    """Commands sent while a run ends, until the station closes: each one answered 202 ``queued`` has a
    status in the run's record (carried out on a tick, or refused as the run has ended), and after the
    run's loop ended the answer is 409. (Commands accepted in the ~40 ms between the last tick and the
    summary were answered 202 and then neither carried out nor logged.) The run is paced (at most 4× real
    time): unpaced, its second after the slew's start took ~30 ms of wall time, which a loaded machine's
    HTTP round trips could miss entirely (CI once had no command queued)."""
    sc = quick_scenario()
    queued: list[int] = []
    answers: list[int] = []
    with GroundStation.live(bind="127.0.0.1:0") as station:
        runner = RunInThread(sc, RunOptions(out_root=tmp_path, duration_s=1.0, pace=4.0), station)
        runner.wait_event(lambda e: e["kind"] == "slew_start", what="the slew's start")
        while runner.thread.is_alive():
            status, answer = command(station, {"command": "hold"})
            answers.append(status)
            if status == 202:
                queued.append(answer["id"])
        for _ in range(3):  # the run has ended; the station still serves
            answers.append(command(station, {"command": "hold"})[0])
        result = runner.join()
    assert queued and answers[-1] == 409 and set(answers) <= {202, 409, 503}
    events = read_events(result.run_dir / "events.jsonl")[0]
    statuses = {e["id"]: e["status"] for e in events if e["kind"] == "command" and e["id"] is not None}
    assert set(queued) <= set(statuses) and set(statuses.values()) <= {"applied", "refused"}
    operator = {o["id"] for o in result.summary["operator"]}
    assert set(queued) <= operator
