"""Readings that parse but are hostile, into a running host (issue 26, findings 1-3): SensaGram datagrams
through a real UDP socket and the real receiver, handed to a lockstep host beside its world's own phone at
drawn moments of the run — time stamps anywhere in int64 nanoseconds or a little off the phone's clock,
magnitudes up to 1e308, bursts. Whatever they are: the run ends in bounded time, every reading is either
taken or dropped and counted, the run keeps the fault campaigns' invariants, and none stalls it.

Before the admission policy, one gyro reading stamped 1e18 ns hung the host (the estimator sub-stepped the
gap without a bound), one of [1e160, -1e160, 1e160] ended the run (a NaN setpoint), 1e6 rad/s gave a run
that said "completed" 169° off, and a few triples stamped 100 s ahead restarted the slew each time.
"""

from __future__ import annotations

import json
import socket
import time

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from observer_support import SilentObserver

from hil.estimation.admission import PhoneGuard, Verdict
from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.phone_udp import PhoneUdpReceiver
from hil.montecarlo.runner import fault_bounds
from hil.runtime import RunOptions, run
from hil.runtime.invariants import check_run
from hil.runtime.observer import Observers
from hil.runtime.record import RunRecorder
from hil.scenario import load_scenario

TYPES = ("android.sensor.gyroscope", "android.sensor.accelerometer", "android.sensor.magnetic_field")
INT64 = 2**63 - 1

absurd_numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e160, -1e160, 1e308, -1e308, 1e6, 35.0, 0.0]),
    st.floats(-50.0, 50.0),
)
stamps = st.one_of(
    st.tuples(st.just("absolute"), st.integers(-INT64 - 1, INT64)),
    st.tuples(st.just("offset"), st.integers(-200 * 10**9, 200 * 10**9)),  # ns off the phone's clock
    st.tuples(st.just("offset"), st.integers(-(10**6), 10**6)),  # within a millisecond: duplicates, bursts
)
reading = st.tuples(st.sampled_from(TYPES), stamps, st.lists(absurd_numbers, min_size=3, max_size=3))
injection = st.tuples(st.floats(0.3, 9.0), st.lists(reading, min_size=1, max_size=12), st.integers(1, 40))


class Injector(SilentObserver):
    """At each injection's moment, sends its datagrams (``repeat`` times: a burst) through a real UDP socket
    to a real receiver, and hands what the receiver decoded to the host, as the estimator task would."""

    def __init__(self, receiver: PhoneUdpReceiver, plan: list) -> None:  # type: ignore[type-arg]
        self.receiver = receiver
        self.plan = sorted(plan, key=lambda p: p[0])
        self.host = None
        self.sent = 0
        self.handed = 0
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        host, port = receiver.url.removeprefix("udp://").rsplit(":", 1)
        self._to = (host, int(port))

    def started(self, start) -> None:  # type: ignore[no-untyped-def]
        self.host = start.host

    def finished(self, summary) -> None:  # type: ignore[no-untyped-def]
        self._sock.close()

    def _received(self) -> int:
        stats = self.receiver.stats
        return stats.messages + stats.bad_messages

    def tick(self, t: float) -> None:
        while self.plan and self.plan[0][0] <= t:
            _, readings, repeat = self.plan.pop(0)
            for _ in range(repeat):
                for kind, (how, stamp), values in readings:
                    ns = stamp if how == "absolute" else round(t * 1e9) + stamp
                    doc = {"type": kind, "timestamp": ns, "values": values}
                    self._sock.sendto(json.dumps(doc).encode(), self._to)
                    self.sent += 1
            end = time.monotonic() + 5.0  # the receiver's thread takes them off the socket
            while self._received() < self.sent and time.monotonic() < end:
                time.sleep(0.001)
            samples = self.receiver.drain()
            self.handed += len(samples)
            assert self.host is not None
            self.host.feed(samples, t)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(injection, min_size=1, max_size=4))
def test_hostile_readings_into_a_running_host_are_dropped_and_counted(plan):
    sc = load_scenario("cubesat-1u")
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        injector = Injector(receiver, list(plan))
        recorder = RunRecorder(sc.n_units)
        started = time.monotonic()
        result = run(
            sc,
            RunOptions(
                out_root=None, duration_s=4.0, observer=Observers(recorder, injector), rows_to_observer=True
            ),
        )
        wall = time.monotonic() - started
    s = result.summary
    assert wall < 60.0, f"a run of {s['sim_s']:.0f} s simulated took {wall:.0f} s"
    assert not s["exit"].startswith("error"), s["exit"]
    stats = receiver.stats
    assert stats.messages + stats.bad_messages >= injector.sent * 0.99  # UDP on loopback: all of them
    admission = s["phone_admission"]
    fed = s["phone_samples"]
    assert admission["accepted"] + sum(admission["dropped"].values()) == fed  # every reading accounted for
    report = check_run([], recorder, fault_bounds(sc))
    assert report.ok, report.violations


