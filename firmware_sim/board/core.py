"""The :class:`Board`: the MCU around the parts — when things run (scheduling on board time), its
phases (reset, boot, running, hung with the MCU watchdog) and the hardware that runs regardless (pulse
timers, motors, battery and UBEC, the brown-out detector).

The main loop's protocol work is :mod:`.commands`; pulse widths :mod:`.outputs`; the power manager
:mod:`.power`; dead-ESC detection :mod:`.dead_esc`; calibration transfers :mod:`.calibration`; ESC
endpoint programming :mod:`.esc_calibration`; the messages it sends :mod:`.telemetry`.
"""

from __future__ import annotations

import logging
import math
import random
from collections.abc import Sequence
from typing import Any

from hil.timing.clock import Clock
from protocol.calibration import default_unit_calibration
from protocol.errors import ConfigError
from protocol.messages import (
    BoardState,
    ControlMode,
    EscCalAbort,
    FaultFlag,
    GimbalMode,
    Heartbeat,
    PowerState,
    ResetCause,
    Severity,
    UnitState,
    WatchdogState,
)
from protocol.pulse_widths import FINE_PER_US, SigmaDelta, reported_us, whole_us

from .actuators import UnitModel, bench_truths, follow_all
from .calibration import CalibrationTransfers, calibration_or_default
from .codes import LogCode, McuPhase
from .commands import CommandHandler
from .config import BoardConfig, longest_pulse_fine
from .dead_esc import DeadEscDetector
from .esc_calibration import EscCalibration
from .faults import FaultInjector
from .hardware import step_hardware
from .link import BoardLink
from .outputs import PulseShaper, conversion_voltage, ppm_train
from .periodic import Periodic
from .power import PowerSupervisor, solve_supply
from .power_models import Battery, PowerReading
from .state import motors_enabled
from .telemetry import Outbox, fault_flags, telemetry, uptime_ms
from .timeline import PulseTimeline, ResetEvent

logger = logging.getLogger("firmware_sim.board")  # the whole board logs under one name

_NEVER = math.inf
# The phases as plain names: an enum member's lookup (``McuPhase.RUNNING``) costs about 60 ns, and the
# phase is asked several times at every board event.
_RESET, _RUNNING, _HUNG = McuPhase.RESET, McuPhase.RUNNING, McuPhase.HUNG
LINK_GRACE_US = 4_000
"""How long past the link timeout the firmware's 1 kHz tick interrupt stands back while received bytes
wait for the main loop to judge them (firmware/src/app.c: ``LINK_GRACE_MS``). A hung main loop judges
none: the host's frames pile up unread, and the link is as silent as if none came."""


