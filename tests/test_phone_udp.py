"""The live phone path over UDP: SensaGram datagrams, parsed purely and carried over real loopback UDP;
the phone-stream URL registry."""

from __future__ import annotations

import json
import socket
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources import open_receiver, open_sender, phone_url
from hil.link.sources.phone_push import PhonePushSender, PhonePushServer
from hil.link.sources.phone_udp import (
    PhoneUdpReceiver,
    PhoneUdpSender,
    UncalibratedSample,
    decode_datagram,
    encode_datagram,
)
from protocol.errors import ConfigError, InputFormatError, LinkError

finite = st.floats(-1e4, 1e4, allow_nan=False)
a_sample = st.builds(
    SensorSample,
    st.integers(0, 10**16).map(lambda ns: ns * 1e-9),  # boot-clock nanoseconds (months of uptime)
    st.sampled_from(list(SensorKind)),
    st.tuples(finite, finite, finite),
)


@settings(max_examples=100, deadline=None)
@given(a_sample)
def test_encode_then_decode_returns_the_sample(sample):
    got = decode_datagram(encode_datagram(sample))
    assert got is not None and got.kind is sample.kind and got.xyz == sample.xyz
    assert got.t_s == pytest.approx(sample.t_s, abs=1e-9)


def test_the_apps_datagrams():
    """As SensaGram's SensorStreamer writes them: timestamp (ns, boot clock), values, Android type."""
    acc = b'{"timestamp":3925657519043709,"values":[0.31892395,-0.97802734,10.049896],' \
          b'"type":"android.sensor.accelerometer"}'  # fmt: skip
    got = decode_datagram(acc)
    assert got == SensorSample(3925657.519043709, SensorKind.ACC, (0.31892395, -0.97802734, 10.049896))
    mag = {"values": [21.5, -3.0, -40.25], "type": "android.sensor.magnetic_field", "timestamp": 10**9}
    want = SensorSample(1.0, SensorKind.MAG, (21.5, -3.0, -40.25))
    assert decode_datagram(json.dumps(mag).encode()) == want
    # another sensor is ignored (an uncalibrated one: below)
    for other in (
        {"type": "android.gps", "latitude": 1.0, "longitude": 2.0},
        {"type": "android.sensor.light"},
    ):
        assert decode_datagram(json.dumps(other).encode()) is None


def test_a_client_s_spelling_of_the_type_and_its_timestamp_as_a_string_are_read():
    """Another client than SensaGram: its type in another case, its long timestamp as a digit string
    (they were ignored and refused, while the HTTP push takes both)."""
    doc = {"type": "Android.Sensor.Gyroscope", "timestamp": "2000000000", "values": [0.1, 0.2, 0.3]}
    assert decode_datagram(json.dumps(doc).encode()) == SensorSample(2.0, SensorKind.GYR, (0.1, 0.2, 0.3))


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"", "not JSON"),
        (b"\xff\xfe", "not JSON"),
        (b"[1, 2, 3]", "string 'type'"),
        (b'{"values": [1, 2, 3]}', "string 'type'"),
        (b'{"type": "android.sensor.gyroscope", "values": [1, 2, 3]}', "timestamp"),
        (b'{"type": "android.sensor.gyroscope", "timestamp": true, "values": [1, 2, 3]}', "timestamp"),
        (b'{"type": "android.sensor.gyroscope", "timestamp": 5, "values": [1, 2]}', "3 numbers"),
        (b'{"type": "android.sensor.gyroscope", "timestamp": 5, "values": [1, "x", 2]}', "numbers"),
        (b'{"type": "android.sensor.gyroscope", "timestamp": 5, "values": [1, NaN, 2]}', "finite"),
        # digits that are no ASCII digits: str.isdigit() takes them, int() does not (a bare ValueError)
        (b'{"type": "android.sensor.gyroscope", "timestamp": "\\u00b2", "values": [1, 2, 3]}', "timestamp"),
        (b'{"type": "android.sensor.gyroscope", "timestamp": "\\u0663", "values": [1, 2, 3]}', "timestamp"),
    ],
)
def test_malformed_datagrams_are_input_format_errors_naming_the_source(data, reason):
    with pytest.raises(InputFormatError, match=reason) as info:
        decode_datagram(data, "udp from 10.0.0.7")
    assert info.value.path == "udp from 10.0.0.7"


def test_a_sender_streams_to_the_receiver_over_loopback_udp():
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        sender = PhoneUdpSender(receiver.url)
        sent = [SensorSample(5.0 + 0.005 * k, SensorKind.GYR, (k, 0.0, -k)) for k in range(200)]
        sent += [SensorSample(5.0 + 0.02 * k, SensorKind.MAG, (30.0, k, -20.0)) for k in range(50)]
        assert sender.send(sent) and sender.sent == 250
        got = _receive(receiver, 250)
        # loopback keeps the order; values survive the JSON, times to the format's nanosecond
        assert [(s.kind, s.xyz) for s in got] == [(s.kind, s.xyz) for s in sent]
        assert max(abs(a.t_s - b.t_s) for a, b in zip(got, sent, strict=True)) <= 1e-9
        assert receiver.stats.per_kind == {"gyr": 200, "mag": 50} and receiver.stats.messages == 250
        sender.close()


