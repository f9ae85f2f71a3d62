"""Board targets for the conformance tests: anything that puts a board behind a serial port path.

A target is a context manager class taking a :class:`TargetSpec`; entering it starts the board and
returns an object with the :class:`Target` interface. To run the whole conformance suite against a
new board (the C firmware under simavr, a real board on a fixture rig), add ONE entry to
:data:`TARGETS`::

    TARGETS["simavr"] = "firmware.harness.conformance:SimavrTarget"   # "module:Class", imported lazily

Times. ``now()``, ``timeline()`` and ``resets()`` are on the target's own clock (seconds): the
emulator's board clock, or simulated cycles / F_CPU under simavr. On the wire, ``Telemetry.time_ms``
and board ``Heartbeat.time_ms`` are the MCU's uptime (ms since its last reset); ``uptime_origin(t)``
converts between the two. Timing assertions use only these board-side times, never host wall time,
and the host's own timeouts run on the board's clock too (``conformance.host.connect``).

Two kinds of target. A *lockstep* target (``lockstep = True``: the emulator) runs only while the host
waits, so nothing depends on how busy the machine is. A *real-time* one (the firmware under simavr, a real
board) runs on its own: a host the machine does not run for a while goes quiet for that long, and the
board's link watchdog rightly trips. So only the tests about the link watchdog give the board the short
:data:`LINK_TIMEOUT_S` (pytest marker ``link_watchdog``), and they make an attempt in which the host was
starved again (``conformance.host.Host.kept_up``); the others run with :data:`QUIET_LINK_TIMEOUT_S`.
"""

from __future__ import annotations

import contextlib
import copy
import importlib
import os
import select
import time
import tty
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from conformance.host import PTY_WALL_S
from firmware_sim.board.timeline import PulseFrame, ResetEvent

LINK_TIMEOUT_S = 0.25
"""The link watchdog of the tests about it (marker ``link_watchdog``)."""
QUIET_LINK_TIMEOUT_S = 10.0
"""The link watchdog of every other test: far beyond the ~2.3 s a host was measured to go unscheduled on
a two-core machine with two CPU hogs and a campaign beside it (those tests are not about a starved host)."""


@dataclass(frozen=True)
class TargetSpec:
    """How the conformance suite wants the board configured (a target must honour every field)."""

    n_units: int = 4
    frame_rate_hz: float = 100.0
    telemetry_rate_hz: float = 50.0
    link_timeout_s: float = LINK_TIMEOUT_S
    mcu_watchdog_s: float = 0.5
    rotor_safe_us: int = 1000
    esc_supply_switch: bool = True  # the ESC supply cut switch is wired (ESC endpoint programming)
    pulse_tolerance_us: int = 1  # one timer tick of the target's pulse hardware


class Target(Protocol):
    name: str
    spec: TargetSpec
    port: str  # a path pyserial opens (a pty), or a can:// URL (conformance.host.connect)
    lockstep: bool  # runs only while the host waits (advance, take_in, ...: FirmwareSimTarget)
    stats: Any  # firmware_sim.servers.base.ServerStats: the board side's link statistics
    reports_host_presence: bool  # stats.host_present/host_gone/reconnects are kept

    def now(self) -> float: ...
    def idle(self, seconds: float) -> None: ...  # let that much board time pass, no host waiting
    def timeline(self) -> Sequence[PulseFrame]: ...
    def resets(self) -> Sequence[ResetEvent]: ...
    def calibration(self, unit: int) -> Any: ...  # protocol.calibration.UnitCalibration in use
    def esc(self, unit: int) -> Any: ...  # firmware_sim.board.esc.EmulatedEsc on the unit's rotor channel
    def inject_link_noise(self, corrupt: float, drop: float = 0.0) -> None: ...
    def inject_hang(self) -> float: ...  # returns the target time the main loop stopped
    def inject_sag(self, drop_v: float, ramp_s: float, duration_s: float) -> None: ...
    def clear_faults(self) -> None: ...
    def check(self) -> None: ...  # raise if the target died (a crash is a failure)


def uptime_origin(resets: Sequence[ResetEvent], t: float) -> float:
    """Target time of the reset that began the boot containing ``t``."""
    return [r.t for r in resets if r.t <= t][-1]


