"""A phone stream that turns a sensor's calibrated type off mid-run and keeps its raw type (issue: a
SensaGram stream switched from ``android.sensor.gyroscope`` to ``…gyroscope_uncalibrated`` had every later
gyroscope reading ignored — counted only among other sensors', no warning — and the run lost to "no
gyroscope reading came"; Sensor Logger's total acceleration turned off, its user acceleration and gravity
kept, the same for the accelerometer).

A calibrated type holds its sensor while it streams; silent for ``CALIBRATED_QUIET_S`` it no longer does:
its raw type is read again, the change counted (``calibrated_lapses``) and logged. The two are still never
interleaved: a raw reading within that bound of the calibrated type's last is ignored, as before.

Real sockets and the real receivers; the receivers' clock is injected, so the silences are drawn, not
slept.
"""

from __future__ import annotations

import json
import socket
import time
import urllib.request

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.link.sources.phone_push import PhonePushServer
from hil.link.sources.phone_udp import PhoneUdpReceiver
from hil.link.sources.stream import CALIBRATED_QUIET_S, PhoneReceiver


class _Clock:
    """The receivers' clock (s), moved by the test."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _wait_messages(receiver: PhoneReceiver, n: int) -> None:
    """Until the receiver's thread has taken ``n`` messages (accepted or not) off its socket."""
    end = time.monotonic() + 10.0
    while receiver.stats.messages + receiver.stats.bad_messages < n:
        assert time.monotonic() < end, receiver.stats
        time.sleep(0.001)


def _drain(receiver: PhoneReceiver) -> list[float]:
    out: list[float] = []
    while batch := receiver.drain():
        out += [s.xyz[2] for s in batch]
    return out


CAL, RAW = 0.25, 0.5  # the gyroscope's z as each type sends it: told apart by the value


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(st.booleans(), st.sampled_from([0.005, 0.5, CALIBRATED_QUIET_S - 0.01, 2.5, 30.0])),
        min_size=1,
        max_size=25,
    )
)
def test_udp_uncalibrated_takes_over_once_the_calibrated_type_is_silent(plan):
    """Drawn: each event calibrated or uncalibrated, after a drawn silence on the receiver's clock. Model:
    an uncalibrated event is read iff no calibrated one came within ``CALIBRATED_QUIET_S`` before it; a
    calibrated one always. A calibrated type that went silent that long is counted once per silence."""
    clock = _Clock()
    with (
        PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock,
    ):
        port = int(receiver.url.rsplit(":", 1)[1])
        expected: list[float] = []
        ignored = lapses = 0
        last_cal: float | None = None
        t_ns = 10**9
        for k, (calibrated, silence) in enumerate(plan):
            clock.t += silence
            t_ns += round(silence * 1e9)
            if last_cal is not None and clock.t - last_cal > CALIBRATED_QUIET_S:
                lapses += 1
                last_cal = None
            if calibrated:
                doc = {"type": "android.sensor.gyroscope", "timestamp": t_ns, "values": [0.0, 0.0, CAL]}
                expected.append(CAL)
                last_cal = clock.t
            else:
                doc = {
                    "type": "android.sensor.gyroscope_uncalibrated",
                    "timestamp": t_ns,
                    "values": [0.0, 0.0, RAW + 0.125, 0.0, 0.0, 0.125],
                }
                if last_cal is None:
                    expected.append(RAW)
                else:
                    ignored += 1
            sock.sendto(json.dumps(doc).encode(), ("127.0.0.1", port))
            _wait_messages(receiver, k + 1)
        assert _drain(receiver) == expected
        assert receiver.stats.ignored_entries == ignored
        assert receiver.stats.calibrated_lapses == lapses


def _push(url: str, k: int, entries: list[dict[str, object]]) -> None:
    body = json.dumps({"messageId": k, "deviceId": "d", "sessionId": "s", "payload": entries}).encode()
    request = urllib.request.Request(url, body, {"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as answer:
        assert answer.status == 200


def _entry(name: str, t_ns: int, z: float) -> dict[str, object]:
    return {"name": name, "time": t_ns, "values": {"x": 0.0, "y": 0.0, "z": z}}


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from([0.1, CALIBRATED_QUIET_S - 0.01, CALIBRATED_QUIET_S + 0.01, 60.0]))
def test_push_raw_types_and_parts_take_over_once_the_calibrated_ones_are_silent(silence):
    """Sensor Logger pushes its calibrated gyroscope and total acceleration, then (after a drawn silence)
    only the raw gyroscope and the user acceleration with gravity: read iff the silence was longer than
    ``CALIBRATED_QUIET_S``, each change counted; else ignored and counted, never beside the others."""
    clock = _Clock()
    t0 = 1_700_000_000 * 10**9
    with PhonePushServer("http://127.0.0.1:0/", clock=clock) as server:
        for k in range(3):
            t = t0 + k * 10**8
            _push(server.url, k, [_entry("gyroscope", t, CAL), _entry("totalacceleration", t, 9.875)])
        clock.t += silence
        for k in range(3, 6):
            t = t0 + k * 10**8 + round(silence * 1e9)
            entries = [
                _entry("gyroscopeuncalibrated", t, RAW),
                _entry("accelerometer", t, 0.25),
                _entry("gravity", t, 9.5),
            ]
            _push(server.url, k, entries)
        values = _drain(server)
        took_over = silence > CALIBRATED_QUIET_S
        assert values.count(CAL) == 3 and values.count(9.875) == 3
        assert values.count(RAW) == (3 if took_over else 0)
        assert values.count(9.5 + 0.25) == (3 if took_over else 0)
        assert server.stats.ignored_entries == (0 if took_over else 9)
        # the gyroscope, the accelerometer (total acceleration is one) and total acceleration itself
        assert server.stats.calibrated_lapses == (3 if took_over else 0)
