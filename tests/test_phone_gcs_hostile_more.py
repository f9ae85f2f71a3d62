"""Well-formed but hostile input to the phone receivers and the ground station, through their real
interfaces (a real HTTP push server, a real ground-station server and raw sockets).

Regressions:

* a Sensor Logger push whose ``messageId`` was an integer of 4300 digits (valid JSON, under Python's digit
  limit) was counted as that many lost batches; two such jumps made ``message_gaps`` an integer past the
  digit limit, and ``summary.json`` (and ``/api/stats``) could no longer be written: ``ValueError:
  Exceeds the limit (4300 digits) for integer string conversion``;
* each ground-station stream took the hub's whole history in one read and wrote it in one go: 16
  clients that opened ``/api/stream`` and never read held ~2 GiB of the host's memory for a 60 MiB
  history (until ``SEND_TIMEOUT_S``, then they could reconnect).
"""

from __future__ import annotations

import http.client
import json
import socket
import tempfile
import time
from pathlib import Path

import pytest
from gcs_support import wait_for

from hil.gcs.hub import READ_MAX, Hub
from hil.gcs.server import MAX_STREAMS, GcsServer
from hil.link.sources.listening import ListeningSource
from hil.link.sources.phone_push import MAX_MESSAGE_GAP, PhonePushServer
from hil.runtime.runlog import write_summary

TOKEN = "probe-token"


def _push(server: PhonePushServer, message_id: str, t_ns: int) -> int:
    """POST one batch of one gyroscope reading with ``message_id`` written as is (JSON text)."""
    reading = f'{{"name": "gyroscope", "time": {t_ns}, "values": {{"x": 0.01, "y": 0, "z": 0}}}}'
    body = f'{{"messageId": {message_id}, "sessionId": "s", "payload": [{reading}]}}'.encode()
    port = server._httpd.server_port
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request("POST", "/", body, {"Content-Type": "application/json"})
        answer = conn.getresponse()
        answer.read()
    finally:
        conn.close()
    return answer.status


# ------------------------------------------------------------------------------------- phone push
def test_an_absurd_message_id_restarts_the_count_and_the_summary_is_still_written():
    big = "9" * 4300  # the largest integer json.loads takes
    t0 = 1_698_501_144_401_773_000
    with PhonePushServer("http://127.0.0.1:0/") as server:
        ids = ["0", big, "0", big, "0", big, "1", "2"]
        statuses = [_push(server, mid, t0 + k * 10_000_000) for k, mid in enumerate(ids)]
        assert statuses == [200] * len(ids)  # each batch's readings are taken
        stats = server.stats
        assert stats.samples == len(ids)
        assert stats.message_gaps == 0  # no phone sent 10**4300 batches
        assert stats.message_restarts == 6  # up, down, up, down, up, down (to 1; then 2 follows it)
        report = ListeningSource(server).report()
        json.dumps(report)  # what /api/stats and summary.json do with it
        with tempfile.TemporaryDirectory() as run_dir:
            write_summary(run_dir, report)


@pytest.mark.parametrize(
    ("ids", "gaps", "restarts"),
    [
        ([5, 10], 4, 0),  # batches lost in the air
        ([5, 5, 6], 0, 0),  # a batch sent again: not a loss, not a restart
        ([5, 5 + MAX_MESSAGE_GAP + 1], MAX_MESSAGE_GAP, 0),  # the farthest jump still counted as losses
        ([5, 5 + MAX_MESSAGE_GAP + 2, 5 + MAX_MESSAGE_GAP + 4], 1, 1),  # farther: a numbering of its own
        ([40, 3, 4], 0, 1),  # the app restarted its numbering
        ([-(10**30), 10**30], 0, 1),
    ],
)
def test_message_id_jumps_count_losses_only_where_a_phone_could_have_sent_them(ids, gaps, restarts):
    t0 = 1_698_501_144_401_773_000
    with PhonePushServer("http://127.0.0.1:0/") as server:
        for k, mid in enumerate(ids):
            assert _push(server, str(mid), t0 + k * 10_000_000) == 200
        assert (server.stats.message_gaps, server.stats.message_restarts) == (gaps, restarts)


# ------------------------------------------------------------------------------------- ground station
def _rss_mib() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * 4096 / 2**20


def _open_stream(port: int, rcvbuf: int | None = None) -> socket.socket:
    sock = socket.socket()
    if rcvbuf is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.connect(("127.0.0.1", port))
    request = f"GET /api/stream?token={TOKEN} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n"
    sock.sendall(request.encode())
    return sock


def _station(hub: Hub) -> GcsServer:
    server = GcsServer("127.0.0.1", 0, TOKEN, hub, None, lambda: {}, lambda: {})
    server.start()
    return server


@pytest.mark.skipif(not Path("/proc/self/statm").exists(), reason="reads the memory held from /proc")
def test_streams_that_never_read_hold_a_slice_of_the_history_not_a_copy_each():
    hub = Hub()
    hub.set_info(b"event: info\ndata: {}\n\n")
    chunk = b"event: rows\ndata: " + b"1" * (256 * 1024) + b"\n\n"
    for _ in range(240):  # ~60 MiB of history (one object: the hub itself holds little)
        hub.publish(chunk)
    server = _station(hub)
    socks: list[socket.socket] = []
    try:
        before = _rss_mib()
        socks = [_open_stream(server.port, rcvbuf=4096) for _ in range(MAX_STREAMS)]
        wait_for(lambda: server.counters()["streams_open"] == MAX_STREAMS, 20.0, "streams open")
        time.sleep(1.0)  # each has taken what it takes and is waiting for its browser
        grown = _rss_mib() - before
        # before: ~120 MiB a stream (~1.9 GiB); now a slice each, and the kernel's buffers
        assert grown < 400, f"{MAX_STREAMS} streams that never read grew the server by {grown:.0f} MiB"
    finally:
        for sock in socks:
            sock.close()
        server.stop()


def test_a_reading_stream_still_gets_the_whole_history_in_order():
    hub = Hub()
    hub.set_info(b"event: info\ndata: {}\n\n")
    chunks = [b"event: rows\ndata: %d %s\n\n" % (k, b"x" * (READ_MAX // 3)) for k in range(40)]
    for chunk in chunks:
        hub.publish(chunk)
    hub.publish(b"event: rows\ndata: big " + b"y" * (2 * READ_MAX) + b"\n\n")  # larger than a slice
    hub.close()  # the stream ends ("bye") once everything was sent
    server = _station(hub)
    sock = _open_stream(server.port)
    try:
        sock.settimeout(20.0)
        received = bytearray()
        while b"event: bye" not in received:
            data = sock.recv(1 << 20)
            if not data:
                break
            received += data
    finally:
        sock.close()
        server.stop()
    body = bytes(received).split(b"\r\n\r\n", 1)[1]
    text = body.decode("latin-1")
    assert text.count("event: rows") == 41
    positions = [text.index(f"data: {k} ") for k in range(40)]
    assert positions == sorted(positions)
    assert text.index("data: big ") > positions[-1]
    assert hub.stats.skipped_chunks == 0
