"""A phone stream's reading of JSON ``true``/``false`` is no reading (issue: ``{"values": [true, false,
true]}`` from a SensaGram-shaped sender, and a Sensor Logger push whose ``x`` was ``true``, were read as
1.0 and 0.0 — a gyroscope turning at 1 rad/s about two axes, handed to the estimator as live; the project's
one rule for numbers, :func:`hil.numbers.finite_number`, refuses a bool, the phone decoders did not).

Through real sockets into the real receivers: a datagram with a bool among its first three values (or in
an uncalibrated event's bias) is an unreadable message, counted and logged; a push entry with one is a bad
entry, counted; nothing of either is delivered. Numbers written as strings (Sensor Logger's exports do)
still read."""

from __future__ import annotations

import http.client
import json
import socket
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.link.sources.phone_push import PhonePushServer, decode_push
from hil.link.sources.phone_udp import PhoneUdpReceiver

EPOCH_NS = 1_698_501_144_401_773_000
ODD = st.sampled_from([True, False, None, [1.0], {"v": 1.0}, "true", "nan", "inf", "1e999"])


def _wait(predicate, timeout_s: float = 10.0) -> None:
    end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < end
        time.sleep(0.001)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(odd=ODD, at=st.integers(0, 2), kind=st.sampled_from(["gyroscope", "accelerometer", "magnetic_field"]))
def test_a_datagram_with_a_value_that_is_no_number_is_dropped_counted_never_read(odd, at, kind):
    """Drawn: what stands at which of the three values; the receiver counts the datagram unreadable
    (``bad_messages``, naming it) and hands nothing over; a datagram of numbers as strings is read."""
    with (
        PhoneUdpReceiver("udp://127.0.0.1:0") as receiver,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock,
    ):
        address = ("127.0.0.1", int(receiver.url.rsplit(":", 1)[1]))
        values: list[object] = [0.5, -0.25, 0.125]
        values[at] = odd
        sock.sendto(
            json.dumps({"type": f"android.sensor.{kind}", "timestamp": 10**9, "values": values}).encode(),
            address,
        )
        sock.sendto(
            json.dumps(
                {"type": f"android.sensor.{kind}", "timestamp": 2 * 10**9, "values": ["0.5", "1", "-2"]}
            ).encode(),
            address,
        )
        _wait(lambda: receiver.stats.bad_messages + receiver.stats.messages >= 2)
        assert receiver.stats.bad_messages == 1, receiver.stats
        assert "must be finite numbers" in receiver.stats.last_error
        samples = receiver.drain()
        assert [(s.t_s, s.xyz) for s in samples] == [(2.0, (0.5, 1.0, -2.0))]


def test_an_uncalibrated_event_s_bool_bias_is_no_bias():
    """A bias estimate of bools is none: the raw reading is taken as it is, not less 1.0."""
    with (
        PhoneUdpReceiver("udp://127.0.0.1:0") as receiver,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock,
    ):
        address = ("127.0.0.1", int(receiver.url.rsplit(":", 1)[1]))
        event = {
            "type": "android.sensor.gyroscope_uncalibrated",
            "timestamp": 10**9,
            "values": [0.5, 0.5, 0.5, True, True, True],
        }
        sock.sendto(json.dumps(event).encode(), address)
        _wait(lambda: receiver.stats.messages >= 1)
        assert [s.xyz for s in receiver.drain()] == [(0.5, 0.5, 0.5)]


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(odd=ODD, axis=st.sampled_from("xyz"))
def test_a_push_entry_with_a_value_that_is_no_number_is_a_bad_entry_never_read(odd, axis):
    """Drawn: what stands as which of ``x``, ``y``, ``z`` in one of three gyroscope entries of a push:
    that entry is counted bad (``bad_entries``), the other two delivered."""
    with PhonePushServer("http://127.0.0.1:0/push") as server:
        port = int(server.url.rsplit(":", 1)[1].split("/")[0])
        payload = []
        for i in range(3):
            values: dict[str, object] = {"x": 0.5, "y": -0.25, "z": 0.125}
            if i == 1:
                values[axis] = odd
            payload.append({"name": "gyroscope", "time": EPOCH_NS + i * 5_000_000, "values": values})
        body = json.dumps({"messageId": 0, "sessionId": "s", "deviceId": "d", "payload": payload}).encode()
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        try:
            conn.request("POST", "/push", body=body, headers={"Content-Type": "application/json"})
            assert conn.getresponse().status == 200
        finally:
            conn.close()
        assert server.stats.bad_entries == 1, server.stats
        samples = server.drain()
        assert len(samples) == 2 and all(s.xyz == (0.5, -0.25, 0.125) for s in samples)


@pytest.mark.parametrize("name", ["gyroscope", " Gyroscope", "GYROSCOPE\t", "\ngyroscope "])
def test_a_push_sensor_name_padded_or_capitalised_is_read_as_the_udp_decoder_reads_a_type(name):
    """``" gyroscope"`` was counted an ignored sensor, where the UDP decoder strips a type's spaces."""
    body = json.dumps(
        {
            "messageId": 1,
            "payload": [{"name": name, "time": 2_000_000_000, "values": {"x": 0.1, "y": 0.2, "z": 0.3}}],
        }
    ).encode()
    out = decode_push(body)
    assert (out.ignored, out.bad) == (0, 0)
    assert [s.xyz for s in out.samples] == [(0.1, 0.2, 0.3)]
