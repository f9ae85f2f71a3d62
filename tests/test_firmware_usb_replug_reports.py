"""The board firmware under simavr on the USB link (the harness's MAX3421E and phone), ARMED, the phone
unplugged and plugged back in: what the phone gets first once its accessory is open again.

Nothing stale: while no accessory is open the board queues no Telemetry or Heartbeat (they would be old
by the time a phone is back, and they filled the 1 KB transmit ring, so the Logs made meanwhile were
dropped), and what was queued when the phone went away is emptied. The Logs made while it was away —
"USB accessory disconnected", "link lost", "ARMED -> FAILSAFE" — come first, then a Log counting the
reports not sent, then fresh FAILSAFE telemetry. Before the fix the phone got about a dozen ARMED
telemetry frames from before the detach (up to 1.5 s old) and never the FAILSAFE Logs.

The link timeout and how long the phone stays away are drawn (the seed is in every assertion message)."""

from __future__ import annotations

import random
import time

import pytest
from conformance.host import SerialHost, heartbeat

from firmware_sim.avr import AvrBoard, eeprom
from firmware_sim.avr.harness import HarnessOptions
from firmware_sim.board.codes import LogCode
from firmware_sim.board.config import BoardConfig
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    GimbalMode,
    Heartbeat,
    Log,
    Telemetry,
    UnitSetpoint,
)

F_CPU = 16_000_000
PHONE_ACCESSORY = 2


def phone_mode(b: AvrBoard) -> int:
    return int(b.command("usbstate")[0])


def wait_accessory(b: AvrBoard, timeout_s: float = 5.0) -> None:
    end = time.monotonic() + timeout_s
    while phone_mode(b) != PHONE_ACCESSORY:
        assert time.monotonic() < end, f"the phone never reached accessory mode (now {phone_mode(b)})"
        time.sleep(0.02)


@pytest.mark.firmware
def test_after_a_replug_the_phone_gets_the_logs_made_meanwhile_and_nothing_stale():
    seed = random.randrange(2**32)
    rng = random.Random(seed)
    timeout_s, away_s = rng.choice([0.25, 0.6]), rng.uniform(1.0, 1.5)
    why = f"seed {seed}: link timeout {timeout_s} s, the phone away {away_s:.2f} s"
    config = BoardConfig(n_units=2, telemetry_rate_hz=50.0, link_timeout_s=timeout_s)
    image = eeprom.EepromImage(config, link="usb").to_bytes()

    def setpoint() -> ActuatorSetpoint:
        return ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(0.2, 400.0),) * 2)

    with AvrBoard(config, HarnessOptions(extra_args=("--usb",)), eeprom_image=image) as b:
        wait_accessory(b)
        host = SerialHost(b.port, clock=b.now)
        host.handshake()
        host.keepalive = heartbeat
        assert isinstance(host.request(Arm()), Ack), why
        host.keepalive = setpoint
        host.stream(0.5)
        t_detach = int(b.command("usb detach")[0]) / F_CPU
        host.keepalive = None
        host.poll(0.05)  # what had reached the phone before it went
        n0 = len(host.received)
        time.sleep(away_s)
        t_attach = int(b.command("usb attach")[0]) / F_CPU
        wait_accessory(b)
        host.poll(0.4)
        after = host.received[n0:]
        assert [r.cause.name for r in b.resets()] == ["POWER_ON"], why
        reports = [m for m in after if isinstance(m, (Telemetry, Heartbeat))]
        assert reports, why
        # nothing from the phone's absence or before it: every report is made once the accessory is open
        assert all(m.time_ms / 1000 >= t_attach for m in reports), (why, t_detach, reports[:3])
        assert all(m.state == BoardState.FAILSAFE for m in reports), why
        logs = [m for m in after if isinstance(m, Log)]
        texts = [m.text for m in logs]
        first_report = after.index(reports[0])
        lost = next(i for i, m in enumerate(after) if isinstance(m, Log) and m.code == LogCode.LINK_LOST)
        change = next(i for i, m in enumerate(after) if isinstance(m, Log) and "ARMED -> FAILSAFE" in m.text)
        assert lost < first_report and change < first_report, (why, texts)
        assert any("disconnected" in t for t in texts), (why, texts)
        assert any("not sent while no accessory was open" in t for t in texts), (why, texts)
        host.close()
        b.check()
