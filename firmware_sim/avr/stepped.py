"""The firmware as the board of a simulated world: the ATmega2560 binary under simavr, stepped on a clock.

:class:`FirmwareBoard` runs ``avr-harness --stepped --uart-pipe`` (:class:`.AvrBoard`): simulated time
moves only when the board is stepped, and the host's link goes through the control pipe — UART0, or with
``usb`` (``--usb``) the accessory app of the phone on the board's USB host port, which the firmware
enumerates and switches into accessory mode itself (its EEPROM's link = usb) — so the same object is
the board of a lockstep run (the host's ``LockstepClock``: deterministic, as fast as simavr goes) and of a
real-time one (a ``WallClock``: :class:`firmware_sim.servers.pty_server.PtyServer` steps it to the wall
clock's present as it serves the pty, like the Python board).

It has the interface of :class:`firmware_sim.board.Board` that :class:`firmware_sim.world.World` and the
servers call — ``step``, ``feed``, ``take_output``, ``next_deadline_us``, ``next_output_change_us``,
``outputs``, ``drive_epoch``, ``gimbal_mode``, ``units``, ``power``, ``set_unit_states``, ``faults`` —
so the world is the same world whichever board drives it:

* **Pulses.** The widths are the ones the harness measured on the output pins (its record of edges, on
  the timers' 0.5 µs tick grid, :mod:`.records`). A frame's widths reach the drives once all its pulses
  have ended — what an ESC or servo acts on is a whole pulse — so the board wakes at each frame's
  predicted end (start + :data:`SETTLE_US`); a frame whose pulses end later is seen at the next wake.
* **One battery.** The battery, the UBEC rail and the units' loads are firmware_sim's models
  (:func:`firmware_sim.board.power.solve_supply`, the same as the Python board's, fed with the world's
  unit states), solved every :attr:`BoardConfig.power.update_period_s`; the result is set on the
  firmware's four analog inputs (the harness's ``power`` command). The harness's own power model stands
  aside; its brown-out detector acts on that rail, so a sag (``faults.sag``, ``--sag``,
  ``--brownout-at``) browns the MCU out through the world's battery.
* **The firmware's state.** The protocol state and gimbal mode are read from the firmware's RAM
  (``board.state`` .. ``board.gimbal_mode``, watched by the harness at every pulse start): each frame is
  recorded with the state it started in, and the world reads the gimbal pulses in the mode they were made
  for.
* **Faults.** Link faults act on the bytes between host and UART (``faults.filter``, as for the Python
  board); a hang pulls the firmware's watchdog self-test pin; a dead ESC or servo stops its unit's drive
  in the world; phone faults act on the world's phone. A cable unplug is not modelled (refused). With
  USB, :meth:`FirmwareBoard.detach_phone` pulls the phone off the host port for a while (the harness's
  ``usb detach``, then ``usb attach`` of a phone in its normal mode, at their times on the board's clock).

Times are the board clock's (s); the harness's time starts at the clock's time when the board is made.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from hil.timing.clock import Clock, LockstepClock
from protocol.calibration import default_unit_calibration
from protocol.errors import ConfigError
from protocol.messages import BoardState, GimbalMode, UnitState

from ..board.actuators import UnitModel, bench_truths, follow_all
from ..board.config import BoardConfig
from ..board.faults import FaultInjector
from ..board.power import solve_supply
from ..board.power_models import Battery, PowerReading
from ..board.timeline import PulseTimeline, ResetEvent
from .harness import F_CPU, AvrBoard, HarnessOptions
from .paths import FIRMWARE_DIR, FIRMWARE_ELF

SETTLE_US = 2100
"""How long after a frame starts its pulses have all ended (µs): the longest rotor pulse (2000 µs) and
the channels' start skew (:data:`.records.FRAME_SKEW_US`); longer (raw) pulses are seen at the next wake."""
MAX_STEP_S = 0.5
"""The longest span one harness ``step`` command runs (s), well inside the control pipe's answer timeout."""
RX_CHUNK = 240
"""The most bytes one ``rx`` command carries (bytes): its hex fits the harness's 512-character command line
(``harness/control.c``); a longer write from the host (a server reads up to 64 KiB at once) goes in
several."""
_WATCHED_FIELDS = ("state", "mode", "power_state", "gimbal_mode")
"""The firmware's ``board_t`` fields the harness watches (consecutive bytes, app.h)."""
_CYCLES_PER_US = F_CPU // 1_000_000


