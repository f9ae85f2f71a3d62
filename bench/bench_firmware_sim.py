"""firmware_sim through a real pty: frames/s the emulator sustains, and host setpoint → pulse-change-reported
latency, each next to a raw pty peer measured in the same run (a byte sink and an echo process, in the same
Python, on the same kind of pty). Plus the sans-IO board's lockstep speed (board seconds per wall second).

The emulator and the peers run as separate processes (``python -m firmware_sim``), so the host side and
the board do not share a GIL; the host is pyserial, as in ``hil``.
"""

from __future__ import annotations

import statistics
import sys
import time
from typing import Any

import serial

from bench.child import firmware_sim, started
from bench.common import Result
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    Hello,
    HelloReply,
    Telemetry,
    UnitSetpoint,
)

NAME = "firmware_sim"
N_UNITS = 4

# A raw pty peer: "sink" counts frames (0x00 delimiters) and reports the count; "echo" sends bytes back.
_PEER = r"""
import os, select, sys, tty
mode = sys.argv[1]
master, slave = os.openpty()
tty.setraw(slave)
print(os.ttyname(slave), flush=True)
count = 0
while True:
    r, _, _ = select.select([master, sys.stdin], [], [])
    if sys.stdin in r:
        sys.stdin.readline()
        print(count, flush=True)
        continue
    data = os.read(master, 65536)
    if mode == "echo":
        os.write(master, data)
    else:
        count += data.count(0)
"""


def _emulator(frame_rate: int, telemetry_rate: int, can: str | None = None) -> Any:
    """``firmware-sim`` with ``N_UNITS`` units in its own process, on a pty, or on the CAN bus ``can``
    (``can://…``) when given; yields (the process, what the host opens)."""
    argv = firmware_sim(
        "--units",
        str(N_UNITS),
        "--frame-rate",
        str(frame_rate),
        "--telemetry-rate",
        str(telemetry_rate),
        "--link-timeout",
        "2",
    )
    if can is not None:
        return started([*argv, "--can", can], ready="can://")
    return started(argv, ready="/dev/")


def _setpoint(speed: float, gimbal_rate: float = 0.1) -> ActuatorSetpoint:
    return ActuatorSetpoint(units=tuple(UnitSetpoint(gimbal_rate, speed) for _ in range(N_UNITS)))


class _Host:
    """The bench's bare host: framer, deframer and a transport opened from ``url`` (a pty path, a
    ``can://`` URL: :func:`hil.link.transports.open_transport`), no client, so what is measured is the
    link and the board."""

    def __init__(self, url: str) -> None:
        from hil.link.transports import open_transport

        self.link = open_transport(url)
        self.framer = Framer()
        self.deframer = Deframer()

    def send(self, msg: Any) -> None:
        self.link.write(self.framer.encode(msg)[1])

    def messages(self, timeout: float) -> list[Any]:
        data = self.link.read(timeout)
        return [e.message for e in self.deframer.feed(data) if isinstance(e, Frame)]

    def wait(self, cls: type, timeout: float = 2.0) -> Any:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for m in self.messages(0.01):
                if isinstance(m, cls):
                    return m
        raise RuntimeError(f"no {cls.__name__} from the emulator")

    def session(self) -> None:
        for _ in range(20):
            self.send(Hello(schema_hash=SCHEMA_HASH))
            try:
                self.wait(HelloReply, 0.2)
                break
            except RuntimeError:
                continue
        self.send(Arm())
        self.wait(Ack)

    def close(self) -> None:
        self.link.close()


RATES = (2_000, 5_000, 10_000, 20_000, 40_000)  # setpoint frames/s offered to the emulator
LOSS_OK = 0.001  # a rate is sustained while at most this fraction of the frames is lost


def _decoded(host: _Host) -> int:
    """The board's count of valid frames received, from its next Telemetry."""
    return int(host.wait(Telemetry, 1.0).rx_frames)


def _offer(host: _Host, frames: list[bytes], rate: float, seconds: float) -> tuple[int, int]:
    """Write ``frames`` round after round at ``rate`` frames/s on absolute 1 ms deadlines for
    ``seconds``, reading what the board sends meanwhile; returns (frames sent, frames the board
    decoded)."""
    before = _decoded(host)
    sent = 0
    t0 = time.perf_counter()
    while (now := time.perf_counter() - t0) < seconds:
        due = int(now * rate) + 1 - sent  # frames due by now
        if due > 0:
            host.link.write(b"".join(frames[(sent + k) % len(frames)] for k in range(due)))
            sent += due
        host.messages(0.0)
        time.sleep(max(0.0, 0.001 - (time.perf_counter() - t0 - now)))
    time.sleep(0.05)  # let the board drain its ring
    host.messages(0.0)
    return sent, _decoded(host) - before


def sustained_rate(
    seconds: float, can: str | None = None, rates: tuple[int, ...] = RATES
) -> tuple[float, str]:
    """The highest setpoint rate (frames/s) the emulator decodes without losing frames (≤ 0.1 %), on a
    pty or on the CAN bus ``can``, stepping the offered ``rates`` up; and a note of each step's loss."""
    with _emulator(50, 50, can) as board:
        where = board.first_line
        host = _Host(where)
        host.session()
        # One frame per sequence number, as a host's stream has them: byte-identical repeats would be
        # taken for CAN double receptions by the bus's reassembly (protocol.can) and not delivered.
        frames = [host.framer.encode(_setpoint(300.0))[1] for _ in range(256)]
        sustained = 0.0
        steps = []
        for rate in rates:
            sent, decoded = _offer(host, frames, rate, seconds)
            loss = 1.0 - decoded / sent
            steps.append(f"{rate / 1000:g}k: {max(loss, 0.0):.1%} lost")
            if loss > LOSS_OK:
                break
            sustained = decoded / seconds
        host.close()
    return sustained, f"{len(frames[0])}-byte 4-unit setpoints offered at rising rates ({', '.join(steps)})"


