"""Hostile peers against the live phone receivers, through real loopback sockets: whatever a peer on the
network sends, it costs that one message (counted, logged), never the receiver; HTTP bodies are bounded
whatever the headers say, slow and idle connections time out, and connections are capped.

Regression tests for issue 16, findings 4 (``b"[" * 60000`` to the UDP port ended the run) and 5
(``Content-Length: -1`` read to EOF past the cap, ``Content-Length: abc`` printed a traceback, no socket
timeout, a thread per idle connection), and issue 26, findings 4 and 7 (a flood handed to the estimator
in one batch, a 4 MB push decoded in the host's process, any path accepted, idle sockets locking a good
client out)."""

from __future__ import annotations

import contextlib
import http.client
import os
import signal
import socket
import struct
import threading
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.phone_push import INLINE_MAX, PhonePushSender, PhonePushServer, decode_push, encode_push
from hil.link.sources.phone_udp import PhoneUdpReceiver, PhoneUdpSender, encode_datagram
from hil.link.sources.stream import MAX_BATCH, MAX_QUEUE, PhoneReceiver

GOOD = SensorSample(1.0, SensorKind.GYR, (0.1, 0.2, 0.3))
HOSTILE_DATAGRAMS = [
    b"[" * 60000,  # finding 4: RecursionError in json.loads (and larger than any SensaGram datagram)
    b"[" * 3000,  # under the size cap: refused before the parser (which would raise RecursionError)
    b"1" * 4400,  # past Python's integer digit limit
    b'{"type":"android.sensor.gyroscope","timestamp":1,"values":[' + b"9" * 400 + b",0,0]}",  # OverflowError
    b'{"type":"android.sensor.gyroscope","timestamp":' + b"9" * 400 + b',"values":[0,0,0]}',
    b"\xff\xfe\x00",
    b"",
]


def _udp_address(receiver: PhoneUdpReceiver) -> tuple[str, int]:
    host, port = receiver.url.removeprefix("udp://").split(":")
    return host, int(port)


def _http_address(server: PhonePushServer) -> tuple[str, int]:
    host, port = server.url.removeprefix("http://").split("/")[0].split(":")
    return host, int(port)


