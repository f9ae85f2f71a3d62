"""Hostile clients against the ground station's server, through real sockets (http.client and raw ones):
whatever a client sends, it gets an answer or is cut off by a stated limit, every request turned away is
logged in the run's events as ``rejected``, and no traceback reaches stderr. These are the tests any
server the station moves onto must pass.

Regression tests for issue 26, finding 7: a body of ``[`` x 4000 with a valid token printed a
RecursionError traceback and dropped the connection unanswered and unlogged; Content-Length refusals were
not logged; ``{"command": "hold", "command": "disarm"}`` disarmed; 400 idle sockets held 405 threads; a
client sending a byte a second held its thread for ever."""

from __future__ import annotations

import http.client
import json
import select
import socket
import threading
import time
from typing import Any

import pytest
from gcs_support import RunInThread, answer_of, quick_scenario, request, wait_for
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation
from hil.gcs.server import MAX_CONNECTIONS
from hil.gcs.uplink import MAX_BODY, MAX_DEPTH, parse_command
from hil.link.sources.http_guard import HttpLimits
from hil.runtime import RunOptions
from hil.runtime.observer import RunAborted
from hil.runtime.operator import COMMANDS
from protocol.errors import InputFormatError, LinkError

ANSWERS = {202, 400, 401, 403, 413, 503}


def _post(
    station: GroundStation,
    body: bytes,
    token: str | None = "station",
    origin: str | None = None,
    timeout_s: float = 10.0,
) -> tuple[int, Any]:
    """POST ``body`` as a command (application/json) on a fresh connection: ``(status, answer)``."""
    headers = {"Content-Type": "application/json"}
    if origin is not None:
        headers["Origin"] = origin
    conn = http.client.HTTPConnection("127.0.0.1", station.port, timeout=timeout_s)
    try:
        hdrs = {"Host": f"127.0.0.1:{station.port}", **headers}
        if token is not None:
            hdrs["Authorization"] = f"token {station.token if token == 'station' else token}"
        conn.request("POST", "/api/command", body=body, headers=hdrs)
        return answer_of(conn)
    finally:
        conn.close()


# ----------------------------------------------------------------------------------------- parsing
@pytest.mark.parametrize(
    ("body", "message"),
    [
        (b"[" * 4000, f"nested 4000 deep (at most {MAX_DEPTH})"),
        (b'{"command": ' + b"[" * 9 + b"]" * 9 + b"}", "nested 10 deep"),
        (b'{"command": "hold", "command": "disarm"}', "the key 'command' is given twice"),
        (b'{"command": "slew", "roll_deg": 1, "roll_deg": 2, "pitch_deg": 0, "yaw_deg": 0}', "given twice"),
        (b'{"command": "arm", "x": {"a": 1, "a": 1}}', "the key 'a' is given twice"),
        (b"\xff\xfe", "not UTF-8"),
    ],
)
def test_bodies_nested_too_deep_or_with_a_key_twice_are_refused_before_they_mean_anything(body, message):
    with pytest.raises(InputFormatError, match=message.replace("(", r"\(").replace(")", r"\)")):
        parse_command(body, 1)


def test_brackets_inside_strings_are_not_nesting():
    command = parse_command(b'{"command": "hold"}', 1)
    assert command.name == "hold"
    with pytest.raises(InputFormatError, match="command must be one of"):
        parse_command(b'{"command": "' + b"[" * 100 + b'"}', 1)  # a string: refused for its value


