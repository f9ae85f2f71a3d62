"""The live phone path: Sensor Logger HTTP Push batches, parsed purely and carried over real loopback HTTP."""

from __future__ import annotations

import http.client
import json
import math
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.phone_push import PhonePushSender, PhonePushServer, decode_push, encode_push
from protocol.errors import ConfigError, InputFormatError, LinkError

finite = st.floats(-1e4, 1e4, allow_nan=False)
samples = st.lists(
    st.builds(
        SensorSample,
        st.integers(1_600_000_000_000_000_000, 1_900_000_000_000_000_000).map(lambda ns: ns * 1e-9),
        st.sampled_from(list(SensorKind)),
        st.tuples(finite, finite, finite),
    ),
    max_size=40,
)


@settings(max_examples=60, deadline=None)
@given(samples)
def test_encode_then_decode_returns_the_samples_in_time_order(batch):
    out = decode_push(encode_push(batch, 7, "s", "d"))
    got, bad, ignored, mid = out.samples, out.bad, out.ignored, out.message_id
    assert (bad, ignored, mid) == (0, 0, 7)
    want = sorted(batch, key=lambda s: (s.t_s, int(s.kind)))
    assert [(s.kind, s.xyz) for s in got] == [(s.kind, s.xyz) for s in want]
    assert all(abs(a.t_s - b.t_s) < 1e-6 for a, b in zip(got, want, strict=True))


def test_the_apps_schema_with_other_sensors_and_bad_entries():
    body = json.dumps(
        {
            "messageId": 3,
            "sessionId": "x",
            "deviceId": "y",
            "payload": [
                {"name": "gyroscope", "time": 2_000_000_000, "values": {"x": 0.1, "y": 0.2, "z": 0.3}},
                {"name": "location", "time": 2_000_000_000, "values": {"latitude": 1.0}},
                {"name": "magnetometer", "time": "2010000000", "values": {"x": 20, "y": -5, "z": -40}},
                {"name": "gyroscope", "time": 2_020_000_000, "values": {"x": "NaN", "y": 0, "z": 0}},
                {"name": "gyroscope", "values": {"x": 0, "y": 0, "z": 0}},
                {"time": 1},
            ],
        }
    ).encode()
    out = decode_push(body)
    got, bad, ignored, mid = out.samples, out.bad, out.ignored, out.message_id
    assert [s.kind for s in got] == [SensorKind.GYR, SensorKind.MAG]
    assert got[1].t_s == pytest.approx(2.01) and got[1].xyz == (20.0, -5.0, -40.0)
    assert (bad, ignored, mid) == (3, 1, 3)


def test_user_acceleration_plus_gravity_when_no_total_acceleration_is_pushed():
    entry = lambda name, t, z: {"name": name, "time": t, "values": {"x": 0.0, "y": 0.5, "z": z}}  # noqa: E731
    body = json.dumps(
        {
            "payload": [
                entry("accelerometer", 10, 0.2),
                entry("gravity", 11, 9.8),
                entry("accelerometer", 20, -0.1),
            ]
        }
    ).encode()
    out = decode_push(body)
    got, bad, ignored = out.samples, out.bad, out.ignored
    assert [s.xyz for s in got] == [(0.0, 1.0, 10.0), (0.0, 1.0, 9.700000000000001)]
    assert all(s.kind is SensorKind.ACC for s in got) and bad == ignored == 0


@pytest.mark.parametrize("body", [b"", b"[1, 2]", b'{"payload": 3}', b"\xff\xfe", b"{not json"])
def test_malformed_batches_are_input_format_errors_naming_the_source(body):
    with pytest.raises(InputFormatError, match="phone-7"):
        decode_push(body, "phone-7")


def test_a_sender_streams_to_the_receiver_over_loopback_http():
    with PhonePushServer("http://127.0.0.1:0/") as server:
        sender = PhonePushSender(server.url)
        sent = []
        for k in range(20):
            batch = [SensorSample(100.0 + 0.005 * (2 * k + j), SensorKind.GYR, (k, j, 0.0)) for j in range(2)]
            batch.append(SensorSample(100.0 + 0.01 * k, SensorKind.MAG, (30.0, 0.0, -20.0)))
            assert sender.send(batch)
            sent.extend(batch)
        got = server.drain()
        assert len(got) == len(sent) == server.stats.samples == 60
        assert server.stats.per_kind == {"gyr": 40, "mag": 20} and server.stats.message_gaps == 0
        assert server.drain() == []
        sender.message_id += 5  # five batches "lost in the air"
        assert sender.send(sent[:1])
        server.drain()
        assert server.stats.message_gaps == 5
        sender.close()