def timeline_through(target: Target, t: float) -> Sequence[PulseFrame]:
    """The target's pulse frames with every frame begun by target time ``t`` in them. A frame is measured
    once it has ended, and a real-time target (simavr) may be read between a message the host has just
    taken and the frame beside it (a CI run read a watchdog reset's timeline before the boot's first
    frame had ended): the target runs on, host silent, until two frames past ``t``."""
    end = t + 2.0 / target.spec.frame_rate_hz
    if target.now() < end:
        target.idle(end - target.now())
    return target.timeline()


def board_config(spec: TargetSpec) -> Any:
    """The ``firmware_sim.board.config.BoardConfig`` a target runs for ``spec``."""
    from firmware_sim.board.config import BoardConfig

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


class EmulatedTarget:
    """The Python emulator (``firmware_sim``) in lockstep: its clock (a ``LockstepClock``) moves only while
    the host waits (the lockstep hosts of :mod:`conformance.host` advance it), and every byte the host
    wrote is fed to the board before its clock moves on; what the board does, and when, does not depend
    on how busy the machine is. Subclasses put it behind a link; the board side's statistics are the
    servers' own type (:class:`firmware_sim.servers.base.ServerStats`, host presence included)."""

    name = "firmware_sim"
    lockstep = True
    reports_host_presence = True

    def __init__(self, spec: TargetSpec) -> None:
        from firmware_sim.board import Board
        from hil.timing.clock import LockstepClock

        self.spec = spec
        self.clock = LockstepClock(0.0)
        self.board = Board(board_config(spec), self.clock)

    def next_deadline(self) -> float:
        return self.board.next_deadline()

    def advance(self, until: float) -> None:
        raise NotImplementedError

    def idle(self, seconds: float) -> None:
        """Let ``seconds`` of board time pass with no host waiting."""
        end = self.now() + seconds
        while self.now() < end:
            self.advance(min(self.next_deadline(), end, self.now() + 0.001))

    # ---------------------------------------------------------------- the Target interface
    def now(self) -> float:
        return self.clock.now()

    def timeline(self) -> list[PulseFrame]:
        return list(self.board.timeline.frames)

    def resets(self) -> list[ResetEvent]:
        return list(self.board.resets)

    def calibration(self, unit: int) -> Any:
        return self.board.calibrations[unit]

    def esc(self, unit: int) -> Any:
        """The board's own emulated ESC (it sees the pulses and the supply switch as they happen)."""
        self.board.step()
        return copy.deepcopy(self.board.units[unit].esc)

    def inject_link_noise(self, corrupt: float, drop: float = 0.0) -> None:
        self.board.faults.link(corrupt=corrupt, drop=drop)

    def inject_hang(self) -> float:
        self.board.step()
        return self.board.faults.hang(at=self.board.now)

    def inject_sag(self, drop_v: float, ramp_s: float, duration_s: float) -> None:
        self.board.step()
        self.board.faults.sag(drop_v=drop_v, ramp_s=ramp_s, duration=duration_s, at=self.board.now)

    def clear_faults(self) -> None:
        self.board.faults.clear()

    def check(self) -> None:
        self.board.step()  # a board that cannot run raises here


