"""Board targets for the conformance tests: anything that puts a board behind a serial port path.

A target is a context manager class taking a :class:`TargetSpec`; entering it starts the board and
returns an object with the :class:`Target` interface. To run the whole conformance suite against a
new board (the C firmware under simavr, a real board on a fixture rig), add ONE entry to
:data:`TARGETS`::

    TARGETS["simavr"] = "firmware.harness.conformance:SimavrTarget"   # "module:Class", imported lazily

Times. ``now()``, ``timeline()`` and ``resets()`` are on the target's own clock (seconds): the
emulator's board clock, or simulated cycles / F_CPU under simavr. On the wire, ``Telemetry.time_ms``
and board ``Heartbeat.time_ms`` are the MCU's uptime (ms since its last reset); ``uptime_origin(t)``
converts between the two. Timing assertions use only these board-side times, never host wall time.
"""

from __future__ import annotations

import copy
import importlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from firmware_sim.timeline import PulseFrame, ResetEvent


@dataclass(frozen=True)
class TargetSpec:
    """How the conformance suite wants the board configured (a target must honour every field)."""

    n_units: int = 4
    frame_rate_hz: float = 100.0
    telemetry_rate_hz: float = 50.0
    link_timeout_s: float = 0.25
    mcu_watchdog_s: float = 0.5
    rotor_safe_us: int = 1000
    esc_supply_switch: bool = True  # the ESC supply cut switch is wired (ESC endpoint programming)
    pulse_tolerance_us: int = 1  # one timer tick of the target's pulse hardware


class Target(Protocol):
    name: str
    spec: TargetSpec
    port: str  # a path pyserial opens (a pty)

    def now(self) -> float: ...
    def timeline(self) -> Sequence[PulseFrame]: ...
    def resets(self) -> Sequence[ResetEvent]: ...
    def calibration(self, unit: int) -> Any: ...  # protocol.calibration.UnitCalibration in use
    def esc(self, unit: int) -> Any: ...  # firmware_sim.esc.EmulatedEsc on the unit's rotor channel
    def inject_link_noise(self, corrupt: float, drop: float = 0.0) -> None: ...
    def inject_hang(self) -> float: ...  # returns the target time the main loop stopped
    def inject_sag(self, drop_v: float, ramp_s: float, duration_s: float) -> None: ...
    def clear_faults(self) -> None: ...
    def check(self) -> None: ...  # raise if the target died (a crash is a failure)


def uptime_origin(resets: Sequence[ResetEvent], t: float) -> float:
    """Target time of the reset that began the boot containing ``t``."""
    return [r.t for r in resets if r.t <= t][-1]


def board_config(spec: TargetSpec) -> Any:
    """The ``firmware_sim.config.BoardConfig`` a target runs for ``spec``."""
    from firmware_sim.config import BoardConfig

    return BoardConfig(
        n_units=spec.n_units,
        frame_rate_hz=spec.frame_rate_hz,
        telemetry_rate_hz=spec.telemetry_rate_hz,
        link_timeout_s=spec.link_timeout_s,
        mcu_watchdog_s=spec.mcu_watchdog_s,
        rotor_safe_us=spec.rotor_safe_us,
        esc_supply_switch=spec.esc_supply_switch,
        timeline_frames=20_000,
    )


class FirmwareSimTarget:
    """The Python emulator (``firmware_sim``) on a real pty, real time, in this process."""

    name = "firmware_sim"

    def __init__(self, spec: TargetSpec) -> None:
        from firmware_sim.board import Board
        from firmware_sim.pty_server import PtyServer
        from hil.timing.clock import WallClock

        self.spec = spec
        self.board = Board(board_config(spec), WallClock())
        self.server = PtyServer(self.board)
        self.port = self.server.path

    def __enter__(self) -> FirmwareSimTarget:
        self.server.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.close()

    def now(self) -> float:
        with self.server.lock:
            return self.board.now

    def timeline(self) -> list[PulseFrame]:
        with self.server.lock:
            return list(self.board.timeline.frames)

    def resets(self) -> list[ResetEvent]:
        with self.server.lock:
            return list(self.board.resets)

    def calibration(self, unit: int) -> Any:
        return self.board.calibrations[unit]

    def esc(self, unit: int) -> Any:
        """The board's own emulated ESC (it sees the pulses and the supply switch as they happen)."""
        with self.server.lock:
            self.board.step()
            return copy.deepcopy(self.board.units[unit].esc)

    def inject_link_noise(self, corrupt: float, drop: float = 0.0) -> None:
        with self.server.lock:
            self.board.faults.link(corrupt=corrupt, drop=drop)

    def inject_hang(self) -> float:
        with self.server.lock:
            self.board.step()
            return self.board.faults.hang(at=self.board.now)

    def inject_sag(self, drop_v: float, ramp_s: float, duration_s: float) -> None:
        with self.server.lock:
            self.board.step()
            self.board.faults.sag(drop_v=drop_v, ramp_s=ramp_s, duration=duration_s, at=self.board.now)

    def clear_faults(self) -> None:
        with self.server.lock:
            self.board.faults.clear()

    def check(self) -> None:
        self.server.check()
        thread = self.server._thread
        if thread is None or not thread.is_alive():
            raise AssertionError("the firmware_sim pty server thread is not running")


class SimavrTarget:
    """The C firmware (``firmware/``) on simavr's ATmega2560 behind a real pty, paced to real time. Its
    configuration reaches it through its EEPROM, its times are CPU cycles / 16 MHz, its pulses are
    measured on the output pins, its hang is the watchdog self-test pin (``firmware_sim.avr``)."""

    name = "simavr"
    needs_firmware_build = True  # the AVR toolchain and simavr (.ci/apt-packages)

    def __init__(self, spec: TargetSpec) -> None:
        from firmware_sim.avr import AvrBoard

        self.spec = spec
        self.board = AvrBoard(board_config(spec))
        self.port = self.board.port

    def __enter__(self) -> SimavrTarget:
        return self

    def __exit__(self, *exc: object) -> None:
        self.board.close()

    def now(self) -> float:
        return self.board.now()

    def timeline(self) -> list[PulseFrame]:
        return self.board.timeline()

    def resets(self) -> list[ResetEvent]:
        return self.board.resets()

    def calibration(self, unit: int) -> Any:
        return self.board.calibration(unit)

    def esc(self, unit: int) -> Any:
        """An emulated ESC replaying the pulses and the supply cut pin the firmware drove."""
        return self.board.esc(unit)

    def inject_link_noise(self, corrupt: float, drop: float = 0.0) -> None:
        self.board.inject_link_noise(corrupt, drop)

    def inject_hang(self) -> float:
        return self.board.inject_hang()

    def inject_sag(self, drop_v: float, ramp_s: float, duration_s: float) -> None:
        self.board.inject_sag(drop_v, ramp_s, duration_s)

    def clear_faults(self) -> None:
        self.board.clear_faults()

    def check(self) -> None:
        self.board.check()


# name -> target class, or "module:Class" imported on first use (so a target needing extra tools only
# costs something when selected); a class with ``needs_firmware_build = True`` is skipped, with one line
# for all, where the AVR toolchain is missing (tests/conftest.py). Add a board here and the whole suite
# runs against it.
TARGETS: dict[str, Any] = {
    "firmware_sim": FirmwareSimTarget,
    "simavr": SimavrTarget,
}


def resolve(name: str) -> Any:
    target = TARGETS[name]
    if isinstance(target, str):
        module, _, cls = target.partition(":")
        target = getattr(importlib.import_module(module), cls)
    return target
