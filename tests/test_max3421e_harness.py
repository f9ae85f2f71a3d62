"""The harness's USB wiring (firmware/harness/usb.c) under simavr: an AVR program with its own few lines of
SPI (firmware/check/spi_check.c) talks to the MAX3421E model over the Mega ADK's pins, and the test reads
what it saw from its RAM through the harness's control commands. Also: ``--usb`` leaves a firmware that
never touches SPI running as before, and the ``usb``/``usbstate`` commands answer as documented."""

from __future__ import annotations

import os
import select
import subprocess
import time

import pytest
from conformance.host import SerialHost, heartbeat

from firmware_sim.avr import AvrBoard, eeprom
from firmware_sim.avr.build import ensure_built
from firmware_sim.avr.harness import HarnessOptions
from firmware_sim.avr.paths import BUILD_DIR, CODEC_CHECK_ELF, HARNESS
from firmware_sim.board.config import BoardConfig
from protocol import aoa
from protocol.frame import Deframer, Frame, encode_frame
from protocol.messages import SCHEMA_HASH, BoardState, Hello, HelloReply, Telemetry

pytestmark = pytest.mark.firmware

SPI_CHECK_ELF = BUILD_DIR / "spi-check.elf"


class Harness:
    """avr-harness with --control: one command, one answer line."""

    def __init__(self, *args: str) -> None:
        ensure_built()
        self.proc = subprocess.Popen(
            [str(HARNESS), "--control", *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.pty = self._line(10.0)

    def _line(self, timeout: float) -> str:
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            raise TimeoutError("avr-harness did not answer")
        line = self.proc.stdout.readline()
        if not line:
            raise EOFError(self.proc.stderr.read())
        return line.strip()

    def ask(self, command: str) -> list[str]:
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        answer = self._line(10.0).split()
        return answer

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                self.ask("quit")
            except (TimeoutError, EOFError, BrokenPipeError):
                pass
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            f.close()


def symbol_address(elf, name: str) -> int:
    """Data-space address of a RAM symbol (avr-nm shows it at 0x800000 + address)."""
    out = subprocess.run(["avr-nm", str(elf)], capture_output=True, text=True, check=True).stdout
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == name:
            return int(parts[0], 16) - 0x800000
    raise LookupError(name)


def test_spi_check_talks_to_the_chip_through_the_adk_pins():
    addr = symbol_address(SPI_CHECK_ELF, "check")
    h = Harness("--usb", "--unpaced", str(SPI_CHECK_ELF))
    try:
        deadline = time.monotonic() + 30
        while True:
            ok, hexdata = h.ask(f"mem {addr} 32")
            assert ok == "ok"
            data = bytes.fromhex(hexdata)
            if data[0] == 0xA5 or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        assert data[0] == 0xA5, "the check program never finished"
        rev_half, rev, osc_ok, int_low, int_high = data[1:6]
        assert (rev_half, rev) == (0xFF, 0x13)  # MISO unused until FDUPSPI, then REVISION
        assert osc_ok == 1
        assert int_low == 1 and int_high == 1  # INT on PE6 follows BUSEVENTIRQ, enabled and cleared
        setup, in_, status, rcvbc = data[6:10]
        assert (setup, in_, status, rcvbc) == (0, 0, 0, 18)
        desc = data[10:28]
        assert desc[:2] == bytes([18, 1]) and desc[8:12] == bytes([0xE8, 0x04, 0x60, 0x68])
        assert data[28] == 0xFF and data[29] == 0xFF  # RES (PJ2) low: nobody answers; after it, half duplex
        polls = int.from_bytes(data[30:32], "little")
        assert polls >= 1  # the SETUP took simulated time: HXFRDNIRQ was not there at the first look
        state = h.ask("usbstate")
        assert state[0] == "ok" and state[1] == "1"  # a phone in normal mode
        assert bytes.fromhex(state[8]).decode().startswith("register 18 read in half-duplex")
        assert int(state[12]) > 100  # SPI bytes the MCU clocked
    finally:
        h.close()


def test_usb_fault_commands():
    h = Harness("--usb", "--unpaced", str(SPI_CHECK_ELF))
    try:
        assert h.ask("usb detach")[0] == "ok"
        assert h.ask("usbstate")[1] == "0"
        assert h.ask("usb attach")[0] == "ok"
        assert h.ask("usbstate")[1] == "1"
        assert h.ask("usb nak 5")[0] == "ok"
        assert h.ask("usb packet 7")[0] == "ok"
        assert h.ask("usb zlp 1")[0] == "ok"
        assert h.ask("usb aoa 0")[0] == "ok"
        assert h.ask("usb packet 65")[0] == "error"
        assert h.ask("usb aoa x")[0] == "error"
        assert h.ask("usb bogus 1")[0] == "error"
        assert h.ask("usb nak")[0] == "error"  # a value is needed (only detach and attach go without)
        assert h.ask("usb detach 1")[0] == "ok"
    finally:
        h.close()


def test_usb_commands_need_usb():
    h = Harness("--unpaced", str(CODEC_CHECK_ELF))
    try:
        assert h.ask("usbstate")[:2] == ["error", "usbstate:"]
        assert h.ask("usb detach")[0] == "error"
    finally:
        h.close()


def test_usb_mode_runs_a_firmware_that_never_touches_spi():
    # The codec check only speaks UART0: under --usb it runs on (no crash), its UART0 is not on the pty,
    # and what the host writes is dropped and counted, since no accessory is open.
    h = Harness("--usb", "--unpaced", str(CODEC_CHECK_ELF))
    try:
        fd = os.open(h.pty, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, b"\x02\x01\x00")
            deadline = time.monotonic() + 10
            while int(h.ask("usbstate")[11]) < 3 and time.monotonic() < deadline:
                time.sleep(0.05)
            state = h.ask("usbstate")
            assert state[11] == "3" and state[9] == "0"  # dropped, none delivered
            assert int(h.ask("now")[1]) > 0
            assert not select.select([fd], [], [], 0.2)[0]  # nothing from UART0 on the pty
        finally:
            os.close(fd)
    finally:
        h.close()


# --------------------------------------------------------------------------- the real firmware
def usb_board() -> AvrBoard:
    """The board firmware with its EEPROM saying link = usb, under ``--usb``, paced to real time."""
    config = BoardConfig(n_units=2, telemetry_rate_hz=50.0, link_timeout_s=0.25)
    image = eeprom.EepromImage(config, link="usb").to_bytes()
    return AvrBoard(config, HarnessOptions(extra_args=("--usb",)), eeprom_image=image)


def usbstate(board: AvrBoard) -> tuple[int, list[str], str]:
    words = board.command("usbstate")
    text = [bytes.fromhex(w).decode() if w != "-" else "" for w in words[1:8]]
    return int(words[0]), text[:6], text[6]


def wait_mode(board: AvrBoard, mode: int, timeout_s: float) -> None:
    end = board.now() + timeout_s
    while usbstate(board)[0] != mode:
        assert board.now() < end, f"the phone never reached mode {mode}"
        time.sleep(0.02)


def test_real_firmware_serves_the_protocol_over_the_emulated_usb():
    with usb_board() as board:
        wait_mode(board, 2, 5.0)  # enumerated, switched, enumerated again as an accessory
        host = SerialHost(board.port)
        try:
            reply = host.handshake()
            mode, strings, error = usbstate(board)
            # the strings the board sent on SEND_STRING are the identity its HelloReply carries
            assert strings == [s for _, s in aoa.AccessoryIdentity.from_message(reply).strings()]
            assert error == ""
            host.keepalive = heartbeat
            tel = host.wait_type(Telemetry, 1.0)
            assert tel.state == BoardState.DISARMED
        finally:
            host.close()


def test_detach_and_reattach_under_the_real_firmware():
    with usb_board() as board:
        wait_mode(board, 2, 5.0)
        host = SerialHost(board.port)
        try:
            host.handshake()
            board.command("usb detach")
            assert usbstate(board)[0] == 0
            board.command("usb attach")  # a phone plugged in again starts in its normal mode
            wait_mode(board, 2, 5.0)  # and the board switches it again
            host.port.reset_input_buffer()
            host.keepalive = heartbeat
            reply = host.handshake()
            assert reply.state == BoardState.DISARMED
            assert host.wait_type(Telemetry, 1.0)
        finally:
            host.close()


# --------------------------------------------------------------------------- firmware-sim --avr --usb
def test_firmware_sim_avr_usb_serves_the_protocol_on_its_pty():
    import signal
    import sys

    ensure_built()
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--avr", "--usb", "--duration", "60"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/"), proc.stderr.read() if proc.poll() is not None else path
        host = SerialHost(path)
        try:
            reply = host.handshake(tries=100)  # the first ones are lost until the accessory is open
            assert reply.state == BoardState.DISARMED
            host.keepalive = heartbeat
            assert host.wait_type(Telemetry, 1.0)
        finally:
            host.close()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
        assert proc.returncode == 0, err
        # the stop line ends with the phone as the harness saw it: switched, the board's identity sent
        assert "phone on USB: accessory (vscmg-hil / ADK-VSCMG)" in err.strip().splitlines()[-1], err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


@pytest.mark.parametrize(
    ("argv", "why"),
    [
        (["--usb"], "it needs --avr"),
        (["--usb", "--avr", "--can", "virtual/0"], "choose one"),  # one link: the phone or the CAN bridge
        (["--avr", "--world", "cubesat-1u", "--usb-detach", "5:1"], "needs --avr --usb --world"),
        (["--avr", "--usb", "--usb-detach", "5:1"], "needs --avr --usb --world"),  # the stepped board's
    ],
)
def test_firmware_sim_usb_refusals(argv, why, capsys):
    from firmware_sim.cli import main

    with pytest.raises(SystemExit) as exc:
        main([*argv, "--duration", "0.01"])  # refused before it serves: the duration never runs
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--usb" in err and why in err, err


@pytest.mark.parametrize("query", ["usb=1", "usb_detach=5:1"])
def test_the_python_board_has_no_usb_link(query):
    from hil.link.transports import create_transport
    from protocol.errors import ConfigError

    transport = create_transport(f"emu://?{query}")
    with pytest.raises(ConfigError, match="firmware board"):
        transport.board  # noqa: B018  # made on first use: refused there


def test_lockstep_harness_carries_the_protocol_over_usb():
    # --stepped --uart-pipe --usb: the "rx" bytes are the phone app's writes and the "step" answers carry
    # what the board sent on bulk OUT, simulated time moving only on steps (as firmware_sim.avr.stepped).
    config = BoardConfig(n_units=2, link_timeout_s=10.0)
    options = HarnessOptions(usb=True, stepped=True, uart_pipe=True, paced=False)
    step = 160_000  # 10 ms of board time
    with AvrBoard(config, options) as board:
        cycles = 0
        for _ in range(500):
            cycles += step
            board.command(f"step {cycles}")
            if board.command("usbstate")[0] == "2":
                break
        else:
            pytest.fail("no accessory after 5 s of board time")
        board.command("rx " + encode_frame(Hello(schema_hash=SCHEMA_HASH, manufacturer="t"), seq=0).hex())
        deframer = Deframer()
        for _ in range(100):
            cycles += step
            words = board.command(f"step {cycles}")
            assert int(words[0]) >= cycles  # to the instruction that crosses it
            if words[1] != "-":
                replies = [e for e in deframer.feed(bytes.fromhex(words[1])) if isinstance(e, Frame)]
                if any(isinstance(f.message, HelloReply) for f in replies):
                    break
        else:
            pytest.fail("no HelloReply over USB within 1 s of board time")