class FirmwareSimTarget(EmulatedTarget):
    """The emulator behind a real pty, in lockstep: the bytes go through the pty as they would from any
    serial port. (The emulator's real-time pty server, ``firmware_sim.servers.pty_server``, has tests of
    its own: tests/test_firmware_sim_pty.py.)"""

    name = "firmware_sim"

    def __init__(self, spec: TargetSpec) -> None:
        from firmware_sim.servers.base import FrameCounter, HostPresence, ServerStats

        super().__init__(spec)
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline, before the host sets its own modes
        os.set_blocking(master, False)
        self._master: int | None = master
        self._slave: int | None = slave  # held open: a host closing the port never hangs the pty up
        self.port = os.ttyname(slave)
        self.stats = ServerStats()
        self.presence = HostPresence(self.stats)
        self._frames_in, self._frames_out = FrameCounter(), FrameCounter()
        self._host_wrote = 0  # bytes hosts wrote into the pty (they say so: host_wrote)

    @property
    def bytes_out(self) -> int:
        """Bytes the board put into the pty."""
        return self.stats.bytes_out

    def __enter__(self) -> FirmwareSimTarget:
        return self

    def __exit__(self, *exc: object) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None

    # ---------------------------------------------------------------- lockstep (the host drives these)
    def host_wrote(self, n: int) -> None:
        """A host wrote ``n`` bytes into the pty: they reach the board before its clock moves on."""
        self._host_wrote += n

    def take_in(self) -> None:
        """Feed the board, at its present time, every byte hosts have written so far. The pty passes
        bytes on asynchronously, so this waits for them (wall time, only to bound a broken pty)."""
        assert self._master is not None, "the target is closed"
        deadline = time.monotonic() + PTY_WALL_S
        while self.stats.bytes_in < self._host_wrote:
            readable, _, _ = select.select([self._master], [], [], max(deadline - time.monotonic(), 0.0))
            if not readable:
                raise AssertionError(
                    f"the pty passed on {self.stats.bytes_in} of the {self._host_wrote} bytes hosts wrote"
                )
            data = os.read(self._master, 65536)
            self.stats.bytes_in += len(data)
            self.stats.frames_in += self._frames_in.feed(data)
            self.presence.heard(self.now())
            self.board.feed(data)

    def advance(self, until: float) -> None:
        """Run the board to board time ``until`` (its input taken in first), its output into the pty."""
        self.take_in()
        self.clock.set(max(until, self.clock.now()))
        self.board.step()
        self.presence.tick(self.now())
        data = self.board.take_output()
        if data:
            assert self._master is not None, "the target is closed"
            try:
                n = os.write(self._master, data)
            except BlockingIOError:
                n = 0
            self.stats.bytes_out += n
            self.stats.frames_out += self._frames_out.feed(data[:n])
            self.stats.dropped_out += len(data) - n

    def check(self) -> None:
        if self._master is None:
            raise AssertionError("the firmware_sim target's pty is closed")
        super().check()


class FirmwareSimCanTarget(EmulatedTarget):
    """The emulator served on a python-can bus by the real server, ``firmware_sim.servers.can_server``,
    in lockstep (its :meth:`~CanServer.pump` and :meth:`~CanServer.take_in` driven by the host's waits
    instead of its real-time loop). ``interface``: ``virtual`` (in-process) or ``udp_multicast`` (through
    the kernel's sockets, as between processes); ``fd``: CAN FD frames (63 bytes of a frame per segment)
    or classic CAN (7)."""

    interface = "virtual"
    fd = False
    needs_multicast = False

    def __init__(self, spec: TargetSpec) -> None:
        from can_support import multicast_url, virtual_url

        from firmware_sim.servers.can_server import CanServer

        super().__init__(spec)
        make_url = multicast_url if self.interface == "udp_multicast" else virtual_url
        self.port = make_url(fd=self.fd)
        self.server = CanServer(self.board, self.port)
        self.stats = self.server.stats
        self._host_sent = 0  # CAN segments hosts sent (they say so: host_sent)

    def __enter__(self) -> FirmwareSimCanTarget:
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.close()

    def segments_out(self) -> int:
        """CAN segments the board has put on the bus."""
        return self.server.counters()["tx_segments_sent"]

    def _segments_in(self) -> int:
        counters = self.server.counters()
        return counters["rx_segments"] + counters["rx_malformed"]

    def host_sent(self, n: int) -> None:
        """A host sent ``n`` segments: they reach the board before its clock moves on."""
        self._host_sent += n

    def take_in(self) -> None:
        """Feed the board, at its present time, every segment hosts have sent so far (a bus passes them on
        asynchronously: waits for them, wall time only to bound a broken bus)."""
        self.server.take_in(0.0)  # drain the bus even with nothing owed: over udp_multicast the board's
        # own segments come back to its socket, which a board that does not read would let overflow (the
        # kernel then drops what the host sends)
        deadline = time.monotonic() + PTY_WALL_S
        while self._segments_in() < self._host_sent:
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"the bus passed on {self._segments_in()} of the {self._host_sent} segments hosts sent"
                )
            self.server.take_in(0.005)

    def advance(self, until: float) -> None:
        """Run the board to board time ``until`` (its input taken in first), its output onto the bus."""
        self.take_in()
        self.clock.set(max(until, self.clock.now()))
        self.server.pump(self.clock.now())

    def check(self) -> None:
        self.server.check()
        super().check()


class FirmwareSimCanFdTarget(FirmwareSimCanTarget):
    fd = True


