"""The host's link layer (hil.link.board.BoardClient over hil.link.transports), each figure next to a peer
in the
same run:

* host setpoint → pulse change reported, p50/p99, through the full client (reader thread, pyserial, a
  real pty) against ``spawn://firmware-sim`` (490 Hz pulse frames, 1 kHz telemetry), next to a raw pty
  echo of the same bytes (the floor any pty link pays). The board-side share comes from the board's own
  telemetry: ``link_age_ms`` of the first Telemetry showing the new width is the time from the board
  handling the setpoint to that report;
* lockstep in-process link: setpoint round trips (send → Telemetry showing it) per wall second through
  the client and the emu:// transport, next to the bare sans-IO board driven with a framer and a
  deframer (the client's overhead is the difference);
* lockstep real-time factor of a 4-unit, 100 Hz setpoint stream through the client, next to the bare
  board driven at the same rate.
"""

from __future__ import annotations

import functools
import statistics
import sys
import time
from typing import Any

import serial

from bench.bench_firmware_sim import _PEER, _pct
from bench.child import started
from bench.common import Result
from firmware_sim.servers.transports import EmulatorTransport
from hil.link.board import BoardClient, ClientConfig, Event, TelemetryEvent
from hil.timing.clock import LockstepClock
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import SCHEMA_HASH, ActuatorSetpoint, Arm, Hello, Telemetry, UnitSetpoint

NAME = "link"
N_UNITS = 4
ROTOR = 1
SPEEDS = (200.0, 400.0)
_EMU = "emu://?units=4&frame_rate=490&telemetry_rate=1000"


def _setpoint(speed: float) -> ActuatorSetpoint:
    return ActuatorSetpoint(units=tuple(UnitSetpoint(0.1, speed) for _ in range(N_UNITS)))


# =========================================================================== real time, pty
def _pty_latency(samples: int) -> tuple[list[float], list[float], list[float]]:
    """(host setpoint → telemetry showing it, ms), (board share from link_age_ms, ms), (raw echo, ms)."""
    reports: list[TelemetryEvent] = []

    def keep(event: Event) -> None:  # called in the reader thread, as the telemetry is decoded
        if isinstance(event, TelemetryEvent):
            reports.append(event)

    url = "spawn://firmware-sim?units=4&frame_rate=490&telemetry_rate=1000&link_timeout=2"
    with BoardClient(url, config=ClientConfig(max_setpoint_rate_hz=1000.0), on_event=keep) as c:
        c.start()
        c.arm()
        latency, board_share = [], []
        c.send_setpoint(_setpoint(SPEEDS[0]))
        c.wait_for(lambda: c.telemetry is not None and c.telemetry.pulses_us[ROTOR] > 1000, 2.0)
        for k in range(samples):
            time.sleep(0.003)  # let the previous change settle; stay well inside the 50 ms heartbeat gap
            previous = c.telemetry.pulses_us[ROTOR]  # type: ignore[union-attr]
            reports.clear()
            sent = c.clock.now()
            c.send_setpoint(_setpoint(SPEEDS[(k + 1) % 2]))
            if not c.wait_for(functools.partial(_changed, reports, previous), 1.0):
                raise RuntimeError("the pulse never changed")
            first = _changed(reports, previous)
            assert first is not None
            latency.append((first.t - sent) * 1e3)
            board_share.append(float(first.telemetry.link_age_ms))
        c.disarm()
    return latency, board_share, _echo(samples)


MOVED_US = 10  # a change of setpoint moves the rotor pulse by ~100 µs; the battery's sag by 1-2 µs


def _changed(reports: list[TelemetryEvent], previous: int) -> TelemetryEvent | None:
    """The first report whose rotor pulse moved away from ``previous`` by more than the battery's own
    drift (None: no change reported yet)."""
    return next((e for e in reports if abs(e.telemetry.pulses_us[ROTOR] - previous) > MOVED_US), None)


def _echo(samples: int) -> list[float]:
    data = Framer().encode(_setpoint(300.0))[1]
    out = []
    with started([sys.executable, "-c", _PEER, "echo"], ready="/dev/") as peer:
        path = peer.first_line
        port = serial.Serial(path, timeout=1.0)
        for _ in range(samples):
            t0 = time.perf_counter()
            port.write(data)
            got = b""
            while len(got) < len(data):
                got += port.read(len(data) - len(got))
            out.append((time.perf_counter() - t0) * 1e3)
        port.close()
    return out


