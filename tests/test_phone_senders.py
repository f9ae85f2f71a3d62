"""Two phones on one port: a live receiver follows one phone — the first heard — and drops, counts and logs
every other sender's messages, never merging them (``hil.link.sources.senders``); the followed phone gone
silent hands over to a new sender (an app restarted), never to one that streamed alongside it. Through the
real interfaces: UDP datagrams from sockets of their own (a source port each, as each app has), HTTP POSTs
from Sensor Logger-shaped senders with their own ``deviceId`` and ``sessionId``.

Also the hostile-but-well-formed input probed on the same receivers: finite numbers whose sum or unit
makes a non-finite reading (``1e308`` + ``1e308``, a float time of ``1e300`` read in seconds), and a spray
of senders from many source ports (the table of senders stays bounded, the log rate-limited)."""

from __future__ import annotations

import http.client
import json
import logging
import math
import socket
import time
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.listening import ListeningSource
from hil.link.sources.phone_push import INLINE_MAX, PhonePushSender, PhonePushServer, decode_push, encode_push
from hil.link.sources.phone_udp import PhoneUdpReceiver, decode_datagram, encode_datagram
from hil.link.sources.senders import MAX_SENDERS, SWITCH_AFTER_S, Decision, SenderTable
from hil.link.sources.stream import NEW_SENDER_LOGS, PhoneReceiver
from protocol.errors import InputFormatError, LinkError

EPOCH_NS = 1_698_501_144_401_773_000  # Sensor Logger stamps Unix ns: two phones' stamps are ms apart


class Clock:
    """A receiver's monotonic clock, moved by the test (s)."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _handled(receiver: PhoneReceiver) -> int:
    """Messages the receiver has dealt with: taken, refused, or dropped as another phone's."""
    st_ = receiver.stats
    return st_.messages + st_.bad_messages + st_.other_phone_messages