# ----------------------------------------------------------------------------------------- a run's record
def test_turned_away_commands_are_answered_and_logged_in_the_runs_events(tmp_path, capfd):
    """A nested body, a key given twice, a body over the cap, a wrong type: each answered, each logged as
    ``rejected`` with its reason; the board is not disarmed by the duplicate key; nothing on stderr."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=60.0, pace=1.0), station
        )
        runner.wait_event(lambda e: e["kind"] == "armed", what="arming")
        status, answer = _post(station, b"[" * 4000)
        assert status == 400 and "nested 4000 deep" in answer["error"]
        status, answer = _post(station, b'{"command": "hold", "command": "disarm"}')
        assert status == 400 and "given twice" in answer["error"]
        status, answer = _post(station, b'{"command": "hold", "pad": "' + b"x" * 5000 + b'"}')
        assert status == 413 and f"larger than {MAX_BODY}" in answer["error"]
        status, _ = request(
            station, "POST", "/api/command", b'{"command": "disarm"}', {"Content-Type": "text/plain"}
        )
        assert status == 415
        rejected = runner.wait_event(
            lambda e: e["kind"] == "command" and e["status"] == "rejected" and e["reason"] == "size",
            what="the refusals in the run's events",
        )
        assert _post(station, b'{"command": "abort"}')[0] == 202
        result = runner.join()
    events = [e for e in runner.events() if e["kind"] == "command"]
    refused = [(e["reason"], e["detail"]) for e in events if e["status"] == "rejected"]
    assert [r for r, _ in refused] == ["format", "format", "size", "format"]
    assert "nested 4000 deep" in refused[0][1] and "given twice" in refused[1][1]
    assert "5" in rejected["detail"] and rejected["origin"] == "gcs" and rejected["remote"] == "127.0.0.1"
    assert [e["command"] for e in events if e["id"] is not None] == ["abort", "abort"]  # sent, acked
    assert result.summary["exit"].startswith("aborted: from the ground station")
    assert "Traceback" not in capfd.readouterr().err


# ----------------------------------------------------------------------------------------- connections
def test_400_idle_sockets_hold_a_bounded_number_of_threads_and_the_page_is_still_served():
    base = threading.active_count()
    with GroundStation.live(bind="127.0.0.1:0") as station:
        idle = []
        try:
            for _ in range(400):
                idle.append(socket.create_connection(("127.0.0.1", station.port), timeout=10))
            bound = base + 2 + 2 * MAX_CONNECTIONS  # the accept and pump threads; 2 x the cap at worst
            wait_for(lambda: threading.active_count() <= bound, 10.0, f"at most {bound} threads")
            status, page = request(station, "GET", "/", token=None)
            assert status == 200 and "<html" in page.lower()
            counters = station.stats()["server"]
            assert counters["connections_evicted"] >= 400 - MAX_CONNECTIONS
            assert counters["rejected"]["evicted"] == counters["connections_evicted"]
        finally:
            for sock in idle:
                sock.close()


def test_a_client_that_sends_a_byte_a_second_is_cut_off_at_the_request_deadline():
    """Slowloris: a request head dripped a byte at a time never completes; it is closed at 1 s."""
    limits = HttpLimits(max_body=MAX_BODY, timeout_s=1.0, max_connections=MAX_CONNECTIONS)
    with GroundStation.live(bind="127.0.0.1:0", limits=limits) as station:
        drip = socket.create_connection(("127.0.0.1", station.port), timeout=10)
        head = b"GET /api/info HTTP/1.0\r\nHost: 127.0.0.1\r\n" + b"X-Pad: " + b"a" * 200
        start = time.monotonic()
        closed_after = None
        try:
            for byte in head:  # 0.1 s apart: each read is quick, the request never is
                readable, _, _ = select.select([drip], [], [], 0.1)
                if readable and drip.recv(1) == b"":
                    closed_after = time.monotonic() - start
                    break
                drip.sendall(bytes([byte]))
        except OSError:  # reset by the server
            closed_after = time.monotonic() - start
        finally:
            drip.close()
        assert closed_after is not None, "the dripping client was never cut off"
        assert 0.9 <= closed_after <= 8.0
        assert wait_for(lambda: station.stats()["server"]["rejected"].get("timeout") == 1, 5.0, "the count")
        assert request(station, "GET", "/", token=None)[0] == 200


def test_when_every_connection_is_busy_a_new_one_is_closed_unanswered_and_counted():
    limits = HttpLimits(max_body=MAX_BODY, timeout_s=10.0, max_connections=3)
    with GroundStation.live(bind="127.0.0.1:0", limits=limits) as station:
        streams = []
        for _ in range(3):  # a stream is being served: never evicted
            s = socket.create_connection(("127.0.0.1", station.port), timeout=10)
            s.sendall(f"GET /api/stream?token={station.token} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode())
            assert s.recv(64).split(b" ")[1] == b"200"  # tornado answers HTTP/1.1 to a 1.0 request
            streams.append(s)
        extra = socket.create_connection(("127.0.0.1", station.port), timeout=10)
        try:
            assert extra.recv(1) == b""
        except ConnectionResetError:
            pass  # closed unanswered either way
        extra.close()
        counters = station.stats()["server"]
        assert counters["connections_refused"] == 1 and counters["rejected"]["connections"] == 1
        for s in streams:
            s.close()


# ----------------------------------------------------------------------------------------- any body
class _ModelHost:
    """What :meth:`Uplink.service` needs of a host — the run's event log and the operator's hooks —
    recording everything and carrying nothing out (there is no board)."""

    phase = None  # no run's phase: a hold or slew is not steered at once
    in_control = False
    target = None
    aborting = None  # the run's operator log's: no abort under way

    def __init__(self) -> None:
        self.records: list[dict[str, Any]] = []
        self.events = self
        self.operator = self  # the run's operator log (its ids and abort), kept here as the records

    def used(self, command: Any) -> bool:
        return False

    def write(self, t: float, kind: str, **fields: Any) -> None:
        self.records.append({"t": t, "kind": kind, **fields})

    def record_command(self, t: float, command: Any, status: str, **fields: Any) -> None:
        self.records.append({"t": t, "kind": "command", "id": command.id, "status": status})

    def retarget(self, t: float, target: Any) -> str:
        return "a model host takes no targets"

    def arm(self, t: float, origin: str) -> Any:
        raise LinkError("a model host has no board")

    disarm = arm


_json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=10), inner, max_size=5),
    max_leaves=30,
)
_angles = st.floats(-400, 400) | st.integers(-400, 400) | st.text(max_size=3) | st.none()
_commands = st.fixed_dictionaries(
    {"command": st.sampled_from([*COMMANDS, "warp", ""])},
    optional={"roll_deg": _angles, "pitch_deg": _angles, "yaw_deg": _angles, "extra": _json_values},
)
bodies = st.one_of(
    st.binary(max_size=6000),
    _json_values.map(lambda v: json.dumps(v).encode()),
    _commands.map(lambda v: json.dumps(v).encode()),
    st.builds(
        lambda n, opener: opener * n, st.integers(1, 6000), st.sampled_from([b"[", b'{"a":', b'[{"x":'])
    ),
    st.builds(
        lambda a, b: f'{{"command": "{a}", "command": "{b}"}}'.encode(),
        st.sampled_from(COMMANDS),
        st.sampled_from(COMMANDS),
    ),
)


def test_any_command_body_gets_an_answer_in_bounded_time_and_every_refusal_is_logged(capfd):
    """Random bodies (and tokens, and origins) through real requests: always one of the documented answers
    within 10 s — never a dropped connection, never a traceback — and each refusal one ``rejected``
    record in what the control thread logs (:meth:`Uplink.service`, here into a model host)."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        uplink = station.uplink
        assert uplink is not None
        uplink.open()  # what the run's start does (LiveFeed.started): before it, every command is a 409
        host = _ModelHost()
        own = f"http://127.0.0.1:{station.port}"

        tokens = st.sampled_from(["station", "station", "station", "wrong", None])
        origins = st.sampled_from([None, None, own, "http://evil.example"])

        @settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
        @given(bodies, tokens, origins)
        def one(body: bytes, token: str | None, origin: str | None) -> None:
            start = time.monotonic()
            status, answer = _post(station, body, token=token, origin=origin)
            assert status in ANSWERS, (status, answer)
            assert time.monotonic() - start < 10.0
            before = len(host.records)
            try:
                uplink.service(host, time.monotonic())  # what the control thread does on its tick
            except RunAborted:
                pass  # an abort that could not reach a board ends a run; here, nothing
            new = host.records[before:]
            refusals = [r for r in new if r.get("status") == "rejected"]
            if status in (400, 401, 403, 413):
                assert len(refusals) == 1 and isinstance(answer, dict) and answer["reason"]
            else:
                assert not refusals and status == 202  # the inbox is drained after each request

        one()
    assert "Traceback" not in capfd.readouterr().err