class FirmwareBoard:
    """The firmware on simavr as a world's board, on ``clock``. ``config`` becomes the firmware's EEPROM
    configuration; ``options`` the harness's (its fault options: none; ``stepped``/``uart_pipe``/``paced``
    are set here). Use as a context manager, or :meth:`close`."""

    def __init__(
        self,
        config: BoardConfig | None = None,
        clock: Clock | None = None,
        options: HarnessOptions | None = None,
    ) -> None:
        cfg = config if config is not None else BoardConfig()
        cfg.validate()
        self.config = cfg
        self.clock: Clock = clock if clock is not None else LockstepClock()
        opts = options if options is not None else HarnessOptions()
        self.harness = AvrBoard(cfg, replace(opts, paced=False, stepped=True, uart_pipe=True))
        try:
            address = board_field_address(self.harness.options.elf, _WATCHED_FIELDS[0])
            self.harness.command(f"watch {address} {len(_WATCHED_FIELDS)}")
        except BaseException:
            self.harness.close()
            raise
        # A run drops its transport without closing the board (a reopened link finds it running): the
        # harness process ends with the board object, not with the interpreter.
        weakref.finalize(self, self.harness.close)
        n = cfg.n_units
        self.faults = FaultInjector(self.clock, cfg.seed, cfg.n_channels)
        self.battery = Battery(cfg.power.battery)
        truths = bench_truths(cfg)
        self.calibrations = [default_unit_calibration() for _ in range(n)]
        self.units = [
            UnitModel(cfg.motor, cfg.gimbal, self.calibrations[i], truths[i], cfg.esc) for i in range(n)
        ]
        self.power = PowerReading(soc=self.battery.soc)
        self.power.battery_v = self.battery.ocv()
        self.timeline = PulseTimeline(cfg.timeline_frames)
        self.resets: list[ResetEvent] = []
        self.outputs: tuple[float | None, ...] = (None,) * cfg.n_channels
        """The widths (µs, whole 0.5 µs ticks) of the newest complete frame on the pins (None: no pulse)."""
        self.drive_epoch = 0
        """Counts the changes of what the motors' drivers see (a frame's widths, outputs off at a reset)."""
        self.gimbal_mode = GimbalMode.RATE
        self._origin_us = round(self.clock.now() * 1e6)
        self._t_us = self._phys_us = self._origin_us
        self._frame_us = round(1e6 / cfg.frame_rate_hz)
        self._poll_us = max(1, round(cfg.power.update_period_s * 1e6))
        self._last_frame_t: float | None = None
        self._seen_resets = 0
        self._seen_supply = 0
        self._supply_on = True
        self._watched: bytes | None = None
        self._sent_power = ""
        self._out = bytearray()
        # (µs of board time, +1 a detach window opens | -1 one closes), in order, openings first at a tie
        self._usb_events: list[tuple[int, int]] = []
        self._usb_windows_open = 0  # the phone is off the port while any detach window is open
        self.steps = 0  # harness step commands
        solve_supply(self.power, self.battery, cfg.power.ubec, self.units, self.faults, self.now)
        self._send_power()

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        self.harness.close()

    def __enter__(self) -> FirmwareBoard:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ the Board interface
    @property
    def now(self) -> float:
        """The board's time (s): how far it has run."""
        return self._t_us / 1e6

    @property
    def state(self) -> BoardState:
        """The firmware's protocol state (from its RAM, as of the last step)."""
        return BoardState(self._watched[0]) if self._watched else BoardState.BOOT

    def step(self, now: float | None = None) -> None:
        """Run the firmware up to ``now`` (s; default the clock's now): the analog inputs set from the
        battery and rail as they are, the units and the battery brought to the span's end, hangs due
        meanwhile injected at their time, then the new pulse frames, resets and state read from the
        harness's record."""
        target = round((self.clock.now() if now is None else now) * 1e6)
        while self._t_us < target:
            until = min(target, self._t_us + round(MAX_STEP_S * 1e6))
            hang_us = round(self.faults.next_hang() * 1e6) if self.faults.hangs else math.inf
            if hang_us <= until:
                until = max(int(hang_us), self._t_us)
            if self._usb_events and self._usb_events[0][0] <= until:
                until = max(self._usb_events[0][0], self._t_us)
            self._send_power()  # the battery and rail as they are now, for the span (never ahead of it)
            self._physics(until)
            self._run_to(until)
            if self.faults.hangs and round(self.faults.next_hang() * 1e6) <= self._t_us:
                self.faults.pop_hang()
                self.harness.inject_hang()
            while self._usb_events and self._usb_events[0][0] <= self._t_us:
                self._usb_window_edge(self._usb_events.pop(0)[1])

    def feed(self, data: bytes) -> None:
        """Bytes from the host arriving now (the board first catches up to now), through the link's
        faults, into UART0's receive queue."""
        self.step()
        data = self.faults.filter(data, self.now, "rx")
        for at in range(0, len(data), RX_CHUNK):  # the harness's command lines are bounded
            self.harness.command(f"rx {data[at : at + RX_CHUNK].hex()}")

    def take_output(self) -> bytes:
        """Bytes UART0 sent so far (link faults applied)."""
        if not self._out:
            return b""
        data, self._out = bytes(self._out), bytearray()
        return self.faults.filter(data, self.now, "tx")

    def next_deadline_us(self) -> float:
        """When the board next needs stepping (µs of board time): the next power period (the analog
        inputs, the UART's bytes), a frame's predicted end, a hang due."""
        due: float = self._t_us + self._poll_us - (self._t_us - self._origin_us) % self._poll_us
        due = min(due, self.next_output_change_us())
        if self.faults.hangs:
            due = min(due, max(round(self.faults.next_hang() * 1e6), self._t_us))
        if self._usb_events:
            due = min(due, max(self._usb_events[0][0], self._t_us))
        return due

    def next_deadline(self) -> float:
        return self.next_deadline_us() / 1e6

    def next_output_change_us(self) -> float:
        """The predicted end of the next pulse frame (µs of board time): the widths the drives see stay as
        they are before it, unless the MCU resets (seen at the next wake, a power period at most)."""
        last = self._last_frame_t
        if last is None:
            return self._t_us + self._poll_us
        due = round(last * 1e6) + self._frame_us + SETTLE_US
        while due <= self._t_us:
            due += self._frame_us
        return due

    def set_unit_states(
        self,
        states: Sequence[UnitState] | None,
        at: float | None = None,
        rotor_accel: Sequence[float] | None = None,
    ) -> None:
        """The world's unit states (their power draw follows them); see ``Board.set_unit_states``."""
        if at is None:
            self.step()
        stamp = self.now if at is None else at
        if states is None:
            for unit in self.units:
                unit.override(None, stamp)
            return
        if len(states) != self.config.n_units:
            raise ConfigError(
                f"{len(states)} states for {self.config.n_units} units", "FirmwareBoard.set_unit_states"
            )
        accel = (None,) * len(states) if rotor_accel is None else rotor_accel
        for unit, state, a in zip(self.units, states, accel, strict=True):
            unit.override(state, stamp, a)

    def hand_over(self, values: Sequence[float], at: float, rotor_accel: Sequence[float]) -> None:
        """The world's unit states as plain floats; see ``Board.hand_over``."""
        follow_all(self.units, values, at, rotor_accel)

    def unit_states(self) -> tuple[UnitState, ...]:
        return tuple(u.state() for u in self.units)

    def unplugged(self) -> bool:
        """Never: a cable unplug is not modelled for the firmware (refused when asked for)."""
        return False

    def reset(self) -> None:
        """Press the reset button (EXTRF) now."""
        self.step()
        self.harness.press_reset()

    # ------------------------------------------------------------------ the phone on the USB host port
    @property
    def usb(self) -> bool:
        """True when the host's link is the phone's accessory app on the USB host port (not UART0)."""
        return self.harness.options.usb

    def detach_phone(self, duration: float, at: float | None = None) -> None:
        """Pull the phone off the board's USB host port at ``at`` (s of board time; None: now) and plug it
        back ``duration`` s later, in its normal mode (the firmware enumerates it and switches it into
        accessory mode again). Meanwhile the host's writes are lost (the app's write fails) and the board
        hears nothing: its link watchdog fails it safe. Requires ``usb``.

        Windows that overlap or touch are one outage, their union: the phone stays off until the last one
        ends (before, the end of a window inside another plugged it back early). A window lasts at least
        1 µs, the board's time step: a shorter one rounded to 0 µs and, its attach sorted before its
        detach, left the phone off the port for good."""
        if not self.usb:
            raise ConfigError("needs the phone's USB link (usb)", "FirmwareBoard.detach_phone")
        if not (math.isfinite(duration) and duration > 0):
            raise ConfigError(f"{duration!r} s must be a finite time > 0", "FirmwareBoard.detach_phone")
        start = round((self.clock.now() if at is None else at) * 1e6)
        if start < self._t_us:
            raise ConfigError(f"{start / 1e6:g} s is in the board's past", "FirmwareBoard.detach_phone")
        end = start + max(1, round(duration * 1e6))
        self._usb_events += [(start, +1), (end, -1)]
        self._usb_events.sort(key=lambda event: (event[0], -event[1]))  # a window opening first at a tie

    def _usb_window_edge(self, change: int) -> None:
        """A detach window opens (``change`` +1) or closes (-1): the phone leaves the port as the first
        open window begins and comes back as the last one ends."""
        self._usb_windows_open += change
        if change > 0 and self._usb_windows_open == 1:
            self.harness.command("usb detach")
        elif change < 0 and self._usb_windows_open == 0:
            self.harness.command("usb attach")

    def usb_state(self) -> UsbState:
        """The phone as the harness sees it now (``usbstate``). Requires ``usb``."""
        if not self.usb:
            raise ConfigError("needs the phone's USB link (usb)", "FirmwareBoard.usb_state")
        return UsbState.parse(self.harness.command("usbstate"))

    # ------------------------------------------------------------------ internals
    def _run_to(self, until_us: int) -> None:
        cycles = (until_us - self._origin_us) * _CYCLES_PER_US
        words = self.harness.command(f"step {cycles}")
        self.steps += 1
        self._t_us = until_us
        if words[1] != "-":
            self._out += bytes.fromhex(words[1])
        self._read_record()

    def _read_record(self) -> None:
        """New resets, ESC supply switches, watched RAM and the newest complete frame from the record."""
        records = self.harness._records
        records.update()
        origin = self._origin_us / 1e6
        if len(records.resets) > self._seen_resets:
            for event in records.resets[self._seen_resets :]:
                self.resets.append(ResetEvent(origin + event.t, event.cause))
            self._seen_resets = len(records.resets)
            self.outputs = (None,) * self.config.n_channels  # a reset turns every output off
            self.drive_epoch += 1
        if len(records.esc_supply) > self._seen_supply:
            self._supply_on = not records.esc_supply[-1][1]
            self._seen_supply = len(records.esc_supply)
        if records.watched:
            self._watched = records.watched[-1][1]
        frame = records.newest_complete()
        if frame is None or (self._last_frame_t is not None and frame.t <= self._last_frame_t - origin):
            return
        if self.resets and frame.t < self.resets[-1].t - origin:
            return  # a frame from before the newest reset: the outputs are off since
        self._last_frame_t = origin + frame.t
        watched = self._watched_at(records.watched, frame.t)
        state = None if watched is None else watched[0]
        if watched is not None:
            self.gimbal_mode = GimbalMode(watched[3])
        self.outputs = frame.widths
        self.drive_epoch += 1
        self.timeline.record(origin + frame.t, frame.widths, state)

    @staticmethod
    def _watched_at(watched: list[tuple[float, bytes]], t: float) -> bytes | None:
        """The watched bytes as they were when a frame started at harness time ``t`` (the harness samples
        them at the rising edge, a few cycles after the edge's tick; they change rarely: search back)."""
        for seen, value in reversed(watched):
            if seen <= t + 1e-5:
                return value
        return None

    def _physics(self, t_us: int) -> None:
        """The units (their ESCs and drive flags; the world sets their states) and the battery and UBEC
        rail up to ``t_us``, under the outputs as they are."""
        dt = (t_us - self._phys_us) / 1e6
        if dt <= 0.0:
            return
        self._phys_us = t_us
        now = t_us / 1e6
        faults, outputs, v = self.faults, self.outputs, self.power.battery_v
        for i, unit in enumerate(self.units):
            g_ch, r_ch = 2 * i, 2 * i + 1
            if faults.dead_escs:
                was = unit.rotor_dead, unit.gimbal_dead
                unit.rotor_dead = faults.channel_dead(r_ch, now)
                unit.gimbal_dead = faults.channel_dead(g_ch, now)
                if (unit.rotor_dead, unit.gimbal_dead) != was:
                    self.drive_epoch += 1
            unit.step(now, dt, outputs[g_ch], outputs[r_ch], self._supply_on, v)
        self.battery.discharge(self.power.battery_a, dt)
        solve_supply(self.power, self.battery, self.config.power.ubec, self.units, faults, now)

    def _send_power(self) -> None:
        """The battery and UBEC rail onto the firmware's analog inputs (when they changed, to the mV/mA)."""
        p = self.power
        line = f"power {p.battery_v:.3f} {p.battery_a:.3f} {p.ubec_v:.3f} {p.ubec_a:.3f}"
        if line != self._sent_power:
            self.harness.command(line)
            self._sent_power = line


