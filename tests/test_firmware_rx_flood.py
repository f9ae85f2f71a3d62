"""The board firmware under simavr with UART0 at 250 kbaud .. 1 Mbaud and the host writing flat out: its
main loop reads received bytes for a bounded time a pass, so the MCU watchdog check-in, the link
watchdog, the reports and the outputs go on under any flood.

* A flood of frames the board discards (a bad CRC, another protocol's version) is a silent link: the
  rotors reach the safe pulse within the link timeout plus one pulse frame of the last valid frame, the
  board says "link lost", keeps its telemetry going and never resets. It says that bytes were lost
  exactly when it lost some (its own count, uart.c's ``stats``): at 1 Mbaud it cannot keep up; at
  250 kbaud it now does (since the CRC went a byte at a time, firmware/src/crc16.c) and says nothing.
* A flood of valid setpoints keeps the board ARMED: after an overflow the receive ring takes bytes again
  only from a frame delimiter, so it loses whole frames and takes whole ones, never a few bytes of each.

The baud rate and the moment the flood begins after the last valid frame are drawn (the seed is in every
assertion message)."""

from __future__ import annotations

import random
import struct
import threading
import time

import pytest
from conformance.host import SerialHost, heartbeat
from conformance.targets import uptime_origin

from firmware_sim.avr import AvrBoard, eeprom
from firmware_sim.avr.harness import _symbols
from firmware_sim.board.codes import LogCode
from firmware_sim.board.config import BoardConfig
from protocol import cobs
from protocol.crc import crc16_ccitt_false
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    GimbalMode,
    Log,
    ResetCause,
    Telemetry,
    UnitSetpoint,
    WatchdogState,
)

CONFIG = BoardConfig(n_units=2, telemetry_rate_hz=50.0, link_timeout_s=0.25)
BAUDS = (250_000, 500_000, 1_000_000)
FLOOD_S = 1.2  # more than twice the MCU watchdog (0.5 s): a loop that never checks in resets in it
MS = 0.0015  # the wire carries milliseconds
GRACE_S = 0.004  # app.c's LINK_GRACE_MS: the link watchdog waits this long past its timeout for bytes waiting


def setpoint(speed: float = 400.0) -> ActuatorSetpoint:
    return ActuatorSetpoint(
        gimbal_mode=GimbalMode.RATE, units=tuple(UnitSetpoint(0.0, speed) for _ in range(CONFIG.n_units))
    )


def discarded(host: SerialHost, kind: str) -> bytes:
    """A setpoint frame the board must discard: its CRC damaged, or CRC-valid of another protocol version."""
    _, good = host.framer.encode(setpoint())
    body = bytearray(cobs.decode(good[:-1]))
    if kind == "version":
        body[0] ^= 0x7F
        body[-2:] = struct.pack("<H", crc16_ccitt_false(bytes(body[:-2])))
    else:
        body[-1] ^= 0x55
    return cobs.encode(bytes(body)) + b"\0"


def flood(host: SerialHost, blob: bytes, seconds: float) -> None:
    """Write ``blob`` over and over, flat out, for ``seconds`` (wall time), reading what comes back."""
    stop = time.monotonic() + seconds

    def writer() -> None:
        i = 0
        while time.monotonic() < stop:
            host.port.write(blob[i : i + 512])
            i = (i + 512) % len(blob)

    thread = threading.Thread(target=writer)
    thread.start()
    while thread.is_alive():
        host.poll(0.05)
    thread.join()


def armed_board(baud: int):
    return AvrBoard(CONFIG, eeprom_image=eeprom.EepromImage(CONFIG, baud=baud).to_bytes())


def bytes_lost(board: AvrBoard) -> int:
    """The firmware's own count of received bytes lost to a full receive ring (uart.c's
    ``stats.rx_overflow``), read from the simulated MCU's RAM."""
    address = _symbols(board.options.elf)["stats"] & 0xFFFF
    return int.from_bytes(board.memory(address, 4), "little")


def telemetry_gaps(host: SerialHost, t0: float, t1: float) -> list[int]:
    tel = [
        m.time_ms for m in host.received if isinstance(m, Telemetry) and t0 * 1000 <= m.time_ms <= t1 * 1000
    ]
    return [b - a for a, b in zip(tel, tel[1:], strict=False)]


