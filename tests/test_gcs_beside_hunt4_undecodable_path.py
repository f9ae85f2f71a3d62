"""A request whose path parses but whose %-escapes are not UTF-8 (``/static/%ff%fe``): tornado refuses it
with a 400 before the handler runs, and the server answered ``"reason": "error"`` — neither counted in
``/api/stats`` nor logged, where every other refusal is (:meth:`~hil.gcs.server.GcsServer.turned_away`).
Now it is a ``path`` refusal, counted, and the page is still served. Drawn escapes through a real socket."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import pytest
from gcs_support import request
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    run = Path(tmp_path_factory.mktemp("gcs")) / "run"
    run.mkdir()
    (run / "telemetry.csv").write_text("t,phase\n0,1\n0.02,1\n")
    (run / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n')
    with GroundStation.replay(run, bind="127.0.0.1:0", follow=False) as s:
        yield s


def raw_get(station: GroundStation, path: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", station.port), timeout=10) as s:
        s.sendall(b"GET " + path + f" HTTP/1.1\r\nHost: 127.0.0.1:{station.port}\r\n\r\n".encode())
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    return data


# a lone continuation byte, or a lead byte without its continuation: never UTF-8
ROUTES = st.sampled_from([b"/static/", b"/static/a/", b"/api/stats?token="])  # a query's escapes too
BAD = st.sampled_from([b"%ff", b"%fe", b"%80", b"%c3", b"%e2%9c", b"%ed%a0%80", b"%c0%af"])


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(route=ROUTES, bad=BAD, tail=st.sampled_from([b"", b".js", b"x"]))
def test_a_path_whose_escapes_are_not_utf8_is_refused_as_a_path_and_counted(station, route, bad, tail):
    before = station.stats()["server"]["rejected"].get("path", 0)
    head, _, body = raw_get(station, route + bad + tail).partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 400"), head
    assert json.loads(body)["reason"] == "path"
    assert station.stats()["server"]["rejected"].get("path", 0) == before + 1
    assert request(station, "GET", "/")[0] == 200
