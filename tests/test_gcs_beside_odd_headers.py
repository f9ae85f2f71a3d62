"""Malformed ``Host`` and ``Origin`` headers and a static path past the OS's name limit, through the real
tornado server.

``urlsplit`` raises ValueError for an unclosed or invalid bracket (``Host: [::1``, ``Host: [zz]:1``,
``Origin: http://[``), and reading ``/static/`` + 6 kB raises OSError ENAMETOOLONG, none of which the
checks caught: each was a 500 (``reason: error``), its logged detail the path cut to 300 characters, which
did not say which error. Now a Host that cannot be parsed is not this server's (403 ``host``), an Origin
that cannot be parsed is not the page's (403 ``origin``), a name too long is a file that does not exist
(404), and a handler's exception is reported error first.
"""

from __future__ import annotations

import http.client
import time
from dataclasses import dataclass
from typing import Any

import pytest
from gcs_support import UplinkLog, answer_of
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation
from hil.gcs.access import Access


def _get(station: GroundStation, method: str, path: str, headers: dict[str, str]) -> tuple[int, Any]:
    """One request with exactly ``headers`` (no Host added): ``(status, decoded JSON or text)``."""
    conn = http.client.HTTPConnection("127.0.0.1", station.port, timeout=10)
    try:
        conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
        for name, value in headers.items():
            conn.putheader(name, value)
        body = b"{}" if method == "POST" else None
        if body is not None:
            conn.putheader("Content-Length", str(len(body)))
        conn.endheaders(body)
        return answer_of(conn)
    finally:
        conn.close()


def _logged(station: GroundStation) -> list[dict[str, Any]]:
    """The requests turned away since the last call, as the control tick logs them."""
    log = UplinkLog()
    assert station.uplink is not None
    station.uplink.service(log, time.monotonic())  # type: ignore[arg-type]
    return [r for r in log.records if r.get("status") == "rejected"]


def _api(station: GroundStation, method: str) -> tuple[str, dict[str, str]]:
    """A request that passes every check but the headers under test: the path and its token."""
    if method == "GET":
        return f"/api/info?token={station.token}", {}
    return "/api/command", {"Authorization": f"token {station.token}", "Content-Type": "application/json"}


@pytest.mark.parametrize("method", ["GET", "POST"])
@pytest.mark.parametrize("host", ["[::1", "[zz]:1", "[", "[::1]:x", "[::1]:99999", "[::1]]", "]:80"])
def test_a_malformed_host_header_is_refused_403_host(method, host):
    with GroundStation.live(bind="127.0.0.1:0") as station:
        path, headers = _api(station, method)
        status, answer = _get(station, method, path, {"Host": host, **headers})
        assert (status, answer["reason"]) == (403, "host"), answer
        assert [r["reason"] for r in _logged(station)] == ["host"]
        assert "error" not in station.server.counters()["rejected"]


@pytest.mark.parametrize("method", ["GET", "POST"])
@pytest.mark.parametrize(
    "origin", ["http://[", "http://[::1", "http://[zz]", "http://[::1]:x", "http://a:99999"]
)
def test_a_malformed_origin_is_refused_403_origin(method, origin):
    with GroundStation.live(bind="127.0.0.1:0") as station:
        path, headers = _api(station, method)
        status, answer = _get(
            station, method, path, {"Host": f"127.0.0.1:{station.port}", "Origin": origin, **headers}
        )
        assert (status, answer["reason"]) == (403, "origin"), answer
        assert [r["reason"] for r in _logged(station)] == ["origin"]
        assert "error" not in station.server.counters()["rejected"]


_header_text = st.text(alphabet="[]:/.%@0123456789abcdefxz-", max_size=24)


def test_any_host_and_origin_header_gets_an_answer_never_a_500():
    """Host and Origin drawn from the characters that make them ambiguous: the page's own (200 for
    ``/api/stats``), a 403 naming the header, or a Host tornado itself refuses (its bare 400, reported as
    ``request``); never a 500."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        own = f"127.0.0.1:{station.port}"

        hosts = st.one_of(st.just(own), _header_text)
        origins = st.one_of(
            st.none(), st.just(f"http://{own}"), _header_text.map("http://".__add__), _header_text
        )

        @settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
        @given(hosts, origins)
        @example("[::1", None)
        @example(own, "http://[")
        def one(host: str, origin: str | None) -> None:
            headers = {"Host": host} if origin is None else {"Host": host, "Origin": origin}
            status, answer = _get(station, "GET", f"/api/stats?token={station.token}", headers)
            assert status in (200, 400, 403), (status, answer)
            if status == 403:
                assert answer["reason"] in ("host", "origin")
            if status == 400:  # what tornado refuses itself ("@", "%"): its bare 400, reported as request
                assert answer == "" and station.server.counters()["rejected"]["request"]
            assert "error" not in station.server.counters()["rejected"]

        one()


def test_a_static_path_past_the_name_limit_is_404_and_the_page_still_served():
    with GroundStation.live(bind="127.0.0.1:0") as station:
        host = {"Host": f"127.0.0.1:{station.port}"}
        for path in ("/static/" + "a/" * 3000 + "x.js", "/static/" + "b" * 6000 + ".js"):
            status, answer = _get(station, "GET", path, host)
            assert status == 404 and answer["error"].startswith("no such file"), answer
            assert len(answer["error"]) < 200
        assert _get(station, "GET", "/static/app.js", host)[0] == 200
        assert "error" not in station.server.counters()["rejected"]
        assert _logged(station) == []  # a 404 is not a rejection


@dataclass(frozen=True)
class _BrokenAccess(Access):
    """Checks that fail with an exception: what any handler's bug would do."""

    def host_ok(self, host_header: str | None) -> bool:
        raise RuntimeError("a check that broke")


def test_a_handlers_exception_is_reported_saying_which_error_whatever_the_path():
    """The report's detail (cut to 300 characters) says the error first, then the path cut: before, it
    was the path and then the error, and a 6 kB path left only the path."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        access = station.server.access
        station.server.access = _BrokenAccess(access.token, access.host, access.port)
        status, answer = _get(station, "GET", "/static/" + "a/" * 3000 + "x.js", {"Host": "127.0.0.1"})
        assert (status, answer["reason"]) == (500, "error")
        [record] = _logged(station)
        assert record["reason"] == "error"
        assert record["detail"].startswith("RuntimeError: a check that broke at /static/a/a/")
        assert len(record["detail"]) <= 300
