"""A run's phone is picked by URL through one registry (``hil.link.sources``), like the board's transports:
every scheme — SensaGram's ``udp://``, Sensor Logger's ``http://``, the replayed ``recording://``, the
emulator's ``sim://``, in hil's table; another package's by a ``vscmg_hil.phone_sources`` entry point —
builds a source of one shape
(``drain(now)``, ``truth(now)``, ``close()``); a user's source plugs in by entry point or ``register``, and
an unknown scheme is a ConfigError naming the known ones."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time
from typing import Any

import numpy as np
import pytest

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources import (
    ENTRY_POINT_GROUP,
    GroundTruth,
    ListeningSource,
    PhoneSource,
    SourceContext,
    create_source,
    open_sender,
    register,
    schemes,
)
from hil.link.sources.recorded import RecordedSource
from hil.link.sources.simulated import StreamedWorldPhone, WorldPhone
from hil.link.transports import InProcessBoard, create_transport
from hil.scenario import load_scenario
from hil.timing.clock import Clock, LockstepClock, WallClock
from protocol.errors import ConfigError, LinkError

BUILT_IN = {
    "udp": "hil.link.sources.listening:listen",
    "http": "hil.link.sources.listening:listen",
    "recording": "hil.link.sources.recorded:play",
    "sim": "hil.link.sources.simulated:simulated_phone",
}


class _Events:
    """The run's event writer, kept in a list: ``(t, kind, fields)``."""

    def __init__(self) -> None:
        self.records: list[tuple[float, str, dict[str, Any]]] = []

    def __call__(self, t: float, kind: str, **fields: Any) -> None:
        self.records.append((t, kind, fields))

    def kinds(self) -> list[str]:
        return [kind for _, kind, _ in self.records]


def _context(clock: Clock, recording=None, board=None) -> tuple[SourceContext, _Events]:
    scenario = load_scenario("cubesat-1u")
    if board is None:
        board = create_transport(scenario.emulator_url())
        board.bind_clock(clock)
    events = _Events()
    lockstep = isinstance(clock, LockstepClock)
    return SourceContext(scenario, clock, lockstep, board, events, recording), events


def test_the_built_in_schemes_are_in_the_registry():
    assert set(BUILT_IN) <= set(schemes())


def test_an_unknown_scheme_is_a_config_error_naming_the_known_ones():
    context, _ = _context(LockstepClock())
    with pytest.raises(ConfigError) as raised:
        create_source("tcp://127.0.0.1:1", context)
    assert raised.value.where == "--phone"
    assert "unknown phone source scheme 'tcp'" in str(raised.value)
    assert all(name in str(raised.value) for name in BUILT_IN)
    with pytest.raises(ConfigError, match="a recording is played by `hil replay"):
        create_source("recording://", context)  # nothing to play outside a replay
    serial = create_transport("loop://")
    with pytest.raises(ConfigError, match="the built-in emulator's"):
        create_source("sim://", _context(LockstepClock(), board=serial)[0])  # a real board has no world


class _Constant(PhoneSource):
    """A user's source: one gyroscope reading of 0.1 rad/s about z every 10 ms of the run's clock, and the
    truth it implies (a rotation about z from the start)."""

    def __init__(self, url: str, context: SourceContext) -> None:
        self.url = url
        self.next_t = 0.0
        self.closed = False

    def drain(self, now: float) -> list[SensorSample]:
        out = []
        while self.next_t <= now:
            out.append(SensorSample(self.next_t, SensorKind.GYR, np.array([0.0, 0.0, 0.1])))
            self.next_t += 0.01
        return out

    def truth(self, now: float) -> GroundTruth:
        angle = 0.1 * now
        c, s = np.cos(angle), np.sin(angle)
        return GroundTruth(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array([0.0, 0.0, 0.1]))

    def close(self) -> None:
        self.closed = True


def test_a_source_registered_at_run_time_is_built_through_the_registry():
    module = type(sys)("constant_phone_for_test")
    module.Constant = _Constant  # type: ignore[attr-defined]
    sys.modules[module.__name__] = module
    try:
        register("constant", "constant_phone_for_test:Constant")
        assert "constant" in schemes()
        context, _ = _context(LockstepClock())
        with create_source("constant://rig", context) as source:
            # a user's source, held to its interface (hil.link.sources.checked): the wrapper's
            assert isinstance(source.inner, _Constant) and source.url == "constant://rig"
            assert len(source.drain(0.095)) == 10 and source.drain(0.095) == []
            assert source.truth(1.0).omega[2] == pytest.approx(0.1)
            # what it does not override is a stream's: ready at once, no task, no end, nothing counted
            source.wait_ready(1.0, lambda: None)
            assert source.tasks() == [] and source.start(0.0) is None and not source.exhausted
            assert source.rate_hz is None and source.report() == {}
        assert source.inner.closed
    finally:
        del sys.modules[module.__name__]


