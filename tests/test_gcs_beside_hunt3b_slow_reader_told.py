"""A browser that falls behind on the ground station's stream (a slow link, a tab in the background) while
the history it has not read is trimmed (the hub's byte budget full) skips to the oldest chunk held. The skip
was counted in ``/api/stats`` (``skipped_chunks``) but the stream said nothing: the page plotted on across
the hole, rows missing mid-plot without a word. Now the stream carries a ``skipped`` message where the hole
is (hil/gcs/hub.py: :func:`~hil.gcs.hub.skipped`), so the page can say it, between the rows either side.

Through the real server and a real socket that stops reading (a tiny receive buffer) while a followed run
directory grows by megabytes."""

from __future__ import annotations

import json
import re
import socket
import time
from pathlib import Path

import pytest
from gcs_support import request, wait_for

from hil.gcs import GroundStation, RunDirSource, server

COLUMNS = ["t"] + [f"x{k}" for k in range(30)]


def rows_text(start: int, n: int) -> str:
    return "".join(
        f"{k / 50}," + ",".join(f"{k + j}.125" for j in range(30)) + "\n" for k in range(start, start + n)
    )


def received(conn: socket.socket, n: int) -> bytes:
    """What the stream sends next; a stream the server ended before the test had what it waits for fails
    the test (recv's b"" would otherwise be read for ever)."""
    data = conn.recv(n)
    assert data, "the station ended the stream before the newest row"
    return data


def test_a_reader_whose_unread_chunks_were_trimmed_is_told_where(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The socket stalls while the station reads megabytes of rows: on a busy machine that can take longer
    # than the server lets a stream go unread (SEND_TIMEOUT_S, then it is cut off, as it should be: that
    # is test_gcs_beside_hunt4_stalled_stream's). Here the reader must outlive its stall to see what follows
    # the hole.
    monkeypatch.setattr(server, "SEND_TIMEOUT_S", 600.0)
    d = tmp_path / "run"
    d.mkdir()
    (d / "telemetry.csv").write_text(",".join(COLUMNS) + "\n" + rows_text(0, 50))
    (d / "events.jsonl").write_text("")
    with GroundStation(RunDirSource(d), bind="127.0.0.1:0", budget=512 * 1024) as station:
        conn = socket.socket()
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        conn.connect(("127.0.0.1", station.port))
        host = f"127.0.0.1:{station.port}"
        conn.sendall(f"GET /api/stream?token={station.token} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode())
        got = b""
        while b"caught_up" not in got:  # the history, then this socket stops reading
            got += received(conn, 65536)
        n = 50
        with open(d / "telemetry.csv", "a") as f:

            def behind() -> int:  # bytes published that the stalled stream has not taken
                hub = request(station, "GET", "/api/stats")[1]["hub"]
                return int(hub["bytes_published"] - hub["bytes_sent"])

            while behind() < 2 * station.hub.budget:  # past the budget: what it has not read is trimmed
                assert n < 400_000, "the stream never fell behind: the test does not test"
                f.write(rows_text(n, 5000))
                f.flush()
                n += 5000
                time.sleep(0.05)
        wait_for(
            lambda: request(station, "GET", "/api/stats")[1]["run_dir"]["rows"] == n, 60, "every row read"
        )
        last = f"[{(n - 1) / 50:.10g},".encode()
        conn.settimeout(20)
        while last not in got:  # reading again: the rest of the stream, up to the newest row
            got += received(conn, 1 << 20)
        conn.close()
    text = got.decode(errors="replace")
    said = [json.loads(m) for m in re.findall(r"event: skipped\ndata: (.*)\n", text)]
    assert said and all(s["chunks"] > 0 for s in said), "rows went missing and the stream never said so"
    assert sum(s["chunks"] for s in said) == station.stats()["hub"]["skipped_chunks"]