def firmware_board(args: argparse.Namespace, clock: Clock) -> FirmwareBoard:
    """The firmware board firmware-sim's options describe (``emu://?board=firmware&...``), its faults
    scheduled (times relative to the clock's start): with ``--usb`` the host's link is the phone's accessory
    app (a new EEPROM says link = usb), ``--usb-detach AT:DURATION`` pulls the phone off for a while. A
    cable unplug is refused: the harness has no unpowered MCU that comes back with a power-on reset."""
    from ..cli import board_config, parse_stall, schedule_faults

    if args.unplug:
        raise ConfigError("not available with the firmware board (a cable unplug is not modelled)", "unplug")
    usb = bool(getattr(args, "usb", False))
    detaches = [parse_stall(spec, "--usb-detach") for spec in getattr(args, "usb_detach", [])]
    if detaches and not usb:
        raise ConfigError("needs the phone's USB link (--usb, usb=1)", "--usb-detach")
    cfg = board_config(args)
    elf = Path(args.avr) if getattr(args, "avr", None) else FIRMWARE_ELF
    eeprom_file = Path(args.eeprom) if getattr(args, "eeprom", None) else None
    options = HarnessOptions(elf=elf, eeprom_file=eeprom_file, seed=args.seed, usb=usb)
    board = FirmwareBoard(cfg, clock, options)
    try:
        schedule_faults(board.faults, args, cfg)
        for at, duration in detaches:
            board.detach_phone(duration, at=at)
    except BaseException:
        board.close()
        raise
    return board


