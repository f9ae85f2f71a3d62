"""A phone heard, but with nothing usable, is told like a phone not heard (issue: a phone whose every
reading was 1e160 sat 47 s in the warm-up, "waiting for the phone", never stale, never lost; one whose gyro
readings were all refused armed and steered on its accelerometer and magnetometer; a frozen clock was
reported as a silent phone).

- Before the run: :meth:`ListeningSource.wait_ready` judges what arrives through the admission policy and
  says, past ``--phone-wait``, that readings arrived and all were refused, with the reasons (real UDP
  socket, real receiver).
- During the run (lockstep, the world's phone tampered with from a drawn moment on, as a hostile or
  broken phone would be): every gyroscope or accelerometer reading refused, a clock that stopped
  (every reading a duplicate) or stepped back is a phone gap that says why, within ``stale_after_s``
  and a few ticks; a gap that goes on loses the run, and the lost message names it.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from observer_support import SilentObserver

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.listening import ListeningSource
from hil.link.sources.phone_udp import PhoneUdpReceiver
from hil.runtime import RunOptions, run
from hil.runtime.faults import STALE_AFTER_S
from hil.scenario import load_scenario
from protocol.errors import LinkTimeout

TYPES = {"gyr": "android.sensor.gyroscope", "acc": "android.sensor.accelerometer"}
GOOD = {"gyr": [0.001, -0.002, 0.0005], "acc": [0.0, 0.0, 9.81]}
BAD = {
    "out_of_range": lambda k: ([1e160, 1e160, 1e160], 10**7 * k),
    "duplicate": lambda k: (None, 0),  # every reading stamped as the first: a stopped clock
}


def _send(port: int, plan: dict[str, str | None], n: int = 30) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for k in range(n):
            for label, type_ in TYPES.items():
                bad = plan[label]
                values, offset = (GOOD[label], 10**7 * k) if bad is None else BAD[bad](k)
                doc = {"type": type_, "timestamp": 5 * 10**9 + offset, "values": values or GOOD[label]}
                s.sendto(json.dumps(doc).encode(), ("127.0.0.1", port))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.fixed_dictionaries({k: st.sampled_from([None, "out_of_range", "duplicate"]) for k in TYPES}))
def test_a_phone_whose_readings_are_refused_is_not_ready_and_is_told_why(plan):
    """Each needed sensor good, absurd or frozen: ready iff both have a usable reading; else the error
    names each sensor whose readings all came and all were refused, and the reason. Whatever was waited
    on is handed to the run afterwards, none lost."""
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        source = ListeningSource(receiver)
        _send(int(source.url.rsplit(":", 1)[1]), plan)
        end = time.monotonic() + 5.0  # the receiver's thread takes them off the socket
        while receiver.stats.messages < 60 and time.monotonic() < end:
            time.sleep(0.001)
        usable = all(plan[k] != "out_of_range" for k in TYPES)  # a frozen clock's first reading is fine
        if usable:
            source.wait_ready(5.0, lambda: None)
        else:
            with pytest.raises(LinkTimeout) as raised:
                source.wait_ready(0.5, lambda: None)
            said = str(raised.value)
            for label, name in (("gyr", "gyroscope"), ("acc", "accelerometer")):
                refused = f"30 {name} readings arrived but every one was refused (out_of_range 30)"
                assert (refused in said) == (plan[label] == "out_of_range"), said
        handed = []
        while batch := source.drain(0.0):
            handed += batch
        assert len(handed) == receiver.stats.samples == 60


class Tamper(SilentObserver):
    """From ``at`` (s, host time) on, the world phone's readings as ``change`` makes them, on their way
    into the host (the estimator task's ``Host.feed``)."""

    def __init__(self, at: float, change: Callable[[SensorSample, float], SensorSample]) -> None:
        self.at = at
        self.change = change
        self.events: list[dict] = []  # type: ignore[type-arg]

    def started(self, start) -> None:  # type: ignore[no-untyped-def]
        host = start.host
        feed = host.feed

        def tampered(samples, now=None):  # type: ignore[no-untyped-def]
            if now is not None and now >= self.at:
                samples = [self.change(s, now) for s in samples]
            feed(samples, now)

        host.feed = tampered

    def event(self, record) -> None:  # type: ignore[no-untyped-def]
        self.events.append(record)


def _absurd(kind: SensorKind) -> Callable[[SensorSample, float], SensorSample]:
    def change(s: SensorSample, now: float) -> SensorSample:
        return SensorSample(s.t_s, s.kind, (1e160, 1e160, 1e160)) if s.kind is kind else s

    return change


def _frozen(at: float) -> Callable[[SensorSample, float], SensorSample]:
    return lambda s, now: SensorSample(at, s.kind, s.xyz)


def _back(by: float) -> Callable[[SensorSample, float], SensorSample]:
    return lambda s, now: SensorSample(s.t_s - by, s.kind, s.xyz)


FAULTS = {
    "gyro refused": (lambda at: _absurd(SensorKind.GYR), "gyroscope readings came, every one refused"),
    "accelerometer refused": (lambda at: _absurd(SensorKind.ACC), "accelerometer readings came"),
    "clock stopped": (_frozen, "the phone streams but its clock stopped"),
    "clock back 0.6 s": (lambda at: _back(0.6), "the phone's clock went back"),
}
CAUSES = {
    "gyro refused": "phone_readings_refused",
    "accelerometer refused": "phone_readings_refused",
    "clock stopped": "phone_clock_stopped",
    "clock back 0.6 s": "phone_clock_back",
}


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(sorted(FAULTS)), st.floats(1.0, 4.0))
def test_a_phone_streaming_nothing_usable_is_a_phone_gap_that_says_why(fault, at):
    make, said = FAULTS[fault]
    tamper = Tamper(at, make(at))
    result = run(
        load_scenario("cubesat-1u"),
        RunOptions(out_root=None, duration_s=6.0, recover_within_s=1.5, observer=tamper),
    )
    s = result.summary
    gaps = [e for e in tamper.events if e["kind"] == "phone_gap"]
    assert gaps, s["exit"]
    first = gaps[0]
    assert at <= first["t"] <= at + STALE_AFTER_S + 0.1, (first, at)
    assert said in first["why"], first["why"]
    if fault == "clock back 0.6 s":  # the clock catches up 0.6 s later: the phone is back
        assert any(e["kind"] == "phone_back" for e in tamper.events)
        assert s["phone_admission"]["dropped"]["out_of_order"] > 0
    else:  # never back: lost, and the message says why
        assert s["lost"] and CAUSES[fault] in s["lost"], s["lost"]
    if fault == "clock stopped":
        dropped = [e for e in tamper.events if e["kind"] == "readings_dropped"]
        assert any(e["reason"] == "clock_stopped" for e in dropped)
        assert len(dropped) <= 12 * (s["sim_s"] - at) + 2  # a bounded rate, not one per reading
