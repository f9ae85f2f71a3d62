"""The board firmware's USB link end to end: the very firmware image under simavr, its EEPROM saying
``link = usb`` (or ``first``), the harness's MAX3421E + Android phone model on the Mega ADK's SPI pins
(``avr-harness --usb``), the host on the pty the phone's accessory pipes are bridged to.

What only the whole board shows: the refusal ``Log`` of a phone without accessory mode reaches the host
once a phone that has one is plugged in; unplugging the phone is a silent link (FAILSAFE within the link
timeout plus one pulse frame, on the pins) and plugging it back in is enumerated, switched and re-armed;
``first`` takes the USB link when the first valid frame comes from the phone."""

from __future__ import annotations

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
    Log,
    Severity,
    Telemetry,
    UnitSetpoint,
)

pytestmark = pytest.mark.firmware

CONFIG = BoardConfig(n_units=2, telemetry_rate_hz=50.0, link_timeout_s=0.25)
PHONE_DETACHED, PHONE_NORMAL, PHONE_ACCESSORY = 0, 1, 2
F_CPU = 16_000_000


def board(link: str = "usb") -> AvrBoard:
    image = eeprom.EepromImage(CONFIG, link=link).to_bytes()
    return AvrBoard(CONFIG, HarnessOptions(extra_args=("--usb",)), eeprom_image=image)


def phone_mode(b: AvrBoard) -> int:
    return int(b.command("usbstate")[0])


def wait_mode(b: AvrBoard, mode: int, timeout_s: float = 5.0) -> None:
    end = time.monotonic() + timeout_s
    while phone_mode(b) != mode:
        assert time.monotonic() < end, f"the phone never reached mode {mode} (now {phone_mode(b)})"
        time.sleep(0.02)


def usb(b: AvrBoard, *words: str) -> float:
    """A phone/cable fault; the board time (s) it took effect."""
    answer = b.command("usb " + " ".join(words))
    return int(answer[0]) / F_CPU


def setpoint(speed: float = 400.0) -> ActuatorSetpoint:
    return ActuatorSetpoint(
        gimbal_mode=GimbalMode.RATE,
        units=tuple(UnitSetpoint(0.2, speed + 20.0 * i) for i in range(CONFIG.n_units)),
    )


def test_a_phone_without_accessory_mode_is_refused_and_the_log_says_so():
    with board() as b:
        usb(b, "detach")
        usb(b, "aoa", "0")
        usb(b, "attach")
        time.sleep(1.5)  # debounce, reset, enumeration, GET_PROTOCOL: ~0.3 s of board time
        assert phone_mode(b) == PHONE_NORMAL  # never switched
        host = SerialHost(b.port)
        try:
            usb(b, "detach")
            usb(b, "aoa", "2")
            usb(b, "attach")
            wait_mode(b, PHONE_ACCESSORY)
            # what the board queued while no accessory was open arrives first
            log = host.wait_type(Log, 3.0, lambda m: m.code == LogCode.HANDSHAKE)
            assert log.text == "USB device refused: no Android accessory mode (AOA protocol 0)"
            reply = host.handshake()
            assert reply.state == BoardState.DISARMED
            # a Log from inside the USB stack is its deepest call: the firmware's stack rule still holds
            assert b.stack_headroom() >= 256
        finally:
            host.close()


def test_a_phone_that_never_switches_after_start_is_refused_with_an_error_log():
    """START taken, no accessory ever comes back: AOA_HANDSHAKE_TRIES (3) STARTs, AOA_REENUM_US (3 s)
    apart, then the refusal as an ERROR Log (code HANDSHAKE), not a START every 3 s for ever."""
    with board() as b:
        usb(b, "detach")
        usb(b, "never_switch", "1")
        t0 = usb(b, "attach")
        end = time.monotonic() + 60.0
        while usb(b, "nak", "0") - t0 < 3 * 3.0 + 1.0:  # three tries of 3 s, and some
            assert time.monotonic() < end, "the board's clock did not get past the three tries"
            time.sleep(0.25)
        assert phone_mode(b) == PHONE_NORMAL  # never switched
        host = SerialHost(b.port)
        try:
            usb(b, "detach")
            usb(b, "never_switch", "0")
            usb(b, "attach")
            wait_mode(b, PHONE_ACCESSORY)  # a new attach tries again: this phone switches
            refusal = host.wait_type(Log, 3.0, lambda m: m.code == LogCode.HANDSHAKE)
            assert refusal.severity == Severity.ERROR
            assert refusal.text == "USB phone refused: no accessory mode after START, AOA protocol 2"
            logs = [m for m in host.received if isinstance(m, Log)]
            before = logs[: logs.index(refusal)]
            assert sum("switching to accessory mode" in m.text for m in before) == 3
            assert host.handshake().state == BoardState.DISARMED
        finally:
            host.close()