@pytest.mark.firmware
@pytest.mark.parametrize("kind", ["crc", "version"])
def test_a_flood_of_discarded_frames_is_a_silent_link(kind):
    seed = random.randrange(2**32)
    rng = random.Random(seed)
    baud, quiet = rng.choice(BAUDS), rng.uniform(0.0, 0.15)
    why = f"seed {seed}: {kind} flood at {baud} baud, {quiet * 1000:.0f} ms after the last valid frame"
    with armed_board(baud) as board:
        host = SerialHost(board.port, clock=board.now)
        host.handshake()
        host.keepalive = heartbeat
        assert isinstance(host.request(Arm()), Ack)
        host.keepalive = setpoint
        host.stream(0.5)
        host.keepalive = None
        host.poll(quiet)
        t_start = board.now()
        flood(host, discarded(host, kind) * 2000, FLOOD_S)
        t_end = board.now()
        host.poll(0.1)
        resets = board.resets()
        assert [r.cause for r in resets] == [ResetCause.POWER_ON], why
        lost = [
            m for m in host.received if isinstance(m, Telemetry) and m.watchdog == WatchdogState.LINK_LOST
        ]
        assert lost and lost[0].state == BoardState.FAILSAFE, why
        origin = uptime_origin(resets, board.now())
        t_last = origin + (lost[0].time_ms - lost[0].link_age_ms) / 1000  # the last frame the board took
        frame = 1.0 / CONFIG.frame_rate_hz
        rotor = [(f.t, f.widths[1]) for f in board.timeline() if f.t >= t_last - 0.1]
        assert any(w > CONFIG.rotor_safe_us for t, w in rotor if t < t_last), why
        t_safe = next(t for t, w in rotor if t >= t_last and w == CONFIG.rotor_safe_us)
        assert t_safe - t_last <= CONFIG.link_timeout_s + GRACE_S + frame + MS, why
        assert all(w == CONFIG.rotor_safe_us for t, w in rotor if t_safe <= t <= t_end), why
        logs = [m for m in host.received if isinstance(m, Log)]
        assert any(m.code == LogCode.LINK_LOST for m in logs), why
        lost = bytes_lost(board)
        assert any(m.code == LogCode.RX_OVERFLOW for m in logs) == (lost > 0), (why, lost)
        if baud >= 1_000_000:
            assert lost > 0, why  # 160 cycles a byte: no loop keeps up with that
        gaps = telemetry_gaps(host, t_start, t_end)
        assert len(gaps) > FLOOD_S * CONFIG.telemetry_rate_hz / 2 and max(gaps) <= 100, (why, gaps)
        host.close()
        board.check()


@pytest.mark.firmware
def test_a_setpoint_flood_keeps_the_board_armed_and_reporting():
    seed = random.randrange(2**32)
    baud = random.Random(seed).choice(BAUDS)
    why = f"seed {seed}: setpoints flat out at {baud} baud"
    with armed_board(baud) as board:
        host = SerialHost(board.port, clock=board.now)
        host.handshake()
        host.keepalive = heartbeat
        assert isinstance(host.request(Arm()), Ack)
        blob = b"".join(host.framer.encode(setpoint(200.0 + k % 100))[1] for k in range(2000))
        host.keepalive = None
        t_start = board.now()
        flood(host, blob, FLOOD_S)
        t_end = board.now()
        host.keepalive = heartbeat
        host.poll(0.2)
        assert [r.cause for r in board.resets()] == [ResetCause.POWER_ON], why
        during = [
            m
            for m in host.received
            if isinstance(m, Telemetry) and t_start * 1000 <= m.time_ms <= t_end * 1000
        ]
        assert during and all(
            m.state == BoardState.ARMED and m.watchdog == WatchdogState.OK for m in during
        ), why
        gaps = telemetry_gaps(host, t_start, t_end)
        assert len(gaps) > FLOOD_S * CONFIG.telemetry_rate_hz / 2 and max(gaps) <= 100, (why, gaps)
        overflow = [m for m in host.received if isinstance(m, Log) and m.code == LogCode.RX_OVERFLOW]
        # reported, at most once a heartbeat period: a Log each pass would crowd the telemetry out
        assert 1 <= len(overflow) <= (t_end - t_start) * CONFIG.heartbeat_rate_hz + 2, why
        assert not any(isinstance(m, Log) and m.code == LogCode.LINK_LOST for m in host.received), why
        host.close()
        board.check()
