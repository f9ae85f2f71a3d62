"""A client that opens the ground station's stream and never reads it (a hung browser tab, a script that
connects and stops). The server cuts it off once a write has waited :data:`~hil.gcs.server.SEND_TIMEOUT_S`
(its memory bounded by one slice, :data:`~hil.gcs.hub.READ_MAX`), but the cut was silent: no counter in
``/api/stats``, no record — every other refusal of the server is counted and said
(:meth:`~hil.gcs.server.GcsServer.turned_away`). Now it is counted as ``stalled`` (with the peer, and why),
and the other clients' streams carry every row all the while. Through the real server, a real socket with a
small receive buffer that never reads, and a real reader beside it; the send timeout shortened so the test
takes seconds (the same code path)."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import pytest
from gcs_support import request, wait_for

from hil.gcs import GroundStation, server

ROWS = 40_000
HEADER = "t," + ",".join(f"x{k}" for k in range(12)) + "\n"


def write_run(d: Path) -> Path:
    d.mkdir()
    lines = (f"{k / 50}," + ",".join(f"{k + j}.125" for j in range(12)) + "\n" for k in range(ROWS))
    (d / "telemetry.csv").write_text(HEADER + "".join(lines))  # ~3.5 MB: more than the socket buffers hold
    (d / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n')
    (d / "summary.json").write_text(json.dumps({"exit": "completed"}))
    return d


def open_stream(station: GroundStation, rcvbuf: int | None = None) -> socket.socket:
    s = socket.socket()
    if rcvbuf is not None:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.connect(("127.0.0.1", station.port))
    head = f"GET /api/stream?token={station.token} HTTP/1.0\r\nHost: 127.0.0.1:{station.port}\r\n\r\n"
    s.sendall(head.encode())
    return s


def rows_read(s: socket.socket, until: float) -> int:
    """Rows carried by the stream on ``s`` up to the run's last status (``finished``) and its ``id``."""
    data = b""
    s.settimeout(max(until - time.monotonic(), 0.1))
    while b'"state":"finished"' not in data or not data.endswith(b"\n\n") or b"caught_up" not in data:
        chunk = s.recv(1 << 20)
        assert chunk, "the stream ended before its history"
        data += chunk
    return sum(
        len(json.loads(m.split("data: ", 1)[1])["rows"])
        for m in data.decode().split("\n\n")
        if m.startswith("event: rows")
    )


@pytest.mark.parametrize("stalled_clients", [1, 3])
def test_a_stream_that_is_never_read_is_cut_off_counted_and_holds_no_one_else_up(
    tmp_path, monkeypatch, stalled_clients
):
    monkeypatch.setattr(server, "SEND_TIMEOUT_S", 2.0)
    run = write_run(tmp_path / "run")
    with GroundStation.replay(run, bind="127.0.0.1:0", follow=False) as station:
        wait_for(lambda: station.stats()["run_dir"]["finished"], 30, "the run read")
        stalled = [open_stream(station, rcvbuf=4096) for _ in range(stalled_clients)]
        try:
            opened = lambda: station.stats()["hub"]["streams_open"] == stalled_clients  # noqa: E731
            wait_for(opened, 10, "the streams open")
            reader = open_stream(station)
            assert rows_read(reader, time.monotonic() + 30) == ROWS  # beside the stalled ones, all of it
            reader.close()
            wait_for(lambda: station.stats()["hub"]["streams_open"] == 0, 30, "the stalled streams cut off")
            said = wait_for(
                lambda: station.stats()["server"]["rejected"].get("stalled") == stalled_clients,
                10,
                "each stalled stream counted",
            )
            assert said
            status, stats = request(station, "GET", f"/api/stats?token={station.token}")
            assert status == 200 and stats["server"]["rejected"]["stalled"] == stalled_clients
        finally:
            for s in stalled:
                s.close()
