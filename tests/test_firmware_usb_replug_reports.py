"""The board firmware under simavr on the USB link (the harness's MAX3421E and phone), ARMED, the phone
unplugged and plugged back in: what the phone's app reads once the accessory is open again.

Nothing stale, nothing of the meanwhile lost: while no accessory is open the board queues no Telemetry or
Heartbeat (stale by the time a phone is back, and they filled the 1 KB transmit ring so that the Logs made
meanwhile were dropped), and those queued when the phone left are taken out of the ring, every other frame
kept. The app reads the Logs made while it was away ("USB accessory disconnected", "link lost", "ARMED ->
FAILSAFE"), then one saying what was not sent, then fresh FAILSAFE telemetry. Before the fix it read about
a dozen ARMED telemetry frames from before the detach (up to 1.5 s old) and never the FAILSAFE Logs.

A frame cut at the detach (its first bulk OUT packet reached the app, the rest was still queued): the app
holds its start. The rest is dropped and "01 00" ends it at the app as one bad frame, so the first Log after
the replug is read whole (emptying the ring at the detach took the rest away and the app's deframer joined
the cut start to the "disconnected" Log: that Log was lost). The phone NAKing its bulk OUT (``usb nak``)
makes cuts common; the detach moments are drawn.

The link timeout, how long the phone stays away and when it leaves are drawn (the seed is in every
assertion message)."""

from __future__ import annotations

import random
import time
from collections.abc import Callable

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

pytestmark = pytest.mark.firmware

F_CPU = 16_000_000
PHONE_ACCESSORY = 2
NOTE = "while no USB accessory was open"


def phone_mode(b: AvrBoard) -> int:
    return int(b.command("usbstate")[0])


def wait_accessory(b: AvrBoard, timeout_s: float = 5.0) -> None:
    end = time.monotonic() + timeout_s
    while phone_mode(b) != PHONE_ACCESSORY:
        assert time.monotonic() < end, f"the phone never reached accessory mode (now {phone_mode(b)})"
        time.sleep(0.02)


def setpoint() -> ActuatorSetpoint:
    return ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=(UnitSetpoint(0.2, 400.0),) * 2)


def replug(b: AvrBoard, host: SerialHost, rng: random.Random, why: str) -> tuple[list[object], float]:
    """ARMED, setpoints streaming: the phone pulled at a drawn moment, plugged back after a drawn while;
    what the app read from the re-attach on, and the re-attach's board time (s)."""
    host.keepalive = heartbeat
    assert isinstance(host.request(Arm()), Ack), why
    host.keepalive = setpoint
    host.stream(rng.uniform(0.3, 0.6))
    b.command("usb detach")
    host.keepalive = None
    host.poll(0.05)  # what reached the app before the phone went
    n0 = len(host.received)
    time.sleep(rng.uniform(1.0, 1.5))
    t_attach = int(b.command("usb attach")[0]) / F_CPU
    wait_accessory(b)
    host.poll(0.4)
    return host.received[n0:], t_attach


def check_after(after: list[object], t_attach: float, why: str) -> list[str]:
    """What the app read after a replug: no report from before the re-attach, the Logs made while the phone
    was away before the first report, the note saying what was not sent. The Logs' texts."""
    reports = [m for m in after if isinstance(m, (Telemetry, Heartbeat))]
    assert reports, why
    stale = [m for m in reports if m.time_ms / 1000 < t_attach]
    assert not stale, (why, stale[:3])  # made before the re-attach: never shown as live
    assert all(m.state == BoardState.FAILSAFE for m in reports), why
    texts = [m.text for m in after if isinstance(m, Log)]
    first_report = after.index(reports[0])

    def at(pred: Callable[[Log], bool]) -> int:
        """Where the first Log ``pred`` takes was read (len(after): never)."""
        return next((i for i, m in enumerate(after) if isinstance(m, Log) and pred(m)), len(after))

    assert at(lambda m: m.text == "USB accessory disconnected") < first_report, (why, texts)
    assert at(lambda m: m.code == LogCode.LINK_LOST) < first_report, (why, texts)
    assert at(lambda m: "ARMED -> FAILSAFE" in m.text) < first_report, (why, texts)
    assert any(t.startswith(NOTE) for t in texts), (why, texts)
    return texts


def test_after_a_replug_the_app_reads_the_logs_made_meanwhile_and_nothing_stale() -> None:
    seed = random.randrange(2**32)
    rng = random.Random(seed)
    timeout_s = rng.choice([0.25, 0.6])
    why = f"seed {seed}: link timeout {timeout_s} s"
    config = BoardConfig(n_units=2, telemetry_rate_hz=50.0, link_timeout_s=timeout_s)
    image = eeprom.EepromImage(config, link="usb").to_bytes()
    with AvrBoard(config, HarnessOptions(extra_args=("--usb",)), eeprom_image=image) as b:
        wait_accessory(b)
        host = SerialHost(b.port, clock=b.now)
        host.handshake()
        after, t_attach = replug(b, host, rng, why)
        check_after(after, t_attach, why)
        assert [r.cause.name for r in b.resets()] == ["POWER_ON"], why
        host.close()
        b.check()


def test_a_frame_cut_at_the_detach_costs_no_log_after_the_replug() -> None:
    """The phone NAKs each bulk OUT packet a few times, so the ring backs up and a detach often falls
    between a frame's packets; three replugs, each checked as above."""
    seed = random.randrange(2**32)
    rng = random.Random(seed)
    config = BoardConfig(n_units=2, telemetry_rate_hz=50.0, link_timeout_s=0.25)
    image = eeprom.EepromImage(config, link="usb").to_bytes()
    with AvrBoard(config, HarnessOptions(extra_args=("--usb",)), eeprom_image=image) as b:
        wait_accessory(b)
        host = SerialHost(b.port, clock=b.now)
        host.handshake()
        b.command(f"usb nak {rng.randint(2, 6)}")
        for k in range(3):
            why = f"seed {seed}, replug {k}"
            after, t_attach = replug(b, host, rng, why)
            check_after(after, t_attach, why)
        assert [r.cause.name for r in b.resets()] == ["POWER_ON"], seed
        host.close()
        b.check()