@dataclass(frozen=True)
class UsbState:
    """The harness's ``usbstate`` answer: the phone's mode (0 detached, 1 normal, 2 accessory), the six
    strings the board sent it on SEND_STRING (its identity: manufacturer, model, description, version, URI,
    serial), the MAX3421E model's last protocol error ("" if none) and byte counters (bytes the app wrote to
    the board, read from it, dropped while no accessory was open; SPI bytes the MCU clocked)."""

    mode: int
    strings: tuple[str, ...]
    error: str
    to_board: int
    from_board: int
    dropped: int
    spi_bytes: int

    MODES = ("detached", "normal", "accessory")

    @classmethod
    def parse(cls, words: Sequence[str]) -> UsbState:
        """From the words after ``ok``."""
        if len(words) != 12:
            raise ConfigError(f"not a usbstate answer: {' '.join(words)!r}", "usbstate")
        text = [bytes.fromhex(w).decode("utf-8", "replace") if w != "-" else "" for w in words[1:8]]
        counts = [int(w) for w in words[8:12]]
        return cls(int(words[0]), tuple(text[:6]), text[6], *counts)

    @property
    def mode_name(self) -> str:
        return self.MODES[self.mode] if 0 <= self.mode < len(self.MODES) else f"mode {self.mode}"