def test_unplugging_the_phone_is_a_link_loss_and_plugging_it_back_re_arms():
    with board() as b:
        wait_mode(b, PHONE_ACCESSORY)
        host = SerialHost(b.port)
        try:
            host.handshake()
            host.keepalive = heartbeat
            assert isinstance(host.request(Arm()), Ack)
            host.keepalive = setpoint
            host.stream(0.6)
            assert host.wait_type(Telemetry, 1.0).state == BoardState.ARMED
            t_detach = usb(b, "detach")
            host.keepalive = None
            time.sleep(1.0)
            frames = [f for f in b.timeline() if f.t >= t_detach - 0.05]
            assert frames[0].widths[1] > CONFIG.rotor_safe_us  # spinning when the cable went
            t_safe = next(f.t for f in frames if f.widths[1::2] == (CONFIG.rotor_safe_us,) * CONFIG.n_units)
            # the last frame the board took came before the detach: safe within the timeout + one frame
            assert t_safe - t_detach <= CONFIG.link_timeout_s + 1.0 / CONFIG.frame_rate_hz + 0.002
            usb(b, "attach")  # the phone comes back in its normal mode: enumerated and switched again
            wait_mode(b, PHONE_ACCESSORY)
            host.keepalive = heartbeat
            host.stream(0.3)
            seen = [m for m in host.received if isinstance(m, Telemetry)]
            assert seen and seen[-1].state == BoardState.FAILSAFE
            reply = host.handshake()
            assert reply.state == BoardState.DISARMED
            assert isinstance(host.request(Arm()), Ack)
            host.keepalive = setpoint
            host.stream(0.3)
            assert host.wait_type(Telemetry, 1.0).state == BoardState.ARMED
            assert b.stack_headroom() >= 256  # bytes of RAM the stack never reached, USB running
        finally:
            host.close()


def test_first_takes_the_usb_link_when_the_phone_speaks_first():
    with board("first") as b:
        wait_mode(b, PHONE_ACCESSORY)
        host = SerialHost(b.port)
        try:
            reply = host.handshake()  # over the phone's pipes: UART0 never spoke
            assert reply.state == BoardState.DISARMED
            host.keepalive = heartbeat
            assert host.wait_type(Telemetry, 1.0).state == BoardState.DISARMED
        finally:
            host.close()


def test_first_takes_uart0_when_the_host_speaks_there_and_no_chip_answers():
    # the stock harness (no --usb): UART0 on the pty and nothing on the SPI pins, so the stack's chip
    # never starts its oscillator; the board must run on regardless (no hang, no watchdog reset)
    image = eeprom.EepromImage(CONFIG, link="first").to_bytes()
    with AvrBoard(CONFIG, HarnessOptions(), eeprom_image=image) as b:
        host = SerialHost(b.port)
        try:
            reply = host.handshake()
            assert reply.state == BoardState.DISARMED
            host.keepalive = heartbeat
            host.stream(1.5)  # past the stack's first retries of the silent chip (every 1 s)
            assert host.wait_type(Telemetry, 1.0).state == BoardState.DISARMED
            assert len(b.resets()) == 1  # the power-on only
        finally:
            host.close()


def test_a_usb_board_without_its_chip_keeps_running():
    image = eeprom.EepromImage(CONFIG, link="usb").to_bytes()
    with AvrBoard(CONFIG, HarnessOptions(), eeprom_image=image) as b:
        time.sleep(2.5)
        assert b.now() > 2.0
        assert len(b.resets()) == 1
        frames = b.timeline()
        assert frames and frames[-1].t > 2.0  # the pulses go on
        assert frames[-1].widths[1::2] == (CONFIG.rotor_safe_us,) * CONFIG.n_units
