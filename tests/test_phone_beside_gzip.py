"""A compressed push is taken whole or not at all (RFC 1952 §2.2: a gzip body is a series of members):
every member undone, and a stream cut short or followed by bytes that are no member refused 400 with a
gzip-specific reason. Before: a valid body of two members was "not JSON", a member cut before its CRC
and length trailer, or followed by garbage, was answered 200. Over real loopback HTTP to the receiver."""

from __future__ import annotations

import gzip
import http.client
import time
import zlib

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.http_guard import MAX_MEMBERS
from hil.link.sources.phone_push import PhonePushServer, encode_push

SAMPLES = [SensorSample(1.0 + 0.01 * k, SensorKind.GYR, (0.1, 0.2, 0.3)) for k in range(20)]
BODY = encode_push(SAMPLES, 1, "s", "d")


def _post(server: PhonePushServer, data: bytes, coding: str = "gzip") -> tuple[int, bytes]:
    host, port = server.url.split("//")[1].split("/")[0].split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=5)
    try:
        conn.request("POST", "/", data, {"Content-Type": "application/json", "Content-Encoding": coding})
        resp = conn.getresponse()
        return resp.status, resp.read()
    finally:
        conn.close()


def _drained(server: PhonePushServer, n: int) -> list[SensorSample]:
    got: list[SensorSample] = []
    deadline = time.monotonic() + 5
    while len(got) < n and time.monotonic() < deadline:
        got += server.drain()
        time.sleep(0.01)
    return got


cuts = st.lists(st.integers(0, len(BODY)), max_size=MAX_MEMBERS - 1).map(sorted)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cuts, st.sampled_from(["whole", "garbage", "cut", "bad_member"]), st.integers(1, 30))
def test_every_gzip_member_is_undone_and_a_stream_not_whole_is_refused(cuts, how, n):
    bounds = [0, *cuts, len(BODY)]
    members = [gzip.compress(BODY[a:b]) for a, b in zip(bounds, bounds[1:], strict=False)]
    data = b"".join(members)
    if how == "garbage":
        data += b"GARBAGE-NOT-GZIP"[:n]
    elif how == "cut":
        data = data[: len(data) - min(n, 8)]  # the last member's CRC-32 and length, in part or whole
    elif how == "bad_member":
        data += b"\x1f\x8b" + b"\x00" * n  # a second member's magic, no member
    with PhonePushServer("http://127.0.0.1:0/") as server:
        status, answer = _post(server, data)
        if how == "whole":
            assert status == 200, answer
            assert [s.t_s for s in _drained(server, len(SAMPLES))] == pytest.approx([s.t_s for s in SAMPLES])
        else:
            assert status == 400, (how, answer)
            assert b"gzip" in answer, answer
            assert server.stats.bad_messages == 1 and server.stats.samples == 0


def test_deflate_is_taken_whole_and_too_many_members_are_refused():
    with PhonePushServer("http://127.0.0.1:0/") as server:
        assert _post(server, zlib.compress(BODY), "deflate")[0] == 200
        status, answer = _post(server, zlib.compress(BODY) + b"x", "deflate")
        assert status == 400 and b"after the end of the deflate data" in answer
        status, answer = _post(server, zlib.compress(BODY)[:-2], "deflate")
        assert status == 400 and b"cut short" in answer
        status, answer = _post(server, gzip.compress(b"") * MAX_MEMBERS + gzip.compress(BODY))
        assert status == 400 and b"members" in answer
        assert _post(server, gzip.compress(b"") * (MAX_MEMBERS - 1) + gzip.compress(BODY))[0] == 200