# ----------------------------------------------------------------------------------------- raw requests
def _raw(station: GroundStation, data: bytes, timeout_s: float = 10.0) -> bytes:
    """Send ``data`` on a fresh socket, read the answer until the server closes."""
    with socket.create_connection(("127.0.0.1", station.port), timeout=timeout_s) as s:
        s.sendall(data)
        out = b""
        try:
            while chunk := s.recv(65536):
                out += chunk
        except ConnectionResetError:
            pass
    return out


@pytest.mark.parametrize(
    ("head", "body", "status", "reason"),
    [
        ("Transfer-Encoding: chunked", b"1000\r\n" + b"x" * 4096 + b"\r\n1\r\ny\r\n0\r\n\r\n", 413, "size"),
        ("Transfer-Encoding: gzip", b"", 501, "format"),
        ("Content-Length: 12abc", b"", 400, "format"),
        ("Content-Length: 5\r\nContent-Length: 6", b"{}", 400, "format"),
        ("X-Nothing: 1", b"", 411, "format"),
    ],
)
def test_bodies_refused_from_their_headers_are_answered_and_reported_once(head, body, status, reason):
    """The phone receiver's rules for a body (:func:`~hil.link.sources.http_guard.content_length`),
    checked before tornado reads it: a JSON answer with the status, one report."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        request_head = (
            f"POST /api/command HTTP/1.1\r\nHost: 127.0.0.1:{station.port}\r\n"
            f"Authorization: token {station.token}\r\nContent-Type: application/json\r\n{head}\r\n\r\n"
        )
        answer = _raw(station, request_head.encode() + body)
        first, _, rest = answer.partition(b"\r\n")
        assert first.split(b" ")[1] == str(status).encode(), answer[:300]
        assert json.loads(rest.partition(b"\r\n\r\n")[2])["reason"] == reason
        assert station.stats()["server"]["rejected"] == {reason: 1}


def test_what_tornado_refuses_itself_is_reported_not_printed(capfd, caplog):
    """A malformed request line (tornado's bare 400) and a request head over 16 KiB (closed): each one
    ``request`` rejection, logged in the run's events like any other; nothing printed or logged."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        assert _raw(station, b"HELLO\r\n\r\n").startswith(b"HTTP/1.1 400")
        _raw(station, b"GET / HTTP/1.1\r\nX-Pad: " + b"a" * 40000 + b"\r\n\r\n")
        wait_for(lambda: station.stats()["server"]["rejected"].get("request") == 2, 5.0, "two reports")
        uplink = station.uplink
        assert uplink is not None and uplink.stats.rejected == 2
        assert request(station, "GET", "/", token=None)[0] == 200
    assert "Malformed" not in capfd.readouterr().err and not caplog.records


def test_the_server_is_one_thread_whatever_the_clients_hold():
    base = threading.active_count()
    with GroundStation.live(bind="127.0.0.1:0") as station:
        streams = []
        try:
            for _ in range(10):
                s = socket.create_connection(("127.0.0.1", station.port), timeout=10)
                s.sendall(
                    f"GET /api/stream?token={station.token} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode()
                )
                streams.append(s)
            wait_for(lambda: station.hub.stats.streams_open == 10, 10.0, "ten streams")
            assert threading.active_count() == base + 2  # the server's IOLoop and the pump
        finally:
            for s in streams:
                s.close()