# =========================================================================== lockstep, in-process
def _client_round_trips(seconds: float) -> float:
    clock = LockstepClock()
    client = BoardClient(EmulatorTransport(_EMU, clock), config=ClientConfig(max_setpoint_rate_hz=1e6))
    client.connect()
    client.arm()
    trips, width = 0, 1000
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        client.send_setpoint(_setpoint(SPEEDS[trips % 2]))
        new: list[int] = []
        while not new:
            clock.advance(0.0005)
            new = [
                e.telemetry.pulses_us[ROTOR]
                for e in client.service()
                if isinstance(e, TelemetryEvent) and e.telemetry.pulses_us[ROTOR] != width
            ]
        width = new[0]
        trips += 1
    return trips / (time.perf_counter() - start)


def _bare_board() -> tuple[Any, LockstepClock, Framer, Deframer]:
    from firmware_sim.board import Board
    from firmware_sim.board.config import BoardConfig

    clock = LockstepClock()
    board = Board(BoardConfig(n_units=N_UNITS, frame_rate_hz=490.0, telemetry_rate_hz=1000.0), clock)
    framer, deframer = Framer(), Deframer()
    clock.advance(0.1)
    board.feed(framer.encode(Hello(schema_hash=SCHEMA_HASH))[1])
    clock.advance(0.01)
    board.feed(framer.encode(Arm())[1])
    clock.advance(0.01)
    board.step()
    deframer.feed(board.take_output())
    return board, clock, framer, deframer


def _bare_round_trips(seconds: float) -> float:
    board, clock, framer, deframer = _bare_board()
    trips, width = 0, 1000
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        board.feed(framer.encode(_setpoint(SPEEDS[trips % 2]))[1])
        while True:
            clock.advance(0.0005)
            board.step()
            new = [
                e.message.pulses_us[ROTOR]
                for e in deframer.feed(board.take_output())
                if isinstance(e, Frame)
                and isinstance(e.message, Telemetry)
                and e.message.pulses_us[ROTOR] != width
            ]
            if new:
                width = new[0]
                break
        trips += 1
    return trips / (time.perf_counter() - start)


def _client_realtime_factor(seconds: float) -> float:
    clock = LockstepClock()
    client = BoardClient(EmulatorTransport(_EMU, clock))
    client.connect()
    client.arm()
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        clock.advance(0.01)
        client.send_setpoint(_setpoint(300.0 + steps % 100))
        client.service()
        steps += 1
    return steps * 0.01 / (time.perf_counter() - start)


def _bare_realtime_factor(seconds: float) -> float:
    board, clock, framer, deframer = _bare_board()
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        clock.advance(0.01)
        board.feed(framer.encode(_setpoint(300.0 + steps % 100))[1])
        board.step()
        deframer.feed(board.take_output())
        steps += 1
    return steps * 0.01 / (time.perf_counter() - start)


def run(quick: bool) -> list[Result]:
    samples = 30 if quick else 300
    seconds = 0.3 if quick else 2.0
    latency, board_share, echo = _pty_latency(samples)
    trips, bare_trips = _client_round_trips(seconds), _bare_round_trips(seconds)
    factor, bare_factor = _client_realtime_factor(seconds), _bare_realtime_factor(seconds)
    share = statistics.median(board_share)
    note = f"board share (telemetry link_age) p50 {share:.1f} ms; 490 Hz frames, 1 kHz telemetry"
    return [
        Result(
            NAME,
            "setpoint -> pulse reported p50 (client, pty)",
            statistics.median(latency),
            "ms",
            "raw pty echo p50",
            statistics.median(echo),
            False,
            note,
        ),
        Result(
            NAME,
            "setpoint -> pulse reported p99 (client, pty)",
            _pct(latency, 99),
            "ms",
            "raw pty echo p99",
            _pct(echo, 99),
            False,
        ),
        Result(
            NAME,
            "lockstep setpoint round trips (client, emu://)",
            trips,
            "trips/s",
            "bare sans-IO board",
            bare_trips,
            True,
            "0.5 ms lockstep steps, 490 Hz frames, 1 kHz telemetry",
        ),
        Result(
            NAME,
            "lockstep 4-unit 100 Hz link (client, emu://)",
            factor,
            "x real time",
            "bare sans-IO board",
            bare_factor,
            True,
            "setpoint + service() per 10 ms step, 1 kHz telemetry",
        ),
    ]