def test_garbage_and_other_sensors_are_counted_and_the_receiver_keeps_listening():
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        host, port = receiver.url.removeprefix("udp://").split(":")
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for data in (b"{broken", b'{"type":"android.gps","latitude":1}', b"\x00" * 2000):
            raw.sendto(data, (host, int(port)))
        raw.close()
        PhoneUdpSender(receiver.url).send([SensorSample(1.0, SensorKind.ACC, (0.0, 0.0, 9.8))])
        got = _receive(receiver, 1)
        assert [s.xyz for s in got] == [(0.0, 0.0, 9.8)]
        st = receiver.stats
        assert (st.bad_messages, st.ignored_entries, st.samples) == (2, 1, 1)
        assert "not JSON" in st.last_error


def _event(kind: str, t_ns: int, values: list[float]) -> bytes:
    return json.dumps({"timestamp": t_ns, "values": values, "type": kind}).encode()


def test_an_uncalibrated_event_is_its_reading_less_its_bias_estimate():
    """Android's ``…_uncalibrated`` types carry the raw reading and the OS's bias estimate: read as their
    difference (what the calibrated type reports), an :class:`UncalibratedSample`; without a finite
    estimate, the raw reading."""
    got = decode_datagram(
        _event("android.sensor.gyroscope_uncalibrated", 10**9, [0.5, -0.25, 1.0, 0.125, 0.5, -1.0])
    )
    assert type(got) is UncalibratedSample and got == UncalibratedSample(
        1.0, SensorKind.GYR, (0.375, -0.75, 2.0)
    )
    mag = decode_datagram(_event("Android.Sensor.Magnetic_Field_Uncalibrated", 2 * 10**9, [30.0, 5.0, -40.0]))
    assert mag == UncalibratedSample(2.0, SensorKind.MAG, (30.0, 5.0, -40.0))
    nan_bias = _event("android.sensor.accelerometer_uncalibrated", 10**9, [0.0, 0.0, 9.8, "x", 1e400, 0.0])
    assert decode_datagram(nan_bias.replace(b"Infinity", b"1e400")) == UncalibratedSample(
        1.0, SensorKind.ACC, (0.0, 0.0, 9.8)
    )
    with pytest.raises(InputFormatError):
        decode_datagram(
            _event(
                "android.sensor.gyroscope_uncalibrated", 10**9, [float("nan"), 0.0, 0.0, 0.0, 0.0, 0.0]
            ).replace(b"NaN", b"1e999")
        )


def test_a_stream_of_uncalibrated_events_is_used_until_the_calibrated_type_is_heard():
    """A SensaGram stream with only a sensor's uncalibrated type is read from it (less its bias
    estimate); once the calibrated type of that sensor is heard, the stream's uncalibrated events of it
    are ignored and counted — the two are never interleaved — while another sensor's uncalibrated
    events still count as readings until its own calibrated type comes."""
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        host, port = receiver.url.removeprefix("udp://").split(":")
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        events = [
            _event("android.sensor.gyroscope_uncalibrated", 1_000_000_000, [0.2, 0.0, 0.0, 0.1, 0.0, 0.0]),
            _event(
                "android.sensor.magnetic_field_uncalibrated", 1_001_000_000, [35.0, 0.0, -40.0, 5.0, 0.0, 0.0]
            ),
            _event("android.sensor.gyroscope", 1_005_000_000, [0.11, 0.0, 0.0]),
            _event("android.sensor.gyroscope_uncalibrated", 1_006_000_000, [0.3, 0.0, 0.0, 0.1, 0.0, 0.0]),
            _event(
                "android.sensor.magnetic_field_uncalibrated", 1_007_000_000, [36.0, 0.0, -40.0, 5.0, 0.0, 0.0]
            ),
            _event("android.sensor.gyroscope", 1_010_000_000, [0.12, 0.0, 0.0]),
        ]
        for data in events:
            raw.sendto(data, (host, int(port)))
            time.sleep(0.002)  # loopback keeps the order; the receiver reads them in turn
        raw.close()
        got = _receive(receiver, 5)
        assert [(s.kind, s.xyz[0]) for s in got] == [
            (SensorKind.GYR, 0.1), (SensorKind.MAG, 30.0), (SensorKind.GYR, 0.11), (SensorKind.MAG, 31.0),
            (SensorKind.GYR, 0.12),
        ]  # fmt: skip
        assert all(type(s) is SensorSample for s in got)
        assert (
            receiver.stats.ignored_entries == 1
        )  # the gyroscope's uncalibrated event after its calibrated one


def test_a_full_queue_drops_the_oldest_and_counts_them():
    with PhoneUdpReceiver("udp://127.0.0.1:0", max_queue=10) as receiver:
        sent = [SensorSample(float(k), SensorKind.GYR, (0.0, 0.0, float(k))) for k in range(25)]
        PhoneUdpSender(receiver.url).send(sent)
        deadline = time.monotonic() + 5
        while receiver.stats.samples < 25 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert receiver.drain() == sent[-10:] and receiver.stats.overflow == 15