def test_garbage_is_answered_400_counted_and_the_receiver_keeps_serving():
    with PhonePushServer("http://127.0.0.1:0/") as server:
        host, port = server.url.split("//")[1].split("/")[0].split(":")
        conn = http.client.HTTPConnection(host, int(port), timeout=2)
        conn.request("POST", "/", b"{broken", {"Content-Type": "application/json"})
        resp = conn.getresponse()
        assert resp.status == 400 and b"not JSON" in resp.read()
        conn.request("GET", "/")
        assert conn.getresponse().status == 200  # the app's "Tap to Test Pushing"
        conn.close()
        assert server.stats.bad_messages == 1 and "not JSON" in server.stats.last_error
        assert PhonePushSender(server.url).send([SensorSample(1.0, SensorKind.ACC, (0.0, 0.0, 9.8))])
        assert [s.xyz for s in server.drain()] == [(0.0, 0.0, 9.8)]


def test_a_sender_survives_a_receiver_restart_and_counts_the_failure():
    server = PhonePushServer("http://127.0.0.1:0/")
    url = server.url
    port = int(url.rsplit(":", 1)[1].rstrip("/"))
    sender = PhonePushSender(url, timeout_s=0.5)
    assert sender.send([SensorSample(1.0, SensorKind.GYR, (0.0, 0.0, 0.0))])
    server.close()
    assert not sender.send([SensorSample(1.1, SensorKind.GYR, (0.0, 0.0, 0.0))])
    assert sender.failed == 1
    deadline = time.monotonic() + 5
    while True:
        try:
            server = PhonePushServer(f"http://127.0.0.1:{port}/")
            break
        except LinkError:
            assert time.monotonic() < deadline
            time.sleep(0.05)
    with server:
        assert sender.send([SensorSample(1.2, SensorKind.GYR, (0.0, 0.0, 1.0))])
        assert [s.xyz for s in server.drain()] == [(0.0, 0.0, 1.0)]


def test_bad_urls_and_busy_ports_are_link_errors():
    with pytest.raises(ConfigError, match="http://"):  # a bad address is the option's error
        PhonePushSender("udp://127.0.0.1:9")
    with PhonePushServer("http://127.0.0.1:0/") as server:
        port = int(server.url.rsplit(":", 1)[1].rstrip("/"))
        with pytest.raises(LinkError, match=str(port)):
            PhonePushServer(f"http://127.0.0.1:{port}/")
    assert math.isfinite(port)


def test_a_gzip_or_deflate_body_is_undone_within_the_limit_and_another_coding_is_a_415():
    """A push whose body is compressed (``Content-Encoding: gzip``, as a proxy or a client library may
    send it) is read as the app's JSON; a coding the receiver cannot undo is a 415 naming it, and a small
    body that unpacks to more than the body limit a 413 (it was "not JSON (UnicodeDecodeError ...)")."""
    import gzip
    import zlib

    samples = [SensorSample(1.0 + 0.01 * k, SensorKind.GYR, (0.1, 0.2, 0.3)) for k in range(5)]
    body = encode_push(samples, 1, "s", "d")
    bomb = gzip.compress(b" " * (64 << 20))  # 64 kB that unpacks to 64 MB
    with PhonePushServer("http://127.0.0.1:0/") as server:
        host, port = server.url.split("//")[1].split("/")[0].split(":")
        conn = http.client.HTTPConnection(host, int(port), timeout=5)
        answers = []
        for coding, data in (("gzip", gzip.compress(body)), ("deflate", zlib.compress(body)), ("br", body),
                             ("gzip", bomb), ("gzip", b"not gzip")):  # fmt: skip
            conn.request("POST", "/", data, {"Content-Type": "application/json", "Content-Encoding": coding})
            resp = conn.getresponse()
            answers.append((resp.status, resp.read()))
        conn.close()
        assert [status for status, _ in answers] == [200, 200, 415, 413, 400]
        assert b"'br'" in answers[2][1] and b"unpacks to more" in answers[3][1]
        deadline = time.monotonic() + 5
        got: list[SensorSample] = []
        while len(got) < 10 and time.monotonic() < deadline:
            got += server.drain()
            time.sleep(0.02)
        assert [s.t_s for s in got] == [s.t_s for s in samples] * 2


@pytest.mark.parametrize(
    ("unit", "scale", "as_float"),
    [("ns", 10**9, False), ("µs", 10**6, False), ("ms", 10**3, False), ("s", 1, True), ("ms", 10**3, True)],
)
def test_a_batch_s_time_in_another_unit_is_told_by_its_epoch_and_spacing(unit, scale, as_float):
    """A client that writes ``time`` in µs, ms or s since the epoch (the app writes ns): 10 s at 100 Hz
    read as 10 s, not 10 ms (dropped as a flood) or 10 ns."""
    t0 = 1_698_501_144.25
    entries = []
    for k in range(1000):
        t = (t0 + 0.01 * k) * scale
        stamp = t if as_float else round(t)
        entries.append({"name": "gyroscope", "time": stamp, "values": {"x": 1.0, "y": 0.0, "z": 0.0}})
    out = decode_push(json.dumps({"payload": entries}).encode())
    got, bad = out.samples, out.bad
    assert bad == 0 and len(got) == 1000
    assert got[0].t_s == pytest.approx(t0, abs=1e-3) and got[-1].t_s - got[0].t_s == pytest.approx(
        9.99, abs=1e-3
    )