def _wait(predicate, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


# =========================================================================== UDP (finding 4)
def test_datagrams_that_break_the_json_parser_cost_only_themselves(caplog):
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for data in HOSTILE_DATAGRAMS:
            raw.sendto(data, _udp_address(receiver))
        raw.close()
        PhoneUdpSender(receiver.url).send([GOOD])
        assert _wait(lambda: receiver.stats.samples == 1)
        receiver.check()  # the thread's error, if any, would be raised here
        assert receiver._thread.is_alive()
        assert receiver.drain() == [GOOD]
        assert receiver.stats.bad_messages == len(HOSTILE_DATAGRAMS)
    warnings = [r for r in caplog.records if "dropped" in r.getMessage()]
    assert 1 <= len(warnings) <= 2  # at most one a second: a flood does not flood the log
    assert "udp from 127.0.0.1" in warnings[0].getMessage()


def test_a_flood_of_hostile_datagrams_is_counted_and_the_stream_goes_on():
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sent = []
        for k in range(300):
            raw.sendto(HOSTILE_DATAGRAMS[k % len(HOSTILE_DATAGRAMS)], _udp_address(receiver))
            sample = SensorSample(2.0 + 0.005 * k, SensorKind.ACC, (0.0, float(k), 9.8))
            raw.sendto(encode_datagram(sample), _udp_address(receiver))
            sent.append(sample)
        raw.close()
        assert _wait(lambda: receiver.stats.messages + receiver.stats.bad_messages == 600)
        assert [s.xyz for s in _drain_all(receiver)] == [s.xyz for s in sent]  # every one, in order
        assert receiver.stats.bad_messages == 300


def _drain_all(receiver: PhoneReceiver) -> list[SensorSample]:
    """Drain until nothing is held, checking that no call hands over more than the batch bound."""
    out: list[SensorSample] = []
    while batch := receiver.drain():
        assert len(batch) <= MAX_BATCH
        out += batch
    return out


def test_a_flood_of_datagrams_reaches_the_consumer_in_bounded_batches_the_excess_held_or_dropped_oldest():
    """Issue 26, finding 4's UDP half: the estimator task was handed whatever had arrived, in one batch.
    Now each drain hands over at most MAX_BATCH; the rest is held for the next drains, up to MAX_QUEUE,
    beyond which the oldest are dropped and counted."""
    n = MAX_QUEUE + 1000
    sent = [SensorSample(3.0 + 1e-3 * k, SensorKind.GYR, (0.0, 0.0, float(k))) for k in range(n)]
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for sample in sent:
            raw.sendto(encode_datagram(sample), _udp_address(receiver))
        raw.close()
        assert _wait(lambda: receiver.stats.samples == n, 30.0)
        # every sample received is accounted for before any drain too: held, or dropped (it once said
        # held 0 for what came after the last drain, until the next)
        assert (receiver.stats.held, receiver.stats.overflow) == (MAX_QUEUE, n - MAX_QUEUE)
        first = receiver.drain()
        st_ = receiver.stats
        assert len(first) == MAX_BATCH and st_.held == MAX_QUEUE - MAX_BATCH
        assert st_.overflow == n - MAX_QUEUE  # the oldest went: counted, not silently lost
        rest = _drain_all(receiver)
        assert [s.xyz for s in first + rest] == [s.xyz for s in sent[-MAX_QUEUE:]]  # the newest, in order
        assert receiver.stats.held == 0


# =========================================================================== HTTP (finding 5)
def _request(server: PhonePushServer, head: bytes, body: bytes = b"", timeout_s: float = 5.0) -> bytes:
    """Send ``head`` (request line and headers, CRLF-terminated) and ``body`` on a fresh connection;
    everything the server answers until it closes or goes quiet."""
    with socket.create_connection(_http_address(server), timeout=timeout_s) as conn:
        conn.sendall(head + b"\r\n" + body)
        return _read_all(conn)


def _read_all(conn: socket.socket) -> bytes:
    out = b""
    while True:
        try:
            chunk = conn.recv(65536)
        except (TimeoutError, ConnectionResetError):
            return out
        if not chunk:
            return out
        out += chunk
        if b"\r\n\r\n" in out and out.endswith((b"ok", b"receiver")):
            return out


def _status(answer: bytes) -> int:
    return int(answer.split(b" ", 2)[1]) if answer.startswith(b"HTTP/1.1 ") else 0


def _post_head(*headers: str) -> bytes:
    return ("POST / HTTP/1.1\r\nHost: phone\r\n" + "".join(h + "\r\n" for h in headers)).encode()


def _still_serving(server: PhonePushServer) -> bool:
    sender = PhonePushSender(server.url)
    try:
        return sender.send([GOOD]) and server.drain()[-1] == GOOD
    finally:
        sender.close()


def test_content_length_minus_one_is_refused_before_the_body_is_read():
    """Finding 5: it read to EOF past the 4 MB cap (300 MB streamed: +288 MB RSS)."""
    with PhonePushServer("http://127.0.0.1:0/") as server:
        conn = socket.create_connection(_http_address(server), timeout=5)
        conn.sendall(_post_head("Content-Length: -1") + b"\r\n")
        sent, block = 0, b"x" * 65536
        # stream up to 300 MB; the server answers and closes long before
        with contextlib.suppress(BrokenPipeError, ConnectionResetError):
            while sent < 300 * 2**20:
                conn.sendall(block)
                sent += len(block)
        conn.settimeout(2.0)
        try:
            answer = conn.recv(4096)
        except ConnectionResetError:  # closed with our unread bytes in its buffer: an RST
            answer = b""
        conn.close()
        assert sent < 64 * 2**20  # what the socket buffers took before the close, not the stream
        assert answer == b"" or _status(answer) == 400
        assert server.stats.bad_messages == 1 and "Content-Length '-1'" in server.stats.last_error
        assert _still_serving(server)


@pytest.mark.parametrize(
    ("headers", "status", "reason"),
    [
        (("Content-Length: abc",), 400, "not a byte count"),
        (("Content-Length: +5",), 400, "not a byte count"),
        (("Content-Length: 1e3",), 400, "not a byte count"),
        (("Content-Length: 5", "Content-Length: 6"), 400, "contradicting"),
        (("Content-Length: 99999999999999",), 413, "larger than"),
        ((), 411, "needs a Content-Length"),
        (("Transfer-Encoding: gzip, chunked",), 501, "not supported"),
    ],
)
def test_bad_body_headers_are_answered_counted_and_print_nothing(headers, status, reason, capfd):
    """Finding 5: ``Content-Length: abc`` printed a traceback."""
    with PhonePushServer("http://127.0.0.1:0/") as server:
        answer = _request(server, _post_head(*headers), b"{}")
        assert _status(answer) == status and reason.encode() in answer
        assert b"Connection: close" in answer
        assert server.stats.bad_messages == 1 and reason in server.stats.last_error
        assert _still_serving(server)
    assert capfd.readouterr().err == ""


def test_chunked_bodies_are_decoded_under_the_same_cap():
    body = encode_push([GOOD], 1, "s", "d")
    chunked = b"".join(b"%x\r\n%s\r\n" % (len(part), part) for part in (body[:10], body[10:])) + b"0\r\n\r\n"
    with PhonePushServer("http://127.0.0.1:0/", max_body=1000) as server:
        assert _status(_request(server, _post_head("Transfer-Encoding: chunked"), chunked)) == 200
        assert server.drain() == [GOOD]
        huge = b"".join(b"200\r\n" + b"x" * 0x200 + b"\r\n" for _ in range(3))  # 1536 bytes > 1000
        assert _status(_request(server, _post_head("Transfer-Encoding: chunked"), huge)) == 413
        bad = b"zz\r\nxx\r\n0\r\n\r\n"
        assert _status(_request(server, _post_head("Transfer-Encoding: chunked"), bad)) == 400
        assert server.stats.bad_messages == 2 and server.stats.samples == 1


def test_idle_and_dripping_connections_time_out():
    """Finding 5: there was no socket timeout; an idle connection held its thread forever."""
    with PhonePushServer("http://127.0.0.1:0/", timeout_s=0.5) as server:
        idle = socket.create_connection(_http_address(server), timeout=5)
        drip = socket.create_connection(_http_address(server), timeout=5)
        start = time.monotonic()
        closed_at: dict[str, float] = {}

        def dripping() -> None:
            try:
                for byte in _post_head("Content-Length: 10"):  # a byte every 0.1 s: each read is quick
                    drip.sendall(bytes([byte]))
                    time.sleep(0.1)
            except OSError:
                closed_at["drip"] = time.monotonic() - start

        thread = threading.Thread(target=dripping)
        thread.start()
        assert idle.recv(1) == b""  # the server closed the idle connection
        closed_at["idle"] = time.monotonic() - start
        thread.join(timeout=10)
        idle.close()
        drip.close()
        assert 0.4 <= closed_at["idle"] <= 2.0
        assert 0.4 <= closed_at["drip"] <= 2.0  # its request never completed: closed at the deadline
        assert server.stats.timeouts == 2
        assert _still_serving(server)


def test_idle_connections_beyond_the_cap_make_way_for_a_new_one_and_threads_stay_bounded():
    """Issue 16 capped the connections, so three idle sockets locked every phone out until their deadline
    (issue 26, finding 7). Now the one that has waited longest is closed for the newcomer, and counted."""
    base = threading.active_count()
    with PhonePushServer("http://127.0.0.1:0/", max_connections=3, timeout_s=30.0) as server:
        held = [socket.create_connection(_http_address(server), timeout=5) for _ in range(3)]
        assert _wait(lambda: server._httpd.active == 3)
        more = [socket.create_connection(_http_address(server), timeout=5) for _ in range(20)]
        assert held[0].recv(1) == b""  # the longest waiting was closed for a newcomer
        # each newcomer closes the longest waiting one as the server accepts it — or, while the threads of
        # those it closed are still winding down (a loaded machine), is itself closed unanswered
        stats = server.stats
        assert _wait(lambda: stats.evicted_connections + stats.refused_connections >= 20, timeout_s=15.0)
        assert stats.evicted_connections >= 1
        assert _wait(lambda: _still_serving(server), timeout_s=15.0)  # a phone gets through, not after 30 s
        assert threading.active_count() <= base + 2 + 2 * 3  # the server's thread, the decoder's; 2 x cap
        for conn in held + more:
            conn.close()
        assert _wait(lambda: server._httpd.active == 0)


def test_the_push_server_answers_only_its_path():
    """Issue 26, finding 7: any path was taken for the push path."""
    good = encode_push([GOOD], 1, "s", "d")
    with PhonePushServer("http://127.0.0.1:0/sensors") as server:
        host, port = _http_address(server)
        conn = http.client.HTTPConnection(host, port, timeout=5)
        answers = []
        for method, path in [("POST", "/"), ("POST", "/sensors/x"), ("GET", "/admin"), ("GET", "/sensors")]:
            conn.request(method, path, good if method == "POST" else None)
            response = conn.getresponse()
            answers.append((response.status, response.read()))
            if response.getheader("Connection") == "close":
                conn.close()
        conn.request("POST", "/sensors?session=1", good)  # the query is not part of the path
        response = conn.getresponse()
        answers.append((response.status, response.read()))
        conn.close()
        assert [a[0] for a in answers] == [404, 404, 404, 200, 200]
        assert b"the push path is /sensors" in answers[0][1]
        assert server.stats.not_found == 3 and server.drain() == [GOOD]  # the 404s delivered nothing


def _big_push(n: int, t0_s: float = 50.0, message_id: int = 1) -> bytes:
    """A push of ``n`` plausible readings (the three sensors in turn, 0.1 ms apart): ~81 bytes each."""
    kinds = [SensorKind.GYR, SensorKind.ACC, SensorKind.MAG]
    xyz = {
        SensorKind.GYR: (0.01, -0.02, 0.003),
        SensorKind.ACC: (0.1, 0.2, 9.8),
        SensorKind.MAG: (20.5, -5.25, -40.5),
    }
    samples = [SensorSample(t0_s + 1e-4 * k, kinds[k % 3], xyz[kinds[k % 3]]) for k in range(n)]
    return encode_push(samples, message_id, "s", "d")


def _post(server: PhonePushServer, body: bytes, timeout_s: float = 30.0) -> tuple[int, bytes]:
    host, port = _http_address(server)
    conn = http.client.HTTPConnection(host, port, timeout=timeout_s)
    try:
        conn.request("POST", "/", body, {"Content-Type": "application/json"})
        response = conn.getresponse()
        return response.status, response.read()
    finally:
        conn.close()


def test_a_4_mib_push_is_decoded_in_a_process_of_its_own_and_every_reading_counted():
    """Issue 26, finding 4: a legal 4 MB push was parsed in the host's process, stalling its control loop.
    Now it goes to the decoder process; the host builds only what its queue keeps, and counts the rest."""
    body = _big_push(50_000)
    assert INLINE_MAX < len(body) <= 4 * 2**20
    want = decode_push(body).samples[-MAX_QUEUE:]
    with PhonePushServer("http://127.0.0.1:0/") as server:
        assert _post(server, body)[0] == 200
        child = server._decoder._proc
        assert child is not None and child.pid != os.getpid() and child.poll() is None
        st_ = server.stats
        assert st_.samples == 50_000 and st_.overflow == 50_000 - MAX_QUEUE
        assert st_.per_kind == {"gyr": 16_667, "acc": 16_667, "mag": 16_666}
        got = _drain_all(server)
        assert got == want  # the newest readings, exactly as the pure decoder reads them
        assert _post(server, b'{"payload": [' + b"1," * 40_000 + b"1]}")[0] == 200  # entries, not readings
        assert server.stats.bad_entries == 40_001
        status, text = _post(server, b"[" * (INLINE_MAX + 1))
        assert status == 400 and b"not JSON" in text and server.stats.bad_messages == 1


def test_a_decoder_that_dies_or_hangs_costs_one_push_and_is_started_again():
    body = _big_push(2_000)
    assert len(body) > INLINE_MAX
    with PhonePushServer("http://127.0.0.1:0/", decode_timeout_s=3.0) as server:
        assert _post(server, body)[0] == 200
        first = server._decoder._proc
        assert first is not None
        first.kill()
        first.wait()
        assert _post(server, _big_push(2_000, 60.0, 2))[0] == 200  # a new decoder, at once
        second = server._decoder._proc
        assert second is not None and second.pid != first.pid and server.stats.decoder_restarts == 1
        os.kill(second.pid, signal.SIGSTOP)  # a decoder that never answers
        start = time.monotonic()
        status, text = _post(server, _big_push(2_000, 70.0, 3))
        assert status == 503 and b"did not answer within 3.0 s" in text
        assert 2.5 <= time.monotonic() - start <= 20.0
        assert server.stats.bad_messages == 1 and "not decoded" in server.stats.last_error
        assert _post(server, _big_push(2_000, 80.0, 4))[0] == 200
        assert server.stats.decoder_restarts == 2 and server.stats.samples == 6_000


def test_a_hostile_batch_is_answered_400_and_the_keep_alive_connection_goes_on():
    with PhonePushServer("http://127.0.0.1:0/") as server:
        with socket.create_connection(_http_address(server), timeout=5) as conn:
            deep = b"[" * 60000
            conn.sendall(_post_head(f"Content-Length: {len(deep)}") + b"\r\n" + deep)
            first = _read_all(conn)
            good = encode_push([GOOD], 1, "s", "d")
            conn.sendall(_post_head(f"Content-Length: {len(good)}") + b"\r\n" + good)
            second = _read_all(conn)
        assert _status(first) == 400 and b"RecursionError" in first
        assert _status(second) == 200 and server.drain() == [GOOD]
        server.check()


def _unread_by_server(conn: socket.socket) -> int | None:
    """Bytes the server's end of loopback connection ``conn`` holds unread (its receive queue, from
    ``/proc/net/tcp``), None if it has no such socket. Linux drops what a socket has not read when a
    reset arrives, so a test cutting a request with a reset must first see the server read it."""
    client_port = conn.getsockname()[1]
    server_port = conn.getpeername()[1]
    with open("/proc/net/tcp") as table:
        for line in table.readlines()[1:]:
            fields = line.split()
            local, remote, queues = fields[1], fields[2], fields[4]
            if int(local.split(":")[1], 16) == server_port and int(remote.split(":")[1], 16) == client_port:
                return int(queues.split(":")[1], 16)
    return None


def _reset(conn: socket.socket) -> None:
    """Close ``conn`` with a reset (SO_LINGER 0), as a killed app or a client with unread input does."""
    conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    conn.close()


@settings(max_examples=25, deadline=None)
@given(whole=st.integers(0, 3), cut=st.integers(0, 400), pipelined=st.booleans())
def test_a_reset_between_requests_is_a_peer_leaving_one_inside_a_request_is_counted(whole, cut, pipelined):
    """CI caught a client that closed with its last answer unread — so the kernel reset the connection —
    counted as a bad push. A peer resetting its keep-alive connection after ``whole`` complete pushes
    loses none of them and is no bad message; a reset ``cut`` bytes into the next push (its head or its
    body, sent alone or behind the last whole push in one write) cuts that push: one bad message."""
    sender = PhonePushSender("http://127.0.0.1:1/")  # its session and device: _still_serving's phone
    samples = [SensorSample(1.0 + i, SensorKind.GYR, (0.0, 0.0, i)) for i in range(4)]
    pushes = [encode_push([sample], i, sender.session, sender.device) for i, sample in enumerate(samples)]
    requests = [_post_head(f"Content-Length: {len(body)}") + b"\r\n" + body for body in pushes]
    partial = requests[whole][: min(cut, len(requests[whole]) - 1)]
    with PhonePushServer("http://127.0.0.1:0/") as server:
        conn = socket.create_connection(_http_address(server), timeout=5)
        for request in requests[:whole]:
            if pipelined and request is requests[whole - 1]:
                conn.sendall(request + partial)
            else:
                conn.sendall(request)
            answer = b""
            while b"\r\n\r\n" not in answer or not answer.endswith(b"ok"):
                answer += conn.recv(4096)
            assert _status(answer) == 200
        if partial and not (pipelined and whole):
            conn.sendall(partial)
        if partial:
            assert _wait(lambda: _unread_by_server(conn) == 0)
        _reset(conn)
        assert _wait(lambda: server._httpd.active == 0)
        assert [s.xyz[2] for s in server.drain()] == list(range(whole))
        assert server.stats.bad_messages == (1 if partial else 0), server.stats.last_error
        assert _still_serving(server)
