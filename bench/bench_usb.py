"""The board's USB link (issue 30) against its UART0: the very firmware under simavr, once with its EEPROM
saying ``link = uart`` (UART0 at 115200 baud on the pty) and once ``link = usb`` (the harness's MAX3421E +
Android phone model on the Mega ADK's SPI, the phone's accessory pipes on the pty), paced to real time.

* setpoint -> pulse latency: board time from the moment the host writes an ActuatorSetpoint that changes
  the rotor speed to the first pulse frame whose rotor width shows it (median of repeated steps; the
  pulse frame is 2.5 ms at 400 Hz, so the frame's own wait is part of both figures);
* frames/s: valid frames the board took per second of its own time (Telemetry.rx_frames over time_ms)
  while the host writes setpoints as fast as the link accepts them;
* flash and RAM of the USB stack: ``avr-size`` of its objects (spi, max3421e, usb_host, aoa, port) built
  with the firmware's flags.
"""

from __future__ import annotations

import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from bench.bench_firmware_sim import _Host
from bench.common import Result
from firmware_sim.avr import AvrBoard, eeprom
from firmware_sim.avr.harness import F_CPU, HarnessOptions
from firmware_sim.avr.paths import FIRMWARE_DIR
from firmware_sim.board.config import BoardConfig
from firmware_sim.board.timeline import PulseFrame
from protocol.messages import ActuatorSetpoint, GimbalMode, Telemetry, UnitSetpoint

NAME = "usb"
CONFIG = BoardConfig(n_units=2, frame_rate_hz=400.0, telemetry_rate_hz=50.0, link_timeout_s=0.5)
USB_SOURCES = ("spi", "max3421e", "usb_host", "aoa", "port")


def _setpoint(speed: float) -> ActuatorSetpoint:
    return ActuatorSetpoint(
        gimbal_mode=GimbalMode.RATE, units=tuple(UnitSetpoint(0.0, speed) for _ in range(CONFIG.n_units))
    )


def _board(link: str) -> AvrBoard:
    image = eeprom.EepromImage(CONFIG, link=link).to_bytes()
    extra = ("--usb",) if link == "usb" else ()
    return AvrBoard(CONFIG, HarnessOptions(extra_args=extra), eeprom_image=image)


def _wait_accessory(board: AvrBoard, timeout_s: float = 10.0) -> None:
    end = time.monotonic() + timeout_s
    while int(board.command("usbstate")[0]) != 2:
        if time.monotonic() > end:
            raise RuntimeError("the phone never reached accessory mode")
        time.sleep(0.02)


def _stream(host: _Host, speed: float | None, seconds: float) -> None:
    """Read for ``seconds`` of wall time, sending the setpoint every 25 ms (``None``: only read)."""
    end = time.monotonic() + seconds
    while (now := time.monotonic()) < end:
        if speed is not None:
            host.send(_setpoint(speed))
        host.messages(min(0.025, end - now))
        time.sleep(max(0.0, min(0.025, end - time.monotonic())))


def _rotor0(frame: PulseFrame) -> float:
    """Unit 0's rotor pulse width in a frame (us; 0 if the channel had no pulse)."""
    return frame.widths[1] or 0.0


def _board_now(board: AvrBoard) -> float:
    return int(board.command("now")[0]) / F_CPU


def measure(link: str, steps: int, flood_s: float) -> tuple[list[float], float]:
    """(setpoint->pulse latencies in ms, frames/s taken by the board) over ``link``."""
    with _board(link) as board:
        if link == "usb":
            _wait_accessory(board)
        host = _Host(board.port)
        try:
            host.session()  # Hello, Arm, Ack
            latencies = []
            for i in range(steps):
                old, new = (300.0, 500.0) if i % 2 else (500.0, 300.0)
                _stream(host, old, 0.15)  # steady at the old speed
                before = _rotor0(board.timeline()[-1])
                t0 = _board_now(board)
                host.send(_setpoint(new))
                after = None
                end = time.monotonic() + 1.0
                while after is None and time.monotonic() < end:
                    _stream(host, None, 0.02)
                    after = next(
                        (f for f in board.timeline() if f.t > t0 and abs(_rotor0(f) - before) > 5.0), None
                    )
                if after is None:
                    raise RuntimeError(f"{link}: the rotor pulse never showed the setpoint")
                latencies.append((after.t - t0) * 1000.0)
            tel: list[Telemetry] = []
            end = time.monotonic() + flood_s
            while time.monotonic() < end:
                for _ in range(20):
                    host.send(_setpoint(400.0))
                tel += [m for m in host.messages(0.0) if isinstance(m, Telemetry)]
            tel += [m for m in host.messages(0.1) if isinstance(m, Telemetry)]
            first, last = tel[len(tel) // 4], tel[-1]  # past the flood's first queueing
            rate = (last.rx_frames - first.rx_frames) / ((last.time_ms - first.time_ms) / 1000.0)
            return latencies, rate
        finally:
            host.close()


def usb_stack_size() -> tuple[int, int]:
    """(flash, RAM) bytes of the USB stack's objects, with the firmware's compiler flags."""
    text = ram = 0
    with tempfile.TemporaryDirectory(prefix="bench-usb-") as work:
        for name in USB_SOURCES:
            obj = Path(work) / f"{name}.o"
            subprocess.run(
                ["avr-gcc", "-mmcu=atmega2560", f"-DF_CPU={F_CPU}UL", "-Os", "-std=gnu11", "-Iinclude",
                 "-ffunction-sections", "-fdata-sections", "-fshort-enums", "-funsigned-char",
                 "-fno-tree-switch-conversion", "-fno-common", "-c", f"src/{name}.c", "-o", str(obj)],
                cwd=FIRMWARE_DIR, check=True,
            )  # fmt: skip
            out = subprocess.run(["avr-size", str(obj)], capture_output=True, text=True, check=True).stdout
            t, d, b = (int(x) for x in out.splitlines()[1].split()[:3])
            text, ram = text + t + d, ram + d + b
    return text, ram


def run(quick: bool) -> list[Result]:
    steps, flood = (6, 1.0) if quick else (30, 4.0)
    lat, rate = {}, {}
    for link in ("uart", "usb"):
        lat[link], rate[link] = measure(link, steps, flood)
    flash, ram = usb_stack_size()
    note = f"firmware under simavr paced to real time, 400 Hz pulse frames, {steps} speed steps"
    return [
        Result(NAME, "setpoint -> pulse latency over USB (median)", statistics.median(lat["usb"]), "ms",
               "over UART0 at 115200", statistics.median(lat["uart"]), False, note),
        Result(NAME, "setpoint -> pulse latency over USB (max)", max(lat["usb"]), "ms",
               "over UART0 at 115200", max(lat["uart"]), False, note),
        Result(NAME, "frames/s taken over USB", rate["usb"], "frames/s", "over UART0 at 115200",
               rate["uart"], True, f"host writing setpoints flat out for {flood:g} s"),
        Result(NAME, "USB stack flash", flash, "bytes", "", None, False, ", ".join(USB_SOURCES)),
        Result(NAME, "USB stack RAM", ram, "bytes", "", None, False, "variables (.data + .bss)"),
    ]  # fmt: skip