@pytest.mark.parametrize("seconds_from_start", [1.0, 1500.0, 9000.0])
def test_a_ns_clock_from_its_start_stays_ns_in_every_epoch_band(seconds_from_start):
    """The emulator's phone stamps ns from its world's start: 1500 s of it is 1.5e12, a ms epoch's size,
    but its readings 5e6 apart are ns (and a batch of one reading per sensor is taken as ns too)."""
    samples = [
        SensorSample(seconds_from_start + 0.005 * k, SensorKind.GYR, (0.0, 0.0, 0.1)) for k in range(20)
    ]
    for batch in (samples, samples[:1]):
        got = decode_push(encode_push(batch, 1, "s", "d")).samples
        assert [s.t_s for s in got] == pytest.approx([s.t_s for s in batch], abs=1e-9)


def _app_batch(message_id: int, t0_ns: int, n: int, total: bool, parts: bool, pad: int = 0) -> bytes:
    """A Sensor Logger push of ``n`` readings each 5 ms apart from ``t0_ns``: a gyroscope's, and with
    ``total`` total acceleration (z 9.9), with ``parts`` user acceleration (z 0.1) and gravity (z 9.7);
    ``pad`` readings of an unused sensor make the body large (the decoder process's path)."""
    payload = []
    for k in range(n):
        t = t0_ns + 5_000_000 * k
        payload.append({"name": "gyroscope", "time": t, "values": {"x": 0.0, "y": 0.0, "z": 0.01}})
        if total:
            payload.append({"name": "totalacceleration", "time": t, "values": {"x": 0.0, "y": 0.0, "z": 9.9}})
        if parts:
            payload.append({"name": "accelerometer", "time": t, "values": {"x": 0.0, "y": 0.0, "z": 0.1}})
            payload.append({"name": "gravity", "time": t, "values": {"x": 0.0, "y": 0.0, "z": 9.7}})
    payload += [{"name": "light", "time": t0_ns, "values": {"x": 1.0, "y": 0.0, "z": 0.0}}] * pad
    return json.dumps({"messageId": message_id, "payload": payload}).encode()


def test_a_batch_s_parts_are_left_out_once_total_acceleration_was_pushed():
    """:func:`decode_push` with ``parts=False`` (a stream that has sent total acceleration) ignores the
    user acceleration and gravity of a batch without it, counted; it says whether a batch held it."""
    with_total = decode_push(_app_batch(1, 10**18, 2, total=True, parts=True))
    only_parts = decode_push(_app_batch(2, 10**18, 2, total=False, parts=True), parts=False)
    combined = decode_push(_app_batch(2, 10**18, 2, total=False, parts=True))
    assert with_total.total and not only_parts.total and not combined.total
    assert [s.xyz[2] for s in with_total.samples if s.kind is SensorKind.ACC] == [9.9, 9.9]
    assert [s.kind for s in only_parts.samples] == [SensorKind.GYR] * 2 and only_parts.ignored == 4
    assert [s.xyz[2] for s in combined.samples if s.kind is SensorKind.ACC] == [0.1 + 9.7] * 2


@pytest.mark.parametrize("pad", [0, 2000], ids=["inline", "decoder process"])
def test_a_stream_keeps_total_acceleration_as_its_one_accelerometer(pad):
    """A Sensor Logger stream pushing total acceleration, user acceleration and gravity, whose short
    batches sometimes hold no total acceleration reading: before the first total acceleration the parts
    make the accelerometer, from it on only total acceleration does — the two were interleaved batch by
    batch (a stream's accelerometer alternating between two sensors). Small pushes decoded in the
    receiver, large ones in its decoder process, alike."""
    batches = [(False, True), (True, True), (False, True), (True, False), (False, True)]  # (total, parts)
    with PhonePushServer("http://127.0.0.1:0/") as server:
        host, port = server.url.split("//")[1].split("/")[0].split(":")
        conn = http.client.HTTPConnection(host, int(port), timeout=30)
        for i, (total, parts) in enumerate(batches):
            body = _app_batch(i + 1, 10**18 + i * 10**8, 2, total, parts, pad)
            conn.request("POST", "/", body, {"Content-Type": "application/json"})
            resp = conn.getresponse()
            assert resp.status == 200, resp.read()
            resp.read()
        conn.close()
        acc = [s.xyz[2] for s in server.drain() if s.kind is SensorKind.ACC]
        assert acc == [0.1 + 9.7] * 2 + [9.9] * 4  # the first batch's parts, then total acceleration only
        assert server.stats.ignored_entries == 3 * 4 + pad * len(batches)  # the parts of batches 2, 3, 5