def test_the_issues_readings_each_leave_the_run_alone():
    """The reproductions of issue 26 (1-3), each a burst of the same reading: a gyro stamped 1e18 ns,
    [1e160, -1e160, 1e160], 1e6 rad/s, and 8 triples stamped 100 s ahead over 21 s — dropped and counted,
    the run completes and settles, no restart of the estimator or the slew."""
    sc = load_scenario("cubesat-1u")
    far = [(TYPES[0], ("absolute", 10**18), [0.0, 0.0, 0.1])]
    huge = [(TYPES[0], ("offset", 0), [1e160, -1e160, 1e160])]
    fast = [(TYPES[0], ("offset", 1_000), [1e6, 0.0, 0.0])]
    ahead = [(kind, ("offset", 100 * 10**9), [0.0, 0.0, 9.8]) for kind in TYPES]
    plan = [(4.0, far, 1), (6.0, huge, 1), (8.0, fast, 1)] + [(9.0 + 3 * k, ahead, 1) for k in range(8)]
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        recorder = RunRecorder(sc.n_units)
        injector = Injector(receiver, plan)
        result = run(
            sc, RunOptions(out_root=None, observer=Observers(recorder, injector), rows_to_observer=True)
        )
    s = result.summary
    assert s["exit"] == "completed" and s["settled"], (s["exit"], s["requirement"])
    dropped = s["phone_admission"]["dropped"]
    assert dropped["future"] >= 1 + 24 and dropped["out_of_range"] >= 2
    assert s["phone_restarts"] == 0
    assert not [e for e in recorder.events if e["kind"] in ("recovery_start", "phone_jump", "phone_restart")]
    assert check_run([], recorder, fault_bounds(sc)).ok


def _stream(guard: PhoneGuard, t0: float, n: int, dt: float) -> list[Verdict]:
    """``n`` gyro readings from ``t0`` every ``dt`` seconds into ``guard``; their verdicts."""
    return [guard.admit(SensorSample(t0 + k * dt, SensorKind.GYR, (0.0, 0.0, 0.1))) for k in range(n)]


@given(
    ahead=st.floats(2.0, 1e10),
    further=st.floats(2.0, 1e10),
    copies=st.integers(1, 40),
    side=st.sampled_from([-1, 1]),
)
@settings(max_examples=200, deadline=None)
def test_strays_at_far_stamps_never_pass_for_a_moved_clock(ahead, further, copies, side):
    """Copies of strays at one or two far stamps (the soak's hostile cycle sent 100 s ahead and 1e18 ns,
    five times each, and they were taken for a phone whose clock jumped): dropped and counted, the clock
    kept; then a stream that really moved (50 Hz from a far stamp) re-anchors it once."""
    guard = PhoneGuard()
    _stream(guard, 10.0, 50, 0.02)
    newest = guard.newest
    strays = [newest + side * ahead] * copies + [newest + side * (ahead + further)] * copies
    verdicts = [guard.admit(SensorSample(t, SensorKind.GYR, (0.0, 0.0, 0.1))) for t in strays]
    assert set(verdicts) == {Verdict.DROP} and guard.newest == newest
    assert sum(guard.stats.dropped.values()) == 2 * copies
    moved = _stream(guard, newest + side * ahead, 20, 0.02)
    assert moved.count(Verdict.RESTART if side < 0 else Verdict.JUMP) == 1
    assert guard.stats.restarts + guard.stats.jumps == 1


@given(
    ahead=st.floats(2.0, 1e10),
    copies=st.integers(1, 6),
    kinds=st.lists(st.sampled_from(list(SensorKind)), min_size=1, max_size=3, unique=True),
    side=st.sampled_from([-1, 1]),
)
@settings(max_examples=200, deadline=None)
def test_strays_before_the_stream_s_first_reading_are_dropped_not_a_clock_restart(ahead, copies, kinds, side):
    """Strays at one far stamp that come before any reading of the stream (a spoof in the first batch,
    one copy per sensor): the first anchored the clock unseen, and the stream that follows moved it — once,
    answered as a stray (the strays counted dropped, where they lay), not as the phone's clock restarting
    or jumping. Then the stream is accepted on and a real restart is still told as one."""
    guard = PhoneGuard()
    t0 = 10.0
    strays = [SensorSample(t0 + side * ahead, kind, (0.0, 0.0, 0.1)) for kind in kinds] * copies
    first = [guard.admit(s) for s in strays]
    assert first[0] is Verdict.ACCEPT
    verdicts = _stream(guard, t0, 60, 0.005)
    assert verdicts.count(Verdict.STRAY) == 1 and Verdict.RESTART not in verdicts
    assert Verdict.JUMP not in verdicts and verdicts[-1] is Verdict.ACCEPT
    placed = "future" if side > 0 else "past"
    assert guard.stats.dropped[placed] >= len(kinds)  # the strays (and the stream's first, until it moved)
    assert guard.stats.restarts == guard.stats.jumps == 0
    assert guard.stats.accepted + guard.stats.dropped_total == len(strays) + 60
    restarted = _stream(guard, t0 - 5.0, 20, 0.02)  # the app restarted: its clock back 5 s
    assert restarted.count(Verdict.RESTART) == 1 and guard.stats.restarts == 1


def test_a_stray_first_reading_into_a_running_host_is_dropped_and_restarts_nothing():
    """A spoof 100 s ahead as the phone's very first readings (one per sensor, at t = 0): dropped as
    ``future``, no ``phone_restart`` told, none counted (it used to anchor the clock, the genuine stream
    was dropped as ``past`` and then re-anchored as a phone restart)."""
    from hil.montecarlo.fault_plan import fault_options
    from hil.runtime.invariants import InjectedFault

    sc = load_scenario("cubesat-1u")
    sc = sc.with_changes(slew=sc.slew.__class__(**{**sc.slew.__dict__, "duration_s": 8.0}))
    faults = [InjectedFault("phone_spoof", 0.0, {"spoof": "future"})]
    sc = sc.with_changes(fault_options=fault_options(tuple(faults), sc.fault_options))
    recorder = RunRecorder(sc.n_units)
    run(sc, RunOptions(out_root=None, observer=recorder, rows_to_observer=True))
    s = recorder.summary
    assert check_run(faults, recorder, fault_bounds(sc)).ok
    assert s["exit"] == "completed" and s["phone_restarts"] == 0
    assert not [f for f in s["faults"] if f["kind"] in ("phone_restart", "phone_jump")]
    assert any(f["kind"] == "readings_dropped" and f["reason"] == "future" for f in s["faults"])