class Board:
    """One emulated board. ``clock`` supplies "now" for ``feed``/``step()`` without arguments and for
    faults scheduled at ``at=None``; lockstep callers pass a ``LockstepClock`` and advance it.

    ``calibrations`` (one ``protocol.calibration.UnitCalibration`` per unit, ``None`` = not calibrated)
    defaults to ``default_unit_calibration()`` for every unit; it survives resets (EEPROM).

    ``boot_ids`` draws the board's boot id (``HelloReply.boot_id``, ``Heartbeat.boot_id``) anew at every
    boot: a nonzero u32 that differs from the last boot's. Default: a ``random.Random`` seeded from
    ``BoardConfig.seed``, so a lockstep run replays byte for byte; a board process serving a port passes
    one seeded from ``os.urandom`` (``firmware_sim.cli``): a ``firmware-sim`` killed and started again,
    or another one on a reused pty, must not announce the boot id of the board that was there."""

    def __init__(
        self,
        config: BoardConfig | None = None,
        clock: Clock | None = None,
        calibrations: Sequence[Any | None] | None = None,
        boot_ids: random.Random | None = None,
    ) -> None:
        cfg = config if config is not None else BoardConfig()
        cfg.validate()
        self.config = cfg
        if clock is None:
            from hil.timing.clock import LockstepClock

            clock = LockstepClock()
        self.clock = clock
        n = cfg.n_units
        if calibrations is None:
            calibrations = [default_unit_calibration() for _ in range(n)]
        if len(calibrations) != n:
            raise ConfigError(f"{len(calibrations)} calibrations for {n} units", "Board.calibrations")
        self.calibrations: list[Any | None] = list(calibrations)
        self.faults = FaultInjector(clock, cfg.seed, cfg.n_channels)
        self.link = BoardLink(cfg.rx_buffer_bytes, cfg.tx_buffer_bytes)
        self.timeline = PulseTimeline(cfg.timeline_frames)
        self.resets: list[ResetEvent] = []
        self.battery = Battery(cfg.power.battery)
        truths = bench_truths(cfg)
        self.units = [
            UnitModel(cfg.motor, cfg.gimbal, calibration_or_default(self.calibrations, i), truths[i], cfg.esc)
            for i in range(n)
        ]
        self._unit_channels = [(unit, 2 * i, 2 * i + 1) for i, unit in enumerate(self.units)]
        """Each unit with its gimbal and rotor channel numbers (the physics step's loop)."""
        self.power = PowerReading(soc=self.battery.soc)
        self.power.battery_v = self.battery.ocv()
        self.rx_lost_in_reset = 0
        self._boot_ids = boot_ids if boot_ids is not None else random.Random(f"boot ids {cfg.seed}")
        self._wdt_timeout_us = round(cfg.mcu_watchdog_s * 1e6)

        self._tick_us = max(1, round(cfg.tick_s * 1e6))
        self._frames = Periodic(cfg.frame_rate_hz)
        self._telemetry = Periodic(cfg.telemetry_rate_hz)
        self._heartbeat = Periodic(cfg.heartbeat_rate_hz)
        self._power_period = Periodic(1.0 / cfg.power.update_period_s)
        self._ppm = Periodic(1e6 / 22_500.0)
        t0 = self._us(clock.now())
        self._t_us = t0
        self._phys_us = t0
        self._power_period.start(t0, first_offset=True)

        # The parts, each holding its own state (``_reset`` restarts those an MCU reset clears)
        self.phase = _RESET
        self.outbox = Outbox(self.link, lambda: self.phase is _RESET)
        self.power_supervisor = PowerSupervisor(cfg.power, self.outbox)
        self.power_manager = self.power_supervisor.manager
        self.pulses = PulseShaper(cfg)
        self._longest_pulse_fine = longest_pulse_fine(cfg.frame_rate_hz)
        self.dither = SigmaDelta(cfg.n_channels)
        self.dead_esc_detector = DeadEscDetector(cfg, self.outbox)
        self.transfers = CalibrationTransfers(
            self.calibrations, self.link, self.outbox, self._store_calibration
        )
        self.esc_calibration = EscCalibration(cfg, self.outbox, self.units, on_change=self._apply_outputs)
        self.commands = CommandHandler(
            cfg,
            self.link,
            self.outbox,
            calibrations=self.calibrations,
            units=self.units,
            power=self.power_supervisor,
            transfers=self.transfers,
            esc_calibration=self.esc_calibration,
            telemetry=self._telemetry,
            resets=self.resets,
            catch_up=self._physics,
            apply_outputs=self._apply_outputs,
        )
        self.counters = self.commands.counters
        self.command = self.commands.command

        # MCU state (reset by _reset)
        self.targets: tuple[int | None, ...] = (None,) * cfg.n_channels
        """The fine widths (1/512 µs, :mod:`protocol.pulse_widths`) the firmware aims each channel at."""
        self.outputs: tuple[float | None, ...] = (None,) * cfg.n_channels
        """The widths (µs, whole 0.5 µs ticks) on the pins this frame: the targets, dithered."""
        self.drive_epoch = 0
        """Counts the changes of what the motors' drivers see: a pulse frame starts (its widths), the
        outputs go off (reset), a channel dies or revives. A world that stepped ahead under the old
        pulses steps again from where it moved (:mod:`firmware_sim.world`)."""
        self._clamped = False
        self._cut: Any = None  # the unplug (faults.unplug) that cut the power last
        self._release_us = t0
        self._wdt_us = _NEVER
        self._rx_due_us: float = _NEVER
        self._rotors_held = False  # the tick interrupt put the rotors at the safe pulse (a HUNG main loop)
        self._reset(ResetCause.POWER_ON, t0)

    # ================================================================== public API
    def feed(self, data: bytes) -> None:
        """Bytes from the host arriving now (the board first catches up to now)."""
        self.step()
        data = self.faults.filter(data, self._t_us / 1e6, "rx")
        if not data:
            return
        if self.phase is _RESET:
            self.rx_lost_in_reset += len(data)  # the UART is off while the MCU is in reset
            return
        self.link.receive(data)
        if self.phase is _RUNNING and self._rx_due_us is _NEVER:
            self._rx_due_us = -(-self._t_us // self._tick_us) * self._tick_us

    def step(self, now: float | None = None) -> None:
        """Run everything due up to ``now`` seconds (default: the clock's now), each at its own time."""
        target = round((self.clock.now() if now is None else now) * 1_000_000)  # µs, as _us()
        if target < self._t_us:
            return
        while True:
            t = self.next_deadline_us()
            if t > target:
                break
            self._wake(int(t))
        self._physics(target)
        self._t_us = target

    def tick(self) -> None:
        """``step()`` at the clock's current time."""
        self.step()

    def take_output(self) -> bytes:
        """Bytes for the host produced so far (link faults applied)."""
        data = self.link.take()
        if not data:
            return data
        return self.faults.filter(data, self._t_us / 1e6, "tx")

    def next_deadline(self) -> float:
        """Board-clock time (s) of the next wake-up; an I/O loop should call ``step`` then."""
        return self.next_deadline_us() / 1e6

    def next_deadline_us(self) -> float:
        """:meth:`next_deadline` in whole µs of board time (inf: nothing scheduled)."""
        # Asked at every board event and every world step: plain attributes (no properties), and while
        # running the earliest of nine by comparisons: 0.69 µs against 0.91 µs for min() over the same nine
        # ints and inf (CPython 3.11, timeit, best of 5; twice as fast when it was written, decfd20).
        phase = self.phase
        if phase is _RUNNING:
            due = self._power_period.next_us
            if (t := self._frames.next_us) < due:
                due = t
            if (t := self._rx_due_us) < due:
                due = t
            if (t := self._telemetry.next_us) < due:
                due = t
            if (t := self._heartbeat.next_us) < due:
                due = t
            if (t := self._ppm.next_us) < due:
                due = t
            if (t := self.commands.link_deadline_us) < due:
                due = t
            if (t := self.transfers.next_retry_us) < due:
                due = t
            if (t := self.esc_calibration.deadline_us) < due:
                due = t
            if self.faults.hangs:
                due = min(due, max(self._us(self.faults.next_hang()), self._t_us))  # late: now
            if self.faults.unplugs:
                due = min(due, self._next_unplug_us())
            return due
        if phase is _HUNG:  # the timers (pulse frames, PPM train) and the tick interrupt keep running
            due = min(
                self._power_period.next_us,
                self._frames.next_us,
                self._wdt_us,
                self._ppm.next_us,
                self._tick_stop_us(),
            )
            if self.faults.unplugs:
                due = min(due, self._next_unplug_us())
            return due
        due = min(self._power_period.next_us, self._frames.next_us)
        if self._release_us > self._phys_us:  # RESET
            due = min(due, self._release_us)
        return due

    def _next_unplug_us(self) -> float:
        """The next unplug's start (µs of board time): now if one is on that has not cut the power yet,
        else the first one to start after now."""
        t = self._t_us / 1e6
        on = self.faults.unplugged(t)
        if on is not None and on is not self._cut:
            return self._t_us
        start = self.faults.next_unplug(t if on is None else on.start + on.duration)
        return start if math.isinf(start) else max(self._us(start), self._t_us + 1)

    def unplugged(self) -> bool:
        """Whether the board's cable is out now (the in-process port then vanishes: the transport asks)."""
        return bool(self.faults.unplugs) and self.faults.unplugged(self._t_us / 1e6) is not None

    def next_output_change_us(self) -> float:
        """Board time (µs) before which the pulses on the pins stay as they are unless the MCU resets, a
        channel dies or the gimbal mode changes (all of which move :attr:`drive_epoch`): the next pulse
        frame, or while the MCU is held in reset its release (inf: none scheduled)."""
        due = self._frames.next_us
        if self.phase is _RESET:
            due = min(due, max(self._release_us, self._t_us))
        return due

    @property
    def now(self) -> float:
        """The board's time (s): how far ``step`` has run."""
        return self._t_us / 1e6

    @property
    def state(self) -> BoardState:
        """The protocol state (BOOT, DISARMED, ARMED, FAILSAFE)."""
        return self.commands.state

    @property
    def mode(self) -> ControlMode:
        """The control mode (ESC_CALIBRATION while the ESC endpoint procedure runs)."""
        return self.commands.reported_mode

    @property
    def reset_cause(self) -> ResetCause:
        """Why the MCU last reset."""
        return self.resets[-1].cause

    @property
    def power_state(self) -> PowerState:
        """The power manager's stage."""
        return self.power_supervisor.state

    @property
    def last_rx(self) -> float | None:
        """Board time (s) the main loop last handled a valid frame from the host (None: not since reset)."""
        last = self.commands.last_rx_us
        return None if last is None else last / 1e6

    def uptime_ms(self) -> int:
        return uptime_ms(self._t_us, self.resets[-1])

    def set_unit_states(
        self,
        states: Sequence[UnitState] | None,
        at: float | None = None,
        rotor_accel: Sequence[float] | None = None,
    ) -> None:
        """Closed-loop hook: the world's measured unit states (one per unit) replace the internal motor
        model from now on (for telemetry, power draw, dead-ESC detection, gimbal hold); ``None`` hands
        the units back to the internal model. ``at``: the board time (s) the states were measured at, for
        a world that steps in batches up to the board's next event and hands them over without moving
        the board (its next ``step`` uses them); default: the board first catches up to its clock's now.
        ``rotor_accel`` (rad/s², per unit, for the power draw): default, the speed change since the last."""
        if at is None:
            self.step()
        if states is not None and len(states) != self.config.n_units:
            raise ConfigError(
                f"{len(states)} states for {self.config.n_units} units", "Board.set_unit_states"
            )
        stamp = self._t_us / 1e6 if at is None else at
        if states is None:
            for unit in self.units:
                unit.override(None, stamp)
        else:
            accel = (None,) * len(states) if rotor_accel is None else rotor_accel
            for unit, state, a in zip(self.units, states, accel, strict=True):
                unit.override(state, stamp, a)

    def hand_over(self, values: Sequence[float], at: float, rotor_accel: Sequence[float]) -> None:
        """:meth:`set_unit_states` for a world that steps in batches, with the states as plain floats:
        ``values`` the units' gimbal angles (rad, in (−π, π]), gimbal rates (rad/s) and rotor speeds
        (rad/s), n of each one after the other, measured at board time ``at`` (s); ``rotor_accel``
        (rad/s², n). The board does not move; no :class:`UnitState` is built (telemetry builds its own)."""
        follow_all(self.units, values, at, rotor_accel)

    def commanded_outputs(self) -> tuple[float | None, ...]:
        """The mean widths (µs, to 1/512 µs) the firmware would aim the next pulse frames at for its present
        state, command and power stage (``outputs`` is what the last frame carried)."""
        return tuple(None if q is None else q / FINE_PER_US for q in self._compute_outputs()[0])

    def reported_outputs(self) -> tuple[int | None, ...]:
        """The targets in whole µs, as ``Telemetry.pulses_us`` reports them."""
        return tuple(None if q is None else reported_us(q) for q in self.targets)

    @property
    def gimbal_mode(self) -> GimbalMode:
        """How the gimbal pulses are meant now: a rate or an angle (the last setpoint's mode)."""
        return self.command.gimbal_mode

    def unit_states(self) -> tuple[UnitState, ...]:
        return tuple(u.state() for u in self.units)

    def reset(self, cause: ResetCause = ResetCause.EXTERNAL) -> None:
        """Press the reset button (or power-cycle with ``ResetCause.POWER_ON``)."""
        self.step()
        self._reset(cause, self._t_us)

    @property
    def watchdog_state(self) -> WatchdogState:
        return self.commands.watchdog_state

    def fault_flags(self) -> FaultFlag:
        return fault_flags(
            link_lost=self.commands.link_lost,
            dead_esc=bool(self.dead_esc_detector.found),
            power_state=self.power_state,
            ubec_overcurrent=self.power_supervisor.ubec_over,
            calibration_missing=any(c is None for c in self.calibrations),
            reset_cause=self.reset_cause,
            clamped=self._clamped,
        )

    # ================================================================== scheduling
    @staticmethod
    def _us(t: float) -> int:
        return round(t * 1_000_000)

    def _wake(self, t: int) -> None:
        self._t_us = t
        if self.faults.unplugs:
            self._power_cut(t)
        if (
            t >= self._power_period.due_us
            or self._frames.is_due(t)
            or self.phase is not _RUNNING
            or self._telemetry.is_due(t)
        ):
            self._physics(t)  # a wake that only handles received bytes needs no physics
        if self._power_period.is_due(t):
            self._power_period.advance(t)
            self._power_hardware(t)
        if self.phase is _RUNNING and self.faults.hangs and self._us(self.faults.next_hang()) <= t:
            self.faults.pop_hang()  # one due in reset or boot waits for the main loop to run
            self.phase = _HUNG
            self._wdt_us = t + self._wdt_timeout_us
            logger.info("MCU hung at %.6f s; watchdog fires at %.6f s", t / 1e6, self._wdt_us / 1e6)
        if self.phase is _RESET:
            if t >= self._release_us and self.power_supervisor.released(self.power):
                self._boot(t)
        elif self.phase is _HUNG:
            if t >= self._wdt_us:
                self._reset(ResetCause.WATCHDOG, t)
            elif t >= self._tick_stop_us():
                self._hold_rotors(t)
        if self.phase is _RUNNING:
            self._main_loop(t)
        if self._frames.is_due(t):
            self._frames.advance(t)
            self._pulse_frame(t)
        if self._ppm.is_due(t):
            self._ppm.advance(t)
            self.timeline.ppm.append(ppm_train(t, self.targets, self.config.rotor_safe_us))

    # ================================================================== reset, boot, main loop
    def _power_cut(self, t: int) -> None:
        """The cable is out at ``t`` (``faults.unplug``): the MCU loses power — held in reset, its reset
        cause POWER_ON — until the cable is back and it has booted."""
        cut = self.faults.unplugged(t / 1e6)
        if cut is None or cut is self._cut:
            return
        self._cut = cut
        self._reset(ResetCause.POWER_ON, t)
        back_us = self._us(cut.start + cut.duration) + self._us(self.config.boot_time_s)
        self._release_us = max(self._release_us, back_us)
        self.resets[-1] = ResetEvent(
            cut.start + cut.duration, ResetCause.POWER_ON
        )  # its uptime from power-up

    def _reset(self, cause: ResetCause, t: int) -> None:
        if self.resets:
            logger.info("board reset at %.6f s: %s", t / 1e6, cause.name)
        self.resets.append(ResetEvent(t / 1e6, cause))
        self.phase = _RESET
        self._release_us = t + self._us(self.config.boot_time_s)
        self._wdt_us = _NEVER
        self._rx_due_us = _NEVER
        self._rotors_held = False
        self._clamped = False
        self.commands.reset()
        self.commands.boot_id = self._next_boot_id(self.commands.boot_id)
        self.dead_esc_detector.reset()
        self.transfers.reset()
        self.esc_calibration.reset()
        self.link.reset()
        self.power_supervisor.reset()
        self.targets = self.outputs = (None,) * self.config.n_channels
        self.drive_epoch += 1
        self.dither.reset()
        for s in (self._frames, self._telemetry, self._heartbeat, self._ppm):
            s.stop()

    def _tick_stop_us(self) -> float:
        """When the tick interrupt stops the rotors of a HUNG main loop (µs; inf: it will not): at the link
        timeout, plus :data:`LINK_GRACE_US` while received bytes wait, if ARMED in a session whose link
        is not lost yet (firmware/src/app.c: ``app_tick``). The main loop that would have judged the link
        lost and gone to FAILSAFE is stuck; without this the rotors ran on at their last width until the
        MCU watchdog's reset (up to 8 s), where docs/protocol.md puts them at the safe pulse within the
        link timeout plus one frame."""
        commands = self.commands
        if self._rotors_held or not motors_enabled(commands.state):
            return _NEVER
        return commands.link_deadline_us + (LINK_GRACE_US if self.link.rx_pending else 0)

    def _hold_rotors(self, t: int) -> None:
        """The tick interrupt's stop (``pulses_hold``): every rotor channel to the safe pulse from the next
        frame on, the gimbals left as they are, until the watchdog's reset."""
        safe = whole_us(self.config.rotor_safe_us)
        self.targets = tuple(safe if ch % 2 else w for ch, w in enumerate(self.targets))
        self._rotors_held = True
        logger.info("link lost at %.6f s in a hung main loop: rotors held at the safe pulse", t / 1e6)

    def _next_boot_id(self, last: int) -> int:
        """The boot id of the boot this reset leads to: nonzero (0 says "no boot id"), never the last's."""
        while True:
            boot_id = self._boot_ids.getrandbits(32)
            if boot_id not in (0, last):
                return boot_id

    @property
    def boot_id(self) -> int:
        """The id of the board's current boot (drawn at its reset; ``HelloReply.boot_id``)."""
        return self.commands.boot_id

    def _boot(self, t: int) -> None:
        self.phase = _RUNNING
        self._frames.start(t)
        self._heartbeat.start(t)
        if self.config.ppm:
            self._ppm.start(t)
        self.power_supervisor.update(self.power, 0.0, motors_enabled(self.state))
        self.targets, self._clamped = self._compute_outputs()  # on the pins from the first frame (now)
        self.outbox.log(Severity.INFO, LogCode.BOOT, f"boot: reset cause {self.reset_cause.name}")

    def _main_loop(self, t: int) -> None:
        if self._rx_due_us <= t:
            self._rx_due_us = _NEVER
            self.commands.receive(t)
        self.commands.check_link(t)
        self.esc_calibration.poll(t)
        if self._telemetry.is_due(t):
            self._telemetry.advance(t)
            self._send_telemetry(t)
            self.esc_calibration.report(t)
        if self._heartbeat.is_due(t):
            self._heartbeat.advance(t)
            self.outbox.send(
                Heartbeat(
                    time_ms=uptime_ms(t, self.resets[-1]),
                    state=int(self.state),
                    boot_id=self.commands.boot_id,
                )
            )
        self.transfers.retry_due(t)

    # ================================================================== outputs
    def _compute_outputs(self) -> tuple[tuple[int | None, ...], bool]:
        """(fine widths, clamped): the firmware's pulse widths for the present state, command and power
        stage."""
        pm = self.power_manager
        widths, clamped = self.pulses.widths(
            self.calibrations,
            self.command,
            armed=motors_enabled(self.state),
            raw_mode=self.commands.mode is ControlMode.RAW_PULSES,
            shed=self.power_supervisor.shedding,
            limit=self.power_state is PowerState.LIMIT,
            battery_v=conversion_voltage(pm.filtered_v_cell, pm.cells, self.power.battery_v),
        )
        esc = self.esc_calibration.rotor_width()
        if esc is not None:
            channel, width = esc
            widths = widths[:channel] + (whole_us(width),) + widths[channel + 1 :]
        # no width past the frame's end (the firmware's compute_outputs): at 490 Hz a 2500 µs pulse held
        # the pin high for good, while this board reported 2500 µs pulses
        longest = self._longest_pulse_fine
        if any(w is not None and w > longest for w in widths):
            widths = tuple(None if w is None else min(w, longest) for w in widths)
            clamped = True
        return widths, clamped

    def _apply_outputs(self) -> None:
        """The main loop aims the outputs at once (the firmware's ``apply_outputs``): ``targets`` — what
        telemetry reports and the next frame dithers — follow the present state, command and power stage.
        Called when the board leaves ARMED and at every phase of an ESC calibration (its start, steps, end
        or abort); ``outputs`` (the pins) change only at the next frame start."""
        self.targets, self._clamped = self._compute_outputs()

    def _pulse_frame(self, t: int) -> None:
        """A frame starts: the main loop's targets (RUNNING), dithered into this frame's widths by the
        frame-start interrupt — which runs on in a HUNG main loop, so the last targets go on (but
        for the rotors the tick interrupt stops at the link timeout: :meth:`_hold_rotors`)."""
        if self.phase is _RUNNING:
            self._apply_outputs()
        self.outputs = self.dither.frame(self.targets)
        self.drive_epoch += 1
        self.timeline.record(t / 1e6, self.outputs, int(self.commands.state))

    def _store_calibration(self, unit: int, cal: Any) -> None:
        """An uploaded calibration into EEPROM: the unit's model and the pulse conversions use it now."""
        self.calibrations[unit] = cal
        self.units[unit].calibration = cal
        self.pulses.clear_cache()
        self.dead_esc_detector.forget()

    # ================================================================== hardware
    def _physics(self, t: int) -> None:
        """Advance motors, battery and UBEC from the last physics time to ``t`` (hardware: always runs):
        :func:`.hardware.step_hardware`, the fused form of :meth:`_physics_reference`."""
        dt = (t - self._phys_us) / 1e6
        if dt <= 0.0:
            return
        self._phys_us = t
        now = t / 1e6
        if self.faults.dead_escs:
            self._mark_dead(now)
        step_hardware(
            self._unit_channels,
            self.outputs,
            now,
            dt,
            not self.esc_calibration.supply_cut,
            self.power,
            self.battery,
            self.config.power.ubec,
            self.faults,
        )

    def _mark_dead(self, now: float) -> None:
        """The channels dead at ``now`` (s) as the units' ``rotor_dead``/``gimbal_dead``; a change moves
        :attr:`drive_epoch`."""
        for unit, g_ch, r_ch in self._unit_channels:
            was = unit.rotor_dead, unit.gimbal_dead
            unit.rotor_dead = self.faults.channel_dead(r_ch, now)
            unit.gimbal_dead = self.faults.channel_dead(g_ch, now)
            if (unit.rotor_dead, unit.gimbal_dead) != was:
                self.drive_epoch += 1

    def _physics_reference(self, t: int) -> None:
        """:meth:`_physics` as the separate calls it fuses (each unit's step, the battery's discharge, the
        supply's solve): the tests' oracle (``tests/test_board_hardware.py``)."""
        dt = (t - self._phys_us) / 1e6
        if dt <= 0.0:
            return
        self._phys_us = t
        now = t / 1e6
        outputs = self.outputs
        v = self.power.battery_v
        dead = self.faults.dead_escs
        supply_on = not self.esc_calibration.supply_cut
        for unit, g_ch, r_ch in self._unit_channels:
            if dead:
                was = unit.rotor_dead, unit.gimbal_dead
                unit.rotor_dead = self.faults.channel_dead(r_ch, now)
                unit.gimbal_dead = self.faults.channel_dead(g_ch, now)
                if (unit.rotor_dead, unit.gimbal_dead) != was:
                    self.drive_epoch += 1
            unit.step(now, dt, outputs[g_ch], outputs[r_ch], supply_on, v)
        self.battery.discharge(self.power.battery_a, dt)
        solve_supply(self.power, self.battery, self.config.power.ubec, self.units, self.faults, now)

    def _power_hardware(self, t: int) -> None:
        """Brown-out detector (hardware) and, when the main loop runs, the firmware's power manager."""
        if self.phase is not _RESET and self.power_supervisor.browned_out(self.power):
            self._reset(ResetCause.BROWN_OUT, t)
            return
        if self.phase is _RUNNING:
            self.power_supervisor.update(
                self.power, self.config.power.update_period_s, motors_enabled(self.state)
            )
            if not self.power_supervisor.power_ok:
                self.esc_calibration.abort(EscCalAbort.POWER, t)
            taught = self.esc_calibration.rotor_width()
            self.dead_esc_detector.check(
                t,
                self.targets,
                self.units,
                self.power.battery_v,
                self.gimbal_mode,
                being_taught=None if taught is None else taught[0],
            )

    # ================================================================== messages out
    def _send_telemetry(self, t: int) -> None:
        """``Telemetry`` now (``mode`` is ESC_CALIBRATION while that procedure runs)."""
        last_rx = self.commands.last_rx_us
        self.outbox.send(
            telemetry(
                time_ms=uptime_ms(t, self.resets[-1]),
                state=self.state,
                mode=self.mode,
                watchdog=self.watchdog_state,
                power_state=self.power_state,
                faults=self.fault_flags(),
                link_age_us=None if last_rx is None else t - last_rx,
                power=self.power,
                counters=self.link.deframer.counters,
                outputs=self.reported_outputs(),
                units=self.unit_states(),
            )
        )