def _frames_per_second(seconds: float) -> tuple[float, float, str]:
    """:func:`sustained_rate` through a pty; and a raw pty sink taking the same bytes as fast as they
    come."""
    sustained, note = sustained_rate(seconds)
    frame = Framer().encode(_setpoint(300.0))[1]
    batch = frame * 64
    with started([sys.executable, "-c", _PEER, "sink"], ready="/dev/") as sink:
        proc = sink.proc
        port = serial.Serial(sink.first_line, timeout=0.01)
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            port.write(batch)
        port.flush()
        time.sleep(0.05)
        elapsed = time.perf_counter() - t0
        assert proc.stdin is not None and proc.stdout is not None
        proc.stdin.write("\n")
        proc.stdin.flush()
        peer_rate = int(proc.stdout.readline()) / elapsed
        port.close()
    return sustained, peer_rate, note


def pulse_latency(samples: int, can: str | None = None) -> tuple[list[float], int]:
    """Host setpoint → Telemetry showing the new gimbal pulse (ms), on a pty or on the CAN bus ``can``,
    and the samples given up (no report within 0.5 s). The gimbal channel is used because its RATE-mode
    pulse depends on the setpoint alone (a rotor pulse also follows the battery voltage)."""
    out: list[float] = []
    lost = 0
    rates = (0.1, 0.3)
    with _emulator(490, 1000, can) as board:
        where = board.first_line
        host = _Host(where)
        host.session()
        expect: dict[float, int] = {}
        for rate in rates:  # the pulse each setpoint gives, once settled
            host.send(_setpoint(200.0, rate))
            time.sleep(0.05)
            host.messages(0.0)
            expect[rate] = host.wait(Telemetry).pulses_us[0]
        assert expect[rates[0]] != expect[rates[1]]
        for k in range(samples):
            rate = rates[k % 2]
            t0 = time.perf_counter()
            host.send(_setpoint(200.0, rate))
            end = t0 + 0.5
            while time.perf_counter() < end:
                if any(
                    isinstance(m, Telemetry) and m.pulses_us[0] == expect[rate] for m in host.messages(0.005)
                ):
                    out.append((time.perf_counter() - t0) * 1000)
                    break
            else:
                lost += 1
        host.close()
    return out, lost


def _latency(samples: int) -> tuple[list[float], list[float], int]:
    """:func:`pulse_latency` through a pty, a raw pty echo of the same bytes (ms), and the samples given
    up."""
    out, lost = pulse_latency(samples)
    echo: list[float] = []
    with started([sys.executable, "-c", _PEER, "echo"], ready="/dev/") as peer:
        path = peer.first_line
        port = serial.Serial(path, timeout=1.0)
        data = Framer().encode(_setpoint(300.0))[1]
        for _ in range(samples):
            t0 = time.perf_counter()
            port.write(data)
            got = b""
            while len(got) < len(data):
                got += port.read(len(data) - len(got))
            echo.append((time.perf_counter() - t0) * 1000)
        port.close()
    return out, echo, lost


def _lockstep_speed(seconds: float) -> float:
    from firmware_sim.board import Board
    from firmware_sim.board.config import BoardConfig
    from hil.timing.clock import LockstepClock

    clock = LockstepClock()
    board = Board(BoardConfig(n_units=N_UNITS, frame_rate_hz=490.0, telemetry_rate_hz=100.0), clock)
    framer = Framer()
    board.feed(framer.encode(Hello(schema_hash=SCHEMA_HASH))[1])
    clock.advance(0.1)
    board.feed(framer.encode(Arm())[1])
    t0 = time.perf_counter()
    steps = 0
    while time.perf_counter() - t0 < seconds:
        clock.advance(0.002)  # a 500 Hz control loop
        board.feed(framer.encode(_setpoint(300.0 + steps % 100))[1])
        board.step()
        board.take_output()
        steps += 1
    return steps * 0.002 / (time.perf_counter() - t0)


def _pct(xs: list[float], p: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, round(p / 100 * (len(xs) - 1)))]


def run(quick: bool) -> list[Result]:
    seconds = 0.5 if quick else 3.0
    samples = 30 if quick else 300
    rate, peer_rate, note = _frames_per_second(seconds)
    lat, echo, lost = _latency(samples)
    speed = _lockstep_speed(0.3 if quick else 2.0)
    lat_note = (
        "490 Hz pulse frames, 1 kHz telemetry, 1 ms main-loop tick: the change shows on the next frame; "
        f"{len(lat)} samples, {lost} given up after 0.5 s"
    )
    return [
        Result(
            NAME,
            "setpoints sustained through the pty (no loss)",
            rate,
            "frames/s",
            "raw pty sink",
            peer_rate,
            True,
            note,
        ),
        Result(
            NAME,
            "setpoint -> pulse reported p50",
            statistics.median(lat),
            "ms",
            "raw pty echo p50",
            statistics.median(echo),
            False,
            lat_note,
        ),
        Result(
            NAME,
            "setpoint -> pulse reported p99",
            _pct(lat, 99),
            "ms",
            "raw pty echo p99",
            _pct(echo, 99),
            False,
        ),
        Result(
            NAME,
            "lockstep board, 4 units, 490 Hz",
            speed,
            "x real time",
            "real time",
            1.0,
            True,
            "sans-IO Board driven by a 500 Hz host loop in-process",
        ),
    ]