def test_a_third_party_package_registers_a_source_by_entry_point(tmp_path):
    """A package installed beside the project (a dist-info and a module on sys.path, exactly what pip
    leaves) adds ``still://`` without any change to hil."""
    (tmp_path / "thirdparty_phone.py").write_text(textwrap.dedent('''
        import numpy as np
        from hil.estimation.sensors import SensorKind, SensorSample
        from hil.link.sources import PhoneSource

        class Still(PhoneSource):
            def __init__(self, url, context):
                self.url = url
            def drain(self, now):
                return [SensorSample(now, SensorKind.ACC, np.array([0.0, 0.0, 9.81]))]
            def truth(self, now):
                return None
            def close(self):
                self.url = ""  # nothing else to release: the readings are made up on demand
    '''))  # fmt: skip
    info = tmp_path / "thirdparty_phone-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdparty-phone\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nstill = thirdparty_phone:Still\n")
    script = textwrap.dedent(f'''
        import sys
        sys.path.insert(0, {str(tmp_path)!r})
        from hil.link.sources import create_source, schemes
        assert "still" in schemes(), schemes()
        source = create_source("still://desk", None)
        print(type(source.inner).__module__, source.drain(1.5)[0].xyz[2])
    ''')  # fmt: skip
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["thirdparty_phone", "9.81"]


@pytest.mark.parametrize("address", ["127.0.0.1:0", "udp://127.0.0.1:0", "http://127.0.0.1:0/push"])
def test_a_live_phone_is_listened_for_and_counted(address):
    context, events = _context(WallClock())
    sample = SensorSample(1.0, SensorKind.GYR, np.array([0.01, 0.02, 0.03]))
    gravity = SensorSample(1.0, SensorKind.ACC, np.array([0.0, 0.0, 9.81]))  # a run starts on both
    with create_source(address, context) as source:
        scheme = address.split("://")[0] if "://" in address else "udp"  # a bare HOST:PORT is SensaGram's
        assert isinstance(source, ListeningSource) and source.url.startswith(f"{scheme}://127.0.0.1:")
        assert events.kinds() == ["phone_listening"] and events.records[0][2] == {"url": source.url}
        sender = open_sender(source.url)
        try:
            sender.send([sample, gravity])
            source.wait_ready(5.0, lambda: None)
        finally:
            sender.close()
        got = {s.kind: s for s in source.drain(0.0)}
        assert np.allclose(got[SensorKind.GYR].xyz, sample.xyz) and np.allclose(
            got[SensorKind.ACC].xyz, gravity.xyz
        )
        assert source.truth(0.0) is None and source.tasks() == [] and source.start(0.0) is None
        report = source.report()["phone"]
        assert report["url"] == source.url and report["samples"] == 2


def test_a_live_phone_that_sends_nothing_is_a_clear_error():
    context, _ = _context(WallClock())
    fed = []
    with create_source("udp://127.0.0.1:0", context) as source, pytest.raises(Exception) as raised:
        source.wait_ready(0.2, lambda: fed.append(1))
    assert f"no phone stream on {source.url}" in str(raised.value) and "SensaGram" in str(raised.value)
    assert "nothing was heard" in str(raised.value)
    assert fed  # the board's link was kept fed meanwhile


UNCALIBRATED = "android.sensor.gyroscope_uncalibrated"
GYROSCOPE, MAGNETOMETER = "android.sensor.gyroscope", "android.sensor.magnetic_field"