def test_a_sender_keeps_streaming_while_nobody_listens_and_the_host_comes_back():
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        url = receiver.url
    sender = PhoneUdpSender(url)
    sample = SensorSample(1.0, SensorKind.GYR, (0.0, 0.0, 0.0))
    for _ in range(5):  # fire and forget: the datagrams are lost, the sender carries on
        assert sender.send([sample])
    assert (sender.sent, sender.failed) == (5, 0)
    with PhoneUdpReceiver(url) as receiver:  # the host comes back on the same port
        later = SensorSample(2.0, SensorKind.GYR, (0.0, 0.0, 1.0))
        assert sender.send([later])
        assert _receive(receiver, 1) == [later]


def test_busy_ports_and_bad_urls_are_clear_errors():
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        port = receiver.url.rsplit(":", 1)[1]
        with pytest.raises(LinkError, match=port):
            PhoneUdpReceiver(f"udp://127.0.0.1:{port}")
    for bad in ("udp://127.0.0.1", "udp://:80", "udp://host:port"):  # a bad address is the option's error
        with pytest.raises(ConfigError, match="udp://HOST:PORT"):
            PhoneUdpSender(bad)
    with pytest.raises(ConfigError, match="udp://HOST:PORT or http://") as info:
        phone_url("tcp://127.0.0.1:1")
    assert info.value.where == "--phone"


def test_the_registry_picks_the_app_by_url():
    assert phone_url("0.0.0.0:8123") == "udp://0.0.0.0:8123"
    assert phone_url("http://0.0.0.0:8123/push") == "http://0.0.0.0:8123/push"
    with open_receiver("127.0.0.1:0") as udp, open_receiver("http://127.0.0.1:0/") as http:
        assert isinstance(udp, PhoneUdpReceiver) and udp.url.startswith("udp://127.0.0.1:")
        assert isinstance(http, PhonePushServer) and http.url.startswith("http://127.0.0.1:")
        to_udp, to_http = open_sender(udp.url), open_sender(http.url)
        assert isinstance(to_udp, PhoneUdpSender) and isinstance(to_http, PhonePushSender)
        sample = SensorSample(2.0, SensorKind.MAG, (1.0, 2.0, 3.0))
        assert to_udp.send([sample]) and to_http.send([sample])
        assert _receive(udp, 1) == [sample] and _receive(http, 1) == [sample]
        to_http.close()
        to_udp.close()


def _receive(receiver, n: int, timeout_s: float = 5.0) -> list[SensorSample]:
    """What ``receiver`` drains until ``n`` samples have arrived (the network thread delivers them)."""
    got: list[SensorSample] = []
    deadline = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < deadline:
        got += receiver.drain()
        time.sleep(0.005)
    return got


def test_datagrams_the_kernel_drops_are_counted_never_silently_lost(caplog):
    """A flood faster than the receiver reads (a host left unscheduled longer than its receive buffer holds,
    as the soak saw under load): whatever the kernel drops is counted from its own report (SO_RXQ_OVFL,
    stamped on each datagram as it is queued) and logged, so every datagram sent is read or counted."""
    datagram = encode_datagram(SensorSample(1.0, SensorKind.GYR, (0.0, 0.0, 0.1))) + b" " * 1_000
    # A queue holding the whole flood: the only drops are the kernel's (the first warning is theirs).
    with PhoneUdpReceiver("udp://127.0.0.1:0", max_queue=FLOOD + 1) as receiver:
        assert receiver.counts_kernel_drops  # Linux
        host, port = receiver.url.removeprefix("udp://").split(":")
        address = (host, int(port))

        def accounted() -> int:
            st = receiver.stats
            return st.messages + st.bad_messages + st.kernel_dropped

        def settle() -> None:
            """Until the receiver has read what the kernel holds (nothing new for a second)."""
            last, quiet_since, deadline = -1, time.monotonic(), time.monotonic() + 120
            while time.monotonic() < deadline and time.monotonic() - quiet_since < 1.0:
                if (now := accounted()) != last:
                    last, quiet_since = now, time.monotonic()
                time.sleep(0.05)

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:
            # The receiver's thread stalled at its first delivery while the flood goes out, as a host left
            # unscheduled is: the kernel's buffer overflows whatever this machine's speed (a CI machine
            # once read a free-running flood as fast as it came, and nothing was dropped to count).
            with receiver._lock:
                for _ in range(FLOOD):
                    raw.sendto(datagram, address)
            settle()
            raw.sendto(datagram, address)  # queued after the flood: it carries the flood's whole count
            settle()
        st = receiver.stats
        assert st.kernel_dropped > 0, "the flood did not overrun the receive buffer"
        assert accounted() == FLOOD + 1 and st.overflow == 0
    assert any("receive buffer was full" in r.getMessage() for r in caplog.records)


FLOOD = 60_000
"""Datagrams of ~1.1 kB sent as fast as one socket can (~66 MB): several times the 8 MB receive buffer."""