def _wait(predicate: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "the receiver did not take the messages in time"
        time.sleep(0.001)


def _drain_all(receiver: PhoneReceiver) -> list[SensorSample]:
    out: list[SensorSample] = []
    while batch := receiver.drain():
        out += batch
    return out


class App:
    """One phone app's UDP socket: a source port of its own, as SensaGram has."""

    def __init__(self, receiver: PhoneUdpReceiver) -> None:
        host, port = receiver.url.removeprefix("udp://").split(":")
        self.to = (host, int(port))
        self.receiver = receiver
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.name = f"127.0.0.1:{self.sock.getsockname()[1]}"

    def send(self, data: bytes, wait: bool = True) -> None:
        """One datagram; ``wait``: until the receiver has dealt with it (before the test's clock moves)."""
        before = _handled(self.receiver)
        self.sock.sendto(data, self.to)
        if wait:
            _wait(lambda: _handled(self.receiver) > before)

    def close(self) -> None:
        self.sock.close()


def _gyro(t_s: float, x: float, y: float = 0.0) -> SensorSample:
    return SensorSample(t_s, SensorKind.GYR, (x, y, 0.0))


# ======================================================================================== UDP (SensaGram)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.booleans(), min_size=1, max_size=40))
def test_any_interleaving_of_two_phones_datagrams_yields_only_the_first_heard_phone_s_samples(order):
    """Two SensaGram phones streaming to one port (each its own boot clock): before, their readings
    reached the estimator interleaved as one phone's. Now only the first heard phone's, every one, in
    order; the other's are counted (once as a phone, each as a message and a sample)."""
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        apps = [App(receiver), App(receiver)]
        sent: list[list[SensorSample]] = [[], []]
        for which in order:
            k = len(sent[which])
            sample = _gyro((1000.0, 5000.0)[which] + 0.005 * k, float(k), float(which))
            apps[which].send(encode_datagram(sample), wait=False)
            sent[which].append(sample)
        _wait(lambda: _handled(receiver) == len(order))
        first, other = int(order[0]), 1 - int(order[0])
        got = _drain_all(receiver)
        assert [(s.xyz, s.t_s) for s in got] == [(s.xyz, s.t_s) for s in sent[first]]
        st_ = receiver.stats
        assert st_.following == apps[first].name and st_.phone_switches == 0
        assert (st_.other_phone_messages, st_.other_phone_samples) == (len(sent[other]),) * 2
        assert st_.other_phones == (1 if sent[other] else 0)
        assert st_.samples == st_.messages == len(sent[first])
        for app in apps:
            app.close()


def test_a_restarted_app_from_a_new_source_port_is_followed_once_the_old_port_is_silent(caplog):
    """SensaGram restarted opens a new socket: the same phone, a new source port. Its datagrams are
    dropped while the old port may still be streaming, and followed once it has been silent for
    SWITCH_AFTER_S; the hand-over is counted and logged."""
    clock = Clock()
    with caplog.at_level(logging.INFO), PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver:
        before, after = App(receiver), App(receiver)
        for k in range(5):
            before.send(encode_datagram(_gyro(100.0 + 0.01 * k, k)))
            clock.now += 0.01
        clock.now += 0.5  # the app restarted: its new socket streams (from its boot clock, as before)
        after.send(encode_datagram(_gyro(101.0, 50)))
        assert receiver.stats.other_phone_messages == 1  # the old port may not be done: not followed yet
        clock.now += SWITCH_AFTER_S
        for k in range(3):
            after.send(encode_datagram(_gyro(103.0 + 0.01 * k, 60 + k)))
        got = _drain_all(receiver)
        assert [s.xyz[0] for s in got] == [0, 1, 2, 3, 4, 60, 61, 62]
        st_ = receiver.stats
        assert st_.phone_switches == 1 and st_.following == after.name and st_.other_phones == 1
        before.close()
        after.close()
    said = [r.getMessage() for r in caplog.records]
    assert any(f"following {before.name}, the first phone heard" in m for m in said)
    assert any(f"{before.name} silent for" in m and f"following {after.name}" in m for m in said)


def test_a_phone_that_streamed_alongside_is_never_followed_even_when_the_followed_one_goes_silent():
    """Two phones streaming at once, then the followed one stops (its battery died): the other one was
    streaming alongside it all the while, so it is not that phone — following it would steer the
    spacecraft on a phone lying on a desk. Its datagrams stay dropped; a new sender (the followed phone's
    app restarted) is followed."""
    clock = Clock()
    with PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver:
        phone, desk, restarted = App(receiver), App(receiver), App(receiver)
        for k in range(4):
            phone.send(encode_datagram(_gyro(100.0 + 0.01 * k, k)))
            desk.send(encode_datagram(_gyro(900.0 + 0.01 * k, -k)))
            clock.now += 0.01
        clock.now += 10 * SWITCH_AFTER_S  # the phone is gone
        for k in range(3):
            desk.send(encode_datagram(_gyro(901.0 + 0.01 * k, -10 - k)))
        restarted.send(encode_datagram(_gyro(200.0, 77)))
        desk.send(encode_datagram(_gyro(902.0, -99)))
        got = _drain_all(receiver)
        assert [s.xyz[0] for s in got] == [0, 1, 2, 3, 77]
        st_ = receiver.stats
        assert st_.following == restarted.name and st_.phone_switches == 1
        assert st_.other_phones == 1 and st_.other_phone_messages == 4 + 3 + 1
        for app in (phone, desk, restarted):
            app.close()


events = st.lists(
    st.tuples(st.integers(0, 2), st.sampled_from([0.0, 0.01, 0.3, 1.0, 2.5])), min_size=1, max_size=30
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(events)
@example(
    [(0, 0.0), (1, 0.01), (0, 0.01), (1, 2.5), (2, 0.3), (1, 2.5)]
)  # 1 streamed alongside 0: never followed
def test_senders_taking_turns_hand_over_only_after_silence_and_never_interleave(steps):
    """Three senders taking turns, pausing, coming back, any way (the time moves between datagrams),
    checked on the recorded history: every datagram delivered or counted; the first sender heard is
    followed first; the delivered stream changes sender only after the one before was silent for
    SWITCH_AFTER_S; and a sender dropped while another was followed, which then sent again, is never
    delivered afterwards (it streamed alongside: two phones never interleave)."""
    clock = Clock()
    with PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver:
        apps = [App(receiver) for _ in range(3)]
        history: list[tuple[int, float, int]] = []  # (sender, when sent, how many samples delivered after)
        delivered_count = 0
        for k, (who, dt) in enumerate(steps):
            clock.now += dt
            apps[who].send(encode_datagram(_gyro(100.0 * (who + 1) + 0.001 * k, k, who)))
            delivered_count += len(receiver.drain())
            history.append((who, clock.now, delivered_count))
        for app in apps:
            app.close()
    delivered = [i for i, (_, _, n) in enumerate(history) if n > (history[i - 1][2] if i else 0)]
    assert len(delivered) + receiver.stats.other_phone_samples == len(steps)  # all accounted for
    assert delivered[0] == 0  # the first sender heard is followed
    for a, b in zip(delivered, delivered[1:], strict=False):
        before, after = history[a][0], history[b][0]
        if before != after:  # a hand-over: the one followed was silent for the bound
            last_of_before = max(t for w, t, _ in history[:b] if w == before)
            assert history[b][1] - last_of_before > SWITCH_AFTER_S
    followed_at = {i: history[max(d for d in delivered if d <= i)][0] for i in range(len(history))}
    for i, (who, _, _) in enumerate(history):
        if i in delivered:
            continue
        later = [j for j in delivered if j > i]
        if later and history[later[0]][0] == followed_at[i] != who:  # the followed one sent again
            assert not [j for j in delivered if j > later[0] and history[j][0] == who], (i, who)


def test_a_new_phone_s_uncalibrated_stream_is_read_after_a_hand_over():
    """Which sensors a stream calibrates is that app's: the phone followed before sent the calibrated
    gyroscope; the one followed after it sends only the uncalibrated type, read as before (it was
    ignored: the previous phone's calibrated gyroscope counted as this one's)."""
    clock = Clock()
    with PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver:
        first, second = App(receiver), App(receiver)
        first.send(encode_datagram(_gyro(100.0, 0.5)))
        clock.now += SWITCH_AFTER_S + 0.1
        raw = {
            "type": "android.sensor.gyroscope_uncalibrated",
            "timestamp": 7 * 10**9,
            "values": [0.3, 0, 0, 0.1, 0, 0],
        }
        second.send(json.dumps(raw).encode())
        got = _drain_all(receiver)
        assert [s.xyz[0] for s in got] == [0.5, pytest.approx(0.2)]
        assert receiver.stats.ignored_entries == 0 and receiver.stats.phone_switches == 1
        first.close()
        second.close()


def test_each_new_phone_is_logged_once_and_another_sensor_only_captures_nothing(caplog):
    """A second and a third phone: one warning each, naming it and the phone followed, however much it
    sends. A sender with only sensors the host does not use (a light sensor) follows nobody, and holds
    nothing to drop: counted as before, not as a phone."""
    with caplog.at_level(logging.INFO), PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        light, phone, second, third = (App(receiver) for _ in range(4))
        light.send(json.dumps({"type": "android.sensor.light", "timestamp": 1, "values": [5, 0, 0]}).encode())
        for k in range(20):
            phone.send(encode_datagram(_gyro(1.0 + 0.01 * k, k)), wait=False)
            second.send(encode_datagram(_gyro(2.0 + 0.01 * k, k)), wait=False)
            third.send(encode_datagram(_gyro(3.0 + 0.01 * k, k)), wait=False)
        _wait(lambda: _handled(receiver) == 61)
        st_ = receiver.stats
        assert st_.following == phone.name and st_.samples == 20 and st_.ignored_entries == 1
        assert (st_.other_phones, st_.other_phone_messages, st_.other_phone_samples) == (2, 40, 40)
        for app in (light, phone, second, third):
            app.close()
    others = [r.getMessage() for r in caplog.records if "another phone" in r.getMessage()]
    assert len(others) == 2
    assert second.name in others[0] and third.name in others[1] and f"following {phone.name}" in others[0]


def test_a_spray_of_senders_is_remembered_in_a_bounded_table_and_logged_under_a_rate_limit(caplog):
    """A peer sending from hundreds of source ports (or a lab full of phones): the receiver remembers at
    most MAX_SENDERS of them, logs at most NEW_SENDER_LOGS lines a second (the next one says how many
    more came), counts them all — and still follows its phone."""
    n = MAX_SENDERS + 300
    clock = Clock()
    with PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver:
        phone = App(receiver)
        phone.send(encode_datagram(_gyro(1.0, 0)))
        spray = [
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)
        ]  # open: ports of their own
        for k, sock in enumerate(spray):
            sock.sendto(encode_datagram(_gyro(50.0 + k, k)), phone.to)
        _wait(lambda: _handled(receiver) == n + 1)
        assert len(receiver._senders) <= MAX_SENDERS + 1
        clock.now += 1.0
        with caplog.at_level(logging.WARNING):
            App(receiver).send(encode_datagram(_gyro(60.0, 0)))
        for sock in spray:  # only now: closed before, one's port could be the new sender's (the same sender)
            sock.close()
        phone.send(encode_datagram(_gyro(1.01, 1)))
        st_ = receiver.stats
        assert st_.other_phones == n + 1 and st_.other_phone_samples == n + 1
        assert [s.xyz[0] for s in _drain_all(receiver)] == [0, 1]
        phone.close()
    said = [r.getMessage() for r in caplog.records if "another phone" in r.getMessage()]
    assert len(said) == NEW_SENDER_LOGS + 1 and f"and {n - NEW_SENDER_LOGS} more new senders" in said[-1]


def test_the_sender_table_stays_bounded_whatever_is_sent():
    table = SenderTable()
    assert table.hear("phone", 0.0, True).decision is Decision.FIRST
    for k in range(100_000):
        assert table.hear(("spray", k), 0.001 * k, True).decision is Decision.OTHER
        table.hear("phone", 0.001 * k, True)
    assert len(table) == MAX_SENDERS + 1


# ==================================================================================== HTTP (Sensor Logger)
def _batch(k: int, t0_ns: int, x: float) -> list[SensorSample]:
    t = (t0_ns + k * 20_000_000) / 1e9
    return [
        SensorSample(t, SensorKind.GYR, (x, k, 0.0)),
        SensorSample(t + 0.005, SensorKind.MAG, (x, k, -40.0)),
    ]


def test_two_sensor_logger_phones_pushing_to_one_port_only_the_first_is_taken_and_its_numbering_kept():
    """Two Sensor Logger phones, both stamping Unix ns, pushing to one port: before, their batches were
    merged — readings within ms of each other, passing for one phone's — and their messageIds counted as
    each other's losses. Now only the first phone's are taken; the other's are answered 200 (an app that
    saw errors might stop), dropped, counted, and in the run's summary."""
    with PhonePushServer("http://127.0.0.1:0/") as server:
        a = PhonePushSender(server.url, session="6f1c2a", device="pixel-7")
        b = PhonePushSender(server.url, session="93bd44", device="galaxy-a52")
        b.message_id = 500
        want = []
        for k in range(10):
            batch = _batch(k, EPOCH_NS, 1.0)
            assert a.send(batch) and b.send(_batch(k, EPOCH_NS + 3_000_000, 2.0))
            want += batch
        assert b.send([]) and a.send(_batch(10, EPOCH_NS, 1.0))  # nothing usable: nothing of the stream's
        want += _batch(10, EPOCH_NS, 1.0)
        got = _drain_all(server)
        assert [(s.kind, s.xyz) for s in got] == [(s.kind, s.xyz) for s in want]
        st_ = server.stats
        assert (st_.message_gaps, st_.message_restarts) == (0, 0)
        assert (st_.other_phones, st_.other_phone_messages, st_.other_phone_samples) == (1, 10, 20)
        assert st_.following == "deviceId 'pixel-7' sessionId '6f1c2a' from 127.0.0.1"
        phone = ListeningSource(server).report()["phone"]
        assert json.loads(json.dumps(phone))["other_phone_samples"] == 20  # summary.json's phone section
        a.close()
        b.close()


def test_a_large_push_is_told_by_its_ids_too():
    """A push over INLINE_MAX is decoded in the decoder process: its ids come back with its readings —
    another phone's is dropped, the followed phone's own taken."""
    big = [SensorSample(EPOCH_NS / 1e9 + 1e-3 * k, SensorKind.GYR, (2.0, k, 0.0)) for k in range(2000)]
    with PhonePushServer("http://127.0.0.1:0/") as server:
        a = PhonePushSender(server.url, session="s-a", device="phone-a")
        assert a.send(_batch(0, EPOCH_NS, 1.0))
        for body, answer in ((encode_push(big, 1, "s-b", "phone-b"), b"follows another phone"),
                             (encode_push(big, 1, "s-a", "phone-a"), b"ok")):  # fmt: skip
            assert len(body) > INLINE_MAX
            host, port = server.url.removeprefix("http://").split("/")[0].split(":")
            conn = http.client.HTTPConnection(host, int(port), timeout=30)
            conn.request("POST", "/", body, {"Content-Type": "application/json"})
            response = conn.getresponse()
            assert response.status == 200 and answer in response.read()
            conn.close()
        assert server._decoder._proc is not None  # they went through the decoder process
        assert [s.xyz[0] for s in _drain_all(server)] == [1.0, 1.0] + [2.0] * 2000
        assert server.stats.other_phone_samples == 2000 and server.stats.samples == 2002
        a.close()


def _app_batch(message_id: int, session: str, t_ns: int, total: bool) -> bytes:
    """A Sensor Logger batch of a gyroscope reading and an accelerometer: total acceleration (``total``),
    or its parts, user acceleration and gravity."""
    entry = lambda name, z: {"name": name, "time": t_ns, "values": {"x": 0.0, "y": 0.0, "z": z}}  # noqa: E731
    acc = [entry("totalacceleration", 9.9)] if total else [entry("accelerometer", 0.1), entry("gravity", 9.7)]
    doc = {
        "messageId": message_id,
        "sessionId": session,
        "deviceId": "pixel-7",
        "payload": [entry("gyroscope", 0.01), *acc],
    }
    return json.dumps(doc).encode()


def _post(server: PhonePushServer, body: bytes) -> int:
    host, port = server.url.removeprefix("http://").split("/")[0].split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    try:
        conn.request("POST", "/", body, {"Content-Type": "application/json"})
        answer = conn.getresponse()
        answer.read()
        return answer.status
    finally:
        conn.close()


def test_the_app_restarted_with_a_new_session_is_followed_afresh():
    """Sensor Logger restarted: the same deviceId, a new sessionId, its messageIds from 0 again, and this
    time only user acceleration and gravity. Its batches are dropped while the old session may still be
    pushing, then followed; the new session starts its own stream: no numbering restart counted (the hand-over
    is), and its parts make its accelerometer from its first batch followed (the old session's total
    acceleration had made the parts ignored, and the batch was read for the old session)."""
    clock = Clock()
    with PhonePushServer("http://127.0.0.1:0/", clock=clock) as server:
        for k in range(3):
            assert _post(server, _app_batch(10 + k, "s1", EPOCH_NS + k * 20_000_000, total=True)) == 200
            clock.now += 0.02
        clock.now += 0.5
        assert _post(server, _app_batch(0, "s2", EPOCH_NS + 10**9, total=False)) == 200
        assert server.stats.other_phone_messages == 1
        clock.now += SWITCH_AFTER_S
        for k in range(1, 3):
            assert (
                _post(server, _app_batch(k, "s2", EPOCH_NS + 3 * 10**9 + k * 20_000_000, total=False)) == 200
            )
        acc = [s.xyz[2] for s in _drain_all(server) if s.kind is SensorKind.ACC]
        assert acc == [9.9] * 3 + [pytest.approx(9.8)] * 2
        st_ = server.stats
        assert st_.phone_switches == 1 and st_.message_restarts == 0 and st_.message_gaps == 0
        assert "sessionId 's2'" in st_.following


def test_a_long_push_period_is_not_silence():
    """A phone pushing every 3 s (a long batch period) is not silent between its batches: a new phone
    heard 2.5 s after its last batch is not followed (it was, with a bound of SWITCH_AFTER_S alone, and the
    phone's next batch then was another phone's). A sender is silent after four of its usual periods."""
    clock = Clock()
    with PhonePushServer("http://127.0.0.1:0/", clock=clock) as server:
        slow = PhonePushSender(server.url, session="s", device="slow")
        for k in range(5):
            assert slow.send(_batch(k, EPOCH_NS, 1.0))
            clock.now += 3.0
        clock.now -= 0.5
        newcomer = PhonePushSender(server.url, session="n", device="newcomer")
        assert newcomer.send(_batch(0, EPOCH_NS, 2.0))
        clock.now += 0.5
        assert slow.send(_batch(5, EPOCH_NS, 1.0))
        clock.now += 4 * 3.0 + 0.1
        restarted = PhonePushSender(server.url, session="r", device="slow")
        assert restarted.send(_batch(0, EPOCH_NS, 3.0))
        assert [s.xyz[0] for s in _drain_all(server)] == [1.0] * 12 + [3.0] * 2
        assert server.stats.other_phone_messages == 1 and server.stats.phone_switches == 1
        for sender in (slow, newcomer, restarted):
            sender.close()


def test_a_run_waiting_for_its_phone_says_another_phone_s_messages_were_dropped():
    """The phone followed streams only its gyroscope; another phone the accelerometer: the run cannot
    start, and the error says the other phone's messages were dropped and which phone is followed."""
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        phone, other = App(receiver), App(receiver)
        phone.send(encode_datagram(_gyro(1.0, 0.1)))
        other.send(encode_datagram(SensorSample(1.0, SensorKind.ACC, (0.0, 0.0, 9.8))))
        with pytest.raises(LinkError) as raised:
            ListeningSource(receiver).wait_ready(0.1, lambda: None)
        assert f"1 messages of 1 other phone(s) dropped: the receiver follows one phone, {phone.name}" in str(
            raised.value
        )
        phone.close()
        other.close()


# ================================================================ finite numbers making a non-finite reading
def test_an_uncalibrated_reading_less_a_finite_bias_past_a_float_is_refused():
    """``1e308`` less a bias of ``-1e308``: both finite, the reading not — a sample of inf reached the
    consumer, counted as a good one. Now the datagram is refused and counted."""
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        app = App(receiver)
        event = {"type": "android.sensor.gyroscope_uncalibrated", "timestamp": 10**9,
                 "values": [1e308, 0, 0, -1e308, 0, 0]}  # fmt: skip
        app.send(json.dumps(event).encode())
        app.send(encode_datagram(_gyro(1.1, 0.5)))
        assert [s.xyz for s in _drain_all(receiver)] == [(0.5, 0.0, 0.0)]
        assert receiver.stats.bad_messages == 1 and "not finite" in receiver.stats.last_error
        app.close()


def test_a_push_s_finite_numbers_that_make_a_non_finite_reading_are_counted_bad():
    """User acceleration plus gravity of ``1e308`` each, and a float time of ``1e300`` in a batch read in
    seconds (its other readings an epoch in s, 10 ms apart): each made a reading of inf, handed to the
    consumer as good. Now each is a bad entry."""
    entry = lambda name, t, x: {"name": name, "time": t, "values": {"x": x, "y": 0.0, "z": 0.0}}  # noqa: E731
    parts = {"payload": [entry("accelerometer", 10**9, 1e308), entry("gravity", 10**9, 1e308)]}
    seconds = {"payload": [entry("gyroscope", 1.7e9 + 0.01 * k, 0.1) for k in range(5)]}
    seconds["payload"].append(entry("gyroscope", 1e300, 0.1))
    with PhonePushServer("http://127.0.0.1:0/") as server:
        assert _post(server, json.dumps(parts).encode()) == 200
        assert _post(server, json.dumps(seconds).encode()) == 200
        got = _drain_all(server)
        assert len(got) == 5 and all(math.isfinite(v) for s in got for v in (s.t_s, *s.xyz))
        assert server.stats.bad_entries == 2 and server.stats.samples == 5


any_finite = st.floats(allow_nan=False, allow_infinity=False)
finite_times = st.integers(-(10**20), 10**20) | any_finite


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["totalacceleration", "gyroscope", "magnetometer", "accelerometer", "gravity"]),
            finite_times,
            st.tuples(any_finite, any_finite, any_finite),
        ),
        max_size=12,
    ),
    st.sampled_from(["android.sensor.gyroscope", "android.sensor.magnetic_field_uncalibrated"]),
    st.tuples(*[any_finite] * 6),
    finite_times,
)
@example(  # user acceleration plus gravity past a float; a float time in a batch read in seconds
    [("accelerometer", 10**9, (1e308, 0.0, 0.0)), ("gravity", 10**9, (1e308, 0.0, 0.0))]
    + [("gyroscope", 1.7e9 + 0.01 * k, (0.0, 0.0, 0.0)) for k in range(5)]
    + [("gyroscope", 1e300, (0.0, 0.0, 0.0))],
    "android.sensor.magnetic_field_uncalibrated",
    (1e308, 0.0, 0.0, -1e308, 0.0, 0.0),  # a reading less its bias past a float
    1e160,
)
def test_finite_numbers_never_make_a_non_finite_sample(entries, kind, values, t_ns):
    """Whatever finite numbers a well-formed message holds — 1e160, 1e308, -1e308 —, every sample either
    decoder hands over has a finite time and finite values (the admission is not where a decoder's inf
    should first be noticed)."""
    body = {
        "payload": [{"name": n, "time": t, "values": dict(zip("xyz", v, strict=True))} for n, t, v in entries]
    }
    batch = decode_push(json.dumps(body).encode())
    datagram = json.dumps({"type": kind, "timestamp": t_ns, "values": list(values)}).encode()
    try:
        one = [decode_datagram(datagram)]
    except InputFormatError:
        one = []
    for sample in [*batch.samples, *one]:
        assert all(math.isfinite(v) for v in (sample.t_s, *sample.xyz)), sample