def board_field_address(elf: Any, field: str) -> int:
    """The data-space address of ``board.<field>`` in the firmware (the ``board`` symbol of ``elf`` plus
    the field's offset in ``board_t`` as avr-gcc lays it out with the firmware's own flags)."""
    from .harness import _symbols

    symbols = _symbols(elf)
    if "board" not in symbols:
        raise ConfigError("no 'board' symbol: not the board firmware's ELF", str(elf))
    base = symbols["board"] & 0xFFFF
    source = (
        '#include <stddef.h>\n#include "app.h"\n'
        f"const unsigned short field_offset = offsetof(board_t, {field});\n"
    )
    flags = [
        "-mmcu=atmega2560",
        "-std=gnu11",
        "-fshort-enums",
        "-funsigned-char",
        f"-I{FIRMWARE_DIR / 'include'}",
    ]
    out = subprocess.run(
        ["avr-gcc", *flags, "-S", "-o", "-", "-x", "c", "-"], input=source, capture_output=True, text=True
    )
    if out.returncode != 0:
        raise ConfigError(f"cannot lay out board_t with avr-gcc: {out.stderr.strip()}", "FirmwareBoard")
    lines = out.stdout.splitlines()
    at = lines.index("field_offset:")
    return base + int(lines[at + 1].split()[-1])