class FirmwareSimMulticastTarget(FirmwareSimCanTarget):
    interface = "udp_multicast"
    needs_multicast = True


class FirmwareSimMulticastFdTarget(FirmwareSimMulticastTarget):
    fd = True


class SimavrTarget:
    """The C firmware (``firmware/``) on simavr's ATmega2560 behind a real pty, paced to real time. Its
    configuration reaches it through its EEPROM, its times are CPU cycles / 16 MHz, its pulses are
    measured on the output pins, its hang is the watchdog self-test pin (``firmware_sim.avr``).

    Real time: the board runs whether or not the host does. A harness the machine cannot run on time
    falls behind (its clock slows down, it does not race to catch up); a host the machine cannot run on
    time goes quiet, as a real one would, and the board's link watchdog may trip."""

    name = "simavr"
    lockstep = False
    needs_firmware_build = True  # the AVR toolchain and simavr (.ci/apt-packages)

    def __init__(self, spec: TargetSpec) -> None:
        from firmware_sim.avr import AvrBoard

        self.spec = spec
        self.board = AvrBoard(board_config(spec))
        self.port = self.board.port

    def __enter__(self) -> SimavrTarget:
        return self

    reports_host_presence = False
    """The harness holds the pty's slave open and reports bytes and frames, not who is on the link."""

    @property
    def stats(self) -> Any:
        """The bridge's counters as the servers' statistics (``ServerStats``; host presence not seen)."""
        from firmware_sim.servers.base import ServerStats

        link = self.board.link_stats()
        return ServerStats(
            bytes_in=link["bytes_in"],
            bytes_out=link["bytes_out"],
            frames_in=link["frames_in"],
            frames_out=link["frames_out"],
            dropped_out=link["dropped_out"],
        )

    def __exit__(self, *exc: object) -> None:
        self.board.close()

    def idle(self, seconds: float) -> None:
        """Let ``seconds`` of board time pass (the board runs on its own)."""
        end = self.now() + seconds
        while self.now() < end:
            time.sleep(0.01)

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


class SimavrUsbTarget(SimavrTarget):
    """The same firmware with its link set to ``usb``: the host's bytes reach it as an Android phone's
    accessory app writing to the Mega ADK's USB host port (the harness's MAX3421E model, ``--usb``), through
    the firmware's USB host stack and AOA handshake, instead of over UART0. Ready once the phone is in
    accessory mode (enumerated, switched, enumerated again): before that the app has nothing to write to.
    After a board reset the stack enumerates the phone again, and until it has, the host's bytes are lost,
    as an app's writes fail while the accessory is gone."""

    name = "simavr-usb"
    ACCESSORY_WITHIN_S = 5.0  # board time: debounce, bus resets, two enumerations and the AOA switch

    def __init__(self, spec: TargetSpec) -> None:
        from firmware_sim.avr import AvrBoard
        from firmware_sim.avr.harness import HarnessOptions

        self.spec = spec
        self.board = AvrBoard(board_config(spec), HarnessOptions(usb=True))
        self.port = self.board.port
        try:
            end = self.now() + self.ACCESSORY_WITHIN_S
            while self.board.command("usbstate")[0] != "2":
                if self.now() > end:
                    raise TimeoutError(f"no accessory after {self.ACCESSORY_WITHIN_S} s of board time")
                time.sleep(0.01)
        except BaseException:
            self.board.close()
            raise


# name -> target class, or "module:Class" imported on first use (so a target needing extra tools only
# costs something when selected); a class with ``needs_firmware_build = True`` is skipped, with one line
# for all, where the AVR toolchain is missing (tests/conftest.py). Add a board here and the whole suite
# runs against it.
TARGETS: dict[str, Any] = {
    "firmware_sim": FirmwareSimTarget,
    "firmware_sim-can": FirmwareSimCanTarget,
    "firmware_sim-canfd": FirmwareSimCanFdTarget,
    "firmware_sim-udp_multicast": FirmwareSimMulticastTarget,
    "firmware_sim-udp_multicast-fd": FirmwareSimMulticastFdTarget,
    "simavr": SimavrTarget,
    "simavr-usb": SimavrUsbTarget,
}


def resolve(name: str) -> Any:
    target = TARGETS[name]
    if isinstance(target, str):
        module, _, cls = target.partition(":")
        target = getattr(importlib.import_module(module), cls)
    return target