@pytest.mark.parametrize(
    ("datagrams", "said"),
    [
        # the app on, only sensors the host does not use: heard, none of it usable
        ([("android.sensor.light", [1, 2, 3]), ("android.sensor.rotation_vector", [0, 0, 0, 1])] * 10,
         ["20 messages heard", "no gyroscope and no accelerometer", "20 readings of sensors the host"]),
        # its gyroscope uncalibrated only: read (less its bias estimate), but no accelerometer
        ([(UNCALIBRATED, [1, 2, 3, 0, 0, 0])] * 20, ["by sensor: gyr 20", "no accelerometer among them"]),
        # a gyroscope and a magnetometer, no accelerometer: the estimator could never start
        ([(GYROSCOPE, [0.1, 0.2, 0.3]), (MAGNETOMETER, [20, 0, -40])] * 10,
         ["by sensor: gyr 10, mag 10", "no accelerometer among them"]),
    ],
)  # fmt: skip
def test_a_live_phone_heard_without_what_a_run_needs_is_told_what_was_heard(datagrams, said):
    """A phone that streams, but not the sensors a run starts on, is not "a phone that sends nothing":
    the error says what came (it used to say to point the app at the host, which it was), and a stream
    without an accelerometer no longer starts a run that could never estimate."""
    import json
    import socket

    context, _ = _context(WallClock())
    with create_source("udp://127.0.0.1:0", context) as source, pytest.raises(LinkError) as raised:
        host, port = source.url.removeprefix("udp://").rsplit(":", 1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for k, (kind, values) in enumerate(datagrams):
                doc = {"type": kind, "timestamp": 3_925_657_519_043_709 + k * 10**7, "values": values}
                s.sendto(json.dumps(doc).encode(), (host, int(port)))
        source.wait_ready(0.5, lambda: None)
    for part in said:
        assert part in str(raised.value)


def test_a_recording_plays_on_the_runs_clock_with_its_truth():
    from firmware_sim.world.models.phone import Trajectory, paper_testbed_rate, simulate
    from hil.scenario.phone import PhoneSpec

    log = simulate(Trajectory.from_rate(paper_testbed_rate, 2.0, dt=2e-3), PhoneSpec.nexus5(), seed=1)
    context, events = _context(LockstepClock(), recording=log)
    with create_source("recording://", context) as source:
        assert isinstance(source, RecordedSource)
        assert source.drain(1e9) == []  # nothing is due before the run starts
        origin = 100.0
        until = source.start(origin)
        control_tick = 1.0 / context.scenario.loop.control_rate_hz
        # the estimator task drains the last sample within one of its periods: the run ends that and two
        # control ticks after it (a 20 Hz log ended before its last sample was drained)
        assert until == pytest.approx(origin + log.end - log.start + 1.0 / source.rate_hz + 2 * control_tick)
        assert events.records == [(origin, "replay_start", {"log": log.source, "until": until})]
        assert source.rate_hz == pytest.approx(198.6, rel=0.01)  # the Nexus 5's gyroscope and accelerometer
        first = source.drain(origin + 0.5)
        assert first and max(s.t_s for s in first) <= origin + 0.5  # on the run's clock
        truth = source.truth(origin + 0.5)
        assert truth is not None and truth.R.shape == (3, 3) and truth.omega.shape == (3,)
        assert not source.exhausted
        released = len(first) + len(source.drain(until))
        assert source.exhausted and source.report() == {"replay": {"samples_released": released}}
        assert released == log.n_samples


def test_the_simulated_phone_in_lockstep_is_stepped_with_the_world():
    clock = LockstepClock()
    context, events = _context(clock)
    with create_source("sim://", context) as source:
        assert isinstance(source, WorldPhone) and isinstance(context.board, InProcessBoard)
        (task,) = source.tasks()
        assert task.name == "world" and task.period_s > 0
        clock.sleep_until(0.1)
        source.advance(clock.now())  # the world task's and the control tick's step
        samples = source.drain(clock.now())
        kinds = {s.kind for s in samples}
        assert kinds == {SensorKind.GYR, SensorKind.ACC, SensorKind.MAG}
        assert all(s.t_s <= 0.1 for s in samples) and len(samples) > 30  # ~0.1 s of a 450 Hz phone
        truth = source.truth(clock.now())
        assert truth.R.shape == (3, 3) and np.allclose(truth.R @ truth.R.T, np.eye(3))
        assert source.report() == {} and events.records == []  # nothing streamed, nothing to count


def test_the_simulated_phone_in_real_time_streams_over_loopback():
    context, events = _context(WallClock())
    with create_source("sim://", context) as source:
        assert isinstance(source, StreamedWorldPhone)
        assert events.kinds() == ["phone_listening"] and source.receiver.url.startswith("udp://127.0.0.1:")
        samples: list[SensorSample] = []
        end = time.monotonic() + 5.0
        while len(samples) < 20 and time.monotonic() < end:
            samples += source.drain(context.clock.now())
            time.sleep(0.02)
        assert len(samples) >= 20 and source.truth(context.clock.now()) is not None
        assert source.report()["phone"]["samples"] >= 20
    assert events.kinds() == ["phone_listening", "world_end"]  # the close stopped the world
