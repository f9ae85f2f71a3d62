"""The emulated ADK board as a sans-IO core: bytes in (``feed``), time passes (``step``), bytes out
(``take_output``). The same object runs behind a pseudo-terminal (:mod:`firmware_sim.pty_server`),
in-process in lockstep, or under fault injection.

Time. The board keeps its own time in integer microseconds on the injected clock's time base and
wakes only when something is due: a main-loop tick with received bytes, a pulse frame, the power
manager's sample, telemetry, a heartbeat, a watchdog deadline. ``step(now)`` runs every wake-up with a
time ≤ ``now`` *at its own scheduled time*, so a late caller (a busy host, a lockstep driver taking big
steps) changes nothing the board does, only when the bytes leave. Everything the board reports —
``Telemetry.time_ms``, the pulse timeline, the reset log — is on this board time, which is what
timing tests measure.

Parts (each a small module): :mod:`.state` (state machine), :mod:`.link` (UART ring, framing,
duplicate filter), :mod:`.power` (battery, UBEC, staged thresholds), :mod:`.actuators` (ESC/motor and
gimbal response), :mod:`.timeline` (pulse frames, resets), :mod:`.faults` (fault injection).

Board time vs. uptime. ``Telemetry.time_ms`` and board ``Heartbeat.time_ms`` are the MCU's uptime:
milliseconds since its last reset (like ``millis()``); :attr:`Board.resets` records each reset on the
board clock, so ``uptime = t − resets[-1].t``.
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Sequence
from typing import Any

from hil.timing.clock import Clock
from protocol.calibration import Reassembler, default_unit_calibration, fragment
from protocol.errors import ConfigError, HilError
from protocol.frame import BadFrame, Frame
from protocol.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    CalibrationData,
    CalibrationRequest,
    ControlMode,
    Disarm,
    FaultFlag,
    Flags,
    GimbalMode,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    Nack,
    NackReason,
    PowerState,
    RawPulses,
    ResetCause,
    SetMode,
    Severity,
    Telemetry,
    UnitState,
    WatchdogState,
)

from .actuators import UnitModel
from .config import BoardConfig
from .faults import FaultInjector
from .link import BoardLink
from .periodic import Periodic
from .power import Battery, PowerManager, PowerReading, ubec_input_power, ubec_output
from .state import Event, motors_enabled, transition
from .timeline import PpmTrain, PulseTimeline, ResetEvent

logger = logging.getLogger(__name__)

_NEVER = math.inf
_U16 = 0xFFFF
_CAL_RETRY_S = 0.1
_CAL_TRIES = 5
_VOLT_QUANTUM = 0.01  # V: pulse conversions are cached per 10 mV of battery voltage


class McuPhase(enum.Enum):
    """What the microcontroller is doing (independent of the protocol's BoardState)."""

    RESET = "reset"  # held in reset or booting: no main loop, no pulses
    RUNNING = "running"
    HUNG = "hung"  # main loop stuck: pulse timers keep their last widths, the MCU watchdog runs


class LogCode(enum.IntEnum):
    """``Log.code`` values this board sends."""

    BOOT = 1
    STATE = 2
    LINK_LOST = 3
    LINK_RESTORED = 4
    POWER = 5
    DEAD_ESC = 6
    UBEC_OVERCURRENT = 7
    HANDSHAKE = 8
    BAD_COMMAND = 9
    CALIBRATION = 10
    RX_OVERFLOW = 11


class Board:
    """One emulated board. ``clock`` supplies "now" for ``feed``/``step()`` without arguments and for
    faults scheduled at ``at=None``; lockstep callers pass a ``LockstepClock`` and advance it.

    ``calibrations`` (one ``protocol.calibration.UnitCalibration`` per unit, ``None`` = not calibrated)
    defaults to ``default_unit_calibration()`` for every unit; it survives resets (EEPROM)."""

    def __init__(
        self,
        config: BoardConfig | None = None,
        clock: Clock | None = None,
        calibrations: Sequence[Any | None] | None = None,
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
        self.power_manager = PowerManager(cfg.power.thresholds, cfg.power.battery.cells)
        self.units = [UnitModel(cfg.motor, cfg.gimbal, self._cal_or_default(i)) for i in range(n)]
        self.power = PowerReading(soc=self.battery.soc)
        self.power.battery_v = self.battery.ocv()
        self.counters = {"setpoints": 0, "bad_setpoints": 0, "ignored_setpoints": 0}
        self.rx_lost_in_reset = 0
        self._timeout_us = round(cfg.link_timeout_s * 1e6)
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

        # MCU state (reset by _reset)
        self.phase = McuPhase.RESET
        self.state = BoardState.BOOT
        self.mode = ControlMode.SETPOINT
        self.reset_cause = ResetCause.POWER_ON
        self.power_state = PowerState.NORMAL
        self.outputs: tuple[int | None, ...] = (None,) * cfg.n_channels
        self._release_us = t0
        self._wdt_us = _NEVER
        self._rx_due_us: float = _NEVER
        self._last_rx_us: int | None = None
        self._link_lost = False
        self._session = False
        self._gimbal_mode = GimbalMode.RATE
        self._gimbal_cmd = [0.0] * n
        self._rotor_cmd = [0.0] * n
        self._raw_cmd: tuple[int, ...] | None = None
        self._shed_latched = False
        self._clamped = False
        self._ubec_over = False
        self._dead_since: list[float | None] = [None] * cfg.n_channels
        self._dead_found: set[int] = set()
        self._reassembler = Reassembler()
        self._cal_out: dict[int, list[Any]] = {}  # seq -> [message, tries, next_retry_us]
        self._conv_cache: dict[tuple[Any, ...], Any] = {}
        self._reset(ResetCause.POWER_ON, t0)

    # ================================================================== public API
    def feed(self, data: bytes) -> None:
        """Bytes from the host arriving now (the board first catches up to now)."""
        self.step()
        data = self.faults.filter(data, self._t_us / 1e6, "rx")
        if not data:
            return
        if self.phase is McuPhase.RESET:
            self.rx_lost_in_reset += len(data)  # the UART is off while the MCU is in reset
            return
        self.link.receive(data)
        if self.phase is McuPhase.RUNNING and self._rx_due_us is _NEVER:
            self._rx_due_us = -(-self._t_us // self._tick_us) * self._tick_us

    def step(self, now: float | None = None) -> None:
        """Run everything due up to ``now`` seconds (default: the clock's now), each at its own time."""
        target = self._us(self.clock.now() if now is None else now)
        if target < self._t_us:
            return
        while True:
            t = self._next_due_us()
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
        return self._next_due_us() / 1e6

    @property
    def now(self) -> float:
        """The board's time (s): how far ``step`` has run."""
        return self._t_us / 1e6

    @property
    def last_rx(self) -> float | None:
        """Board time (s) the main loop last handled a valid frame from the host (None: not since reset)."""
        return None if self._last_rx_us is None else self._last_rx_us / 1e6

    def uptime_ms(self) -> int:
        return ((self._t_us - self._us(self.resets[-1].t)) // 1000) & 0xFFFFFFFF

    def set_unit_states(self, states: Sequence[UnitState] | None) -> None:
        """Closed-loop hook: the world's measured unit states (one per unit) replace the internal motor
        model from now on (for telemetry, power draw, dead-ESC detection, gimbal hold); ``None`` hands
        the units back to the internal model."""
        self.step()
        if states is not None and len(states) != self.config.n_units:
            raise ConfigError(
                f"{len(states)} states for {self.config.n_units} units", "Board.set_unit_states"
            )
        for i, unit in enumerate(self.units):
            unit.override(None if states is None else states[i], self._t_us / 1e6)

    def commanded_outputs(self) -> tuple[int | None, ...]:
        """The widths (µs) the firmware would put on the next pulse frame for its present state, command
        and power stage (``outputs`` is what the last frame carried)."""
        clamped = self._clamped
        try:
            return self._compute_outputs()
        finally:
            self._clamped = clamped

    @property
    def gimbal_mode(self) -> GimbalMode:
        """How the gimbal pulses are meant now: a rate or an angle (the last setpoint's mode)."""
        return self._gimbal_mode

    def unit_states(self) -> tuple[UnitState, ...]:
        return tuple(u.state() for u in self.units)

    def reset(self, cause: ResetCause = ResetCause.EXTERNAL) -> None:
        """Press the reset button (or power-cycle with ``ResetCause.POWER_ON``)."""
        self.step()
        self._reset(cause, self._t_us)

    @property
    def watchdog_state(self) -> WatchdogState:
        return WatchdogState.LINK_LOST if self._link_lost else WatchdogState.OK

    def fault_flags(self) -> FaultFlag:
        f = FaultFlag.NONE
        if self._link_lost:
            f |= FaultFlag.LINK_LOST
        if self._dead_found:
            f |= FaultFlag.DEAD_ESC
        if self.power_state >= PowerState.WARN:
            f |= FaultFlag.BATTERY_LOW
        if self._ubec_over:
            f |= FaultFlag.UBEC_OVERCURRENT
        if any(c is None for c in self.calibrations):
            f |= FaultFlag.CALIBRATION_MISSING
        if self.reset_cause is ResetCause.WATCHDOG:
            f |= FaultFlag.MCU_WATCHDOG_RESET
        if self.reset_cause is ResetCause.BROWN_OUT:
            f |= FaultFlag.BROWN_OUT_RESET
        if self._clamped:
            f |= FaultFlag.SETPOINT_CLAMPED
        return f

    # ================================================================== scheduling
    @staticmethod
    def _us(t: float) -> int:
        return round(t * 1_000_000)

    def _next_due_us(self) -> float:
        due = min(self._power_period.next_us, self._frames.next_us)
        phase = self.phase
        if phase is McuPhase.RESET:
            if self._release_us > self._phys_us:
                due = min(due, self._release_us)
            return due
        if phase is McuPhase.HUNG:  # the timers (pulse frames, PPM train) keep running: hardware
            return min(due, self._wdt_us, self._ppm.next_us)
        due = min(
            due,
            self._rx_due_us,
            self._telemetry.next_us,
            self._heartbeat.next_us,
            self._ppm.next_us,
            max(self._us(self.faults.next_hang()), self._t_us) if self.faults.hangs else _NEVER,  # late: now
        )
        if self._session and not self._link_lost and self._last_rx_us is not None:
            due = min(due, self._last_rx_us + self._timeout_us)
        for entry in self._cal_out.values():
            due = min(due, entry[2])
        return due

    def _wake(self, t: int) -> None:
        self._t_us = t
        if (
            t >= self._power_period.due_us
            or self._frames.is_due(t)
            or self.phase is not McuPhase.RUNNING
            or self._telemetry.is_due(t)
        ):
            self._physics(t)  # a wake that only handles received bytes needs no physics
        if self._power_period.is_due(t):
            self._power_period.advance(t)
            self._power_hardware(t)
        if self.phase is McuPhase.RUNNING and self.faults.hangs and self._us(self.faults.next_hang()) <= t:
            self.faults.pop_hang()  # one due in reset or boot waits for the main loop to run
            self.phase = McuPhase.HUNG
            self._wdt_us = t + self._wdt_timeout_us
            logger.info("MCU hung at %.6f s; watchdog fires at %.6f s", t / 1e6, self._wdt_us / 1e6)
        if self.phase is McuPhase.RESET:
            if t >= self._release_us and self.power_manager.released(self.power.ubec_v):
                self._boot(t)
        elif self.phase is McuPhase.HUNG:
            if t >= self._wdt_us:
                self._reset(ResetCause.WATCHDOG, t)
        if self.phase is McuPhase.RUNNING:
            self._main_loop(t)
        if self._frames.is_due(t):
            self._frames.advance(t)
            self._pulse_frame(t)
        if self._ppm.is_due(t):
            self._ppm.advance(t)
            self._ppm_frame(t)

    # ================================================================== reset and boot
    def _reset(self, cause: ResetCause, t: int) -> None:
        if self.resets:
            logger.info("board reset at %.6f s: %s", t / 1e6, cause.name)
        self.resets.append(ResetEvent(t / 1e6, cause))
        self.phase = McuPhase.RESET
        self.reset_cause = cause
        self.state = transition(self.state, Event.RESET).state
        self.mode = ControlMode.SETPOINT
        self._release_us = t + self._us(self.config.boot_time_s)
        self._wdt_us = _NEVER
        self._rx_due_us = _NEVER
        self._last_rx_us = None
        self._link_lost = False
        self._session = False
        self._shed_latched = False
        self._clamped = False
        self._raw_cmd = None
        self._gimbal_mode = GimbalMode.RATE
        self._gimbal_cmd = [0.0] * self.config.n_units
        self._rotor_cmd = [0.0] * self.config.n_units
        self._dead_since = [None] * self.config.n_channels
        self._dead_found.clear()
        self._reassembler = Reassembler()
        self._cal_out.clear()
        self.link.reset()
        self.power_manager.reset()
        self.power_state = PowerState.NORMAL
        self.outputs = (None,) * self.config.n_channels
        for s in (self._frames, self._telemetry, self._heartbeat, self._ppm):
            s.stop()

    def _boot(self, t: int) -> None:
        self.phase = McuPhase.RUNNING
        self._frames.start(t)
        self._heartbeat.start(t)
        if self.config.ppm:
            self._ppm.start(t)
        self._power_manager_step(t, 0.0)
        self.outputs = self._compute_outputs()
        self._log(Severity.INFO, LogCode.BOOT, f"boot: reset cause {self.reset_cause.name}")

    # ================================================================== main loop
    def _main_loop(self, t: int) -> None:
        if self._rx_due_us <= t:
            self._rx_due_us = _NEVER
            self._process_rx(t)
        if (
            self._session
            and not self._link_lost
            and self._last_rx_us is not None
            and t >= self._last_rx_us + self._timeout_us
        ):
            self._on_link_lost(t)
        if self._telemetry.is_due(t):
            self._telemetry.advance(t)
            self._send_telemetry(t)
        if self._heartbeat.is_due(t):
            self._heartbeat.advance(t)
            self._send(Heartbeat(time_ms=self._uptime_ms(t), state=int(self.state)))
        for seq, entry in list(self._cal_out.items()):
            if entry[2] <= t:
                self._retry_calibration(seq, entry, t)

    def _process_rx(self, t: int) -> None:
        before = self.link.stats.rx_overflow
        for event in self.link.drain():
            if isinstance(event, BadFrame):
                continue
            self._handle_frame(event, t)
        if self.link.stats.rx_overflow != before:
            self._log(
                Severity.WARNING,
                LogCode.RX_OVERFLOW,
                f"receive buffer overflow ({self.link.stats.rx_overflow} bytes lost)",
            )

    def _handle_frame(self, frame: Frame, t: int) -> None:
        msg = frame.message
        wants_answer = bool(frame.flags & Flags.ACK_REQUESTED) or type(msg).RELIABLE
        if isinstance(msg, (HelloReply, Telemetry, Log)):
            self.link.stats.ignored += 1  # board-to-host messages echoed back: not ours
            return
        self._on_valid_rx(t)
        if wants_answer:
            cached = self.link.cached_answer(frame)
            if cached is not None:
                self._send(cached)
                return
        refused = self._execute(msg, frame, t)
        if wants_answer:
            answer: Ack | Nack
            if refused is None:
                answer = Ack(msg_id=frame.msg_id, seq=frame.seq)
            else:
                answer = Nack(msg_id=frame.msg_id, seq=frame.seq, reason=refused)
            self.link.remember_answer(frame, answer)
            self._send(answer)

    def _execute(self, msg: Any, frame: Frame, t: int) -> NackReason | None:
        """Run one command; returns None (accepted) or the NACK reason."""
        if isinstance(msg, ActuatorSetpoint):
            self._on_setpoint(msg)
        elif isinstance(msg, RawPulses):
            self._on_raw_pulses(msg)
        elif isinstance(msg, Heartbeat):
            pass
        elif isinstance(msg, Hello):
            self._on_hello(msg, t)
        elif isinstance(msg, Arm):
            return self._on_arm()
        elif isinstance(msg, Disarm):
            return self._apply(Event.DISARM)
        elif isinstance(msg, SetMode):
            return self._on_set_mode(msg)
        elif isinstance(msg, CalibrationData):
            return self._on_calibration_data(msg)
        elif isinstance(msg, CalibrationRequest):
            return self._on_calibration_request(msg, t)
        elif isinstance(msg, (Ack, Nack)):
            self._on_answer(msg)
        return None

    def _on_valid_rx(self, t: int) -> None:
        self._last_rx_us = t
        if self._link_lost:
            self._link_lost = False
            self._log(Severity.INFO, LogCode.LINK_RESTORED, "link restored")

    def _on_link_lost(self, t: int) -> None:
        self._link_lost = True
        self._log(
            Severity.WARNING,
            LogCode.LINK_LOST,
            f"link lost: nothing valid for {self.config.link_timeout_s * 1000:.0f} ms",
        )
        self._apply(Event.LINK_LOST)

    # ------------------------------------------------------------------ state changes
    def _apply(self, event: Event) -> NackReason | None:
        tr = transition(self.state, event, power_ok=self._power_ok())
        if tr.accepted:
            self._set_state(tr.state)
        return tr.refused

    def _set_state(self, new: BoardState) -> None:
        old = self.state
        if new is old:
            return
        self.state = new
        if not motors_enabled(new):
            self._hold_gimbals()
            self._rotor_cmd = [0.0] * self.config.n_units
            self._raw_cmd = None
        self._log(
            Severity.WARNING if new is BoardState.FAILSAFE else Severity.INFO,
            LogCode.STATE,
            f"state {old.name} -> {new.name}",
        )
        self._send(Heartbeat(time_ms=self._uptime_ms(self._t_us), state=int(new)))

    def _hold_gimbals(self) -> None:
        """Gimbals hold: zero rate in RATE mode, the present angle in ANGLE mode."""
        if self._gimbal_mode is GimbalMode.RATE:
            self._gimbal_cmd = [0.0] * self.config.n_units
        else:
            self._physics(self._t_us)
            self._gimbal_cmd = [u.gimbal_angle for u in self.units]

    def _power_ok(self) -> bool:
        return self.power_state < PowerState.SHED

    def _on_hello(self, msg: Hello, t: int) -> None:
        compatible = msg.protocol_version == PROTOCOL_VERSION and msg.schema_hash == SCHEMA_HASH
        if compatible:
            self.mode = ControlMode.SETPOINT
            self.link.forget_answers()
            self._apply(Event.HELLO)
            if not self._session:
                self._session = True
                self._telemetry.start(t, first_offset=True)
        else:
            self._log(
                Severity.ERROR,
                LogCode.HANDSHAKE,
                f"incompatible host: protocol {msg.protocol_version} schema {msg.schema_hash:#010x} "
                f"(board: {PROTOCOL_VERSION}, {SCHEMA_HASH:#010x})",
            )
        ident = self.config.identity
        self._send(
            HelloReply(
                protocol_version=PROTOCOL_VERSION,
                schema_hash=SCHEMA_HASH,
                reset_cause=self.reset_cause,
                state=self.state,
                n_units=self.config.n_units,
                frame_rate_hz=round(self.config.frame_rate_hz),
                manufacturer=ident.manufacturer,
                model=ident.model,
                description=ident.description,
                version=ident.version,
                uri=ident.uri,
                serial=ident.serial,
                firmware_build=ident.firmware_build,
            )
        )

    def _on_arm(self) -> NackReason | None:
        if self.state is not BoardState.BOOT and any(c is None for c in self.calibrations):
            return NackReason.BAD_CALIBRATION
        was = self.state
        refused = self._apply(Event.ARM)
        if refused is None:
            self._shed_latched = False
            if was is not BoardState.ARMED:
                self._rotor_cmd = [0.0] * self.config.n_units
                self._raw_cmd = None
        return refused

    def _on_set_mode(self, msg: SetMode) -> NackReason | None:
        refused = transition(self.state, Event.SET_MODE).refused
        if refused is not None:
            return refused
        if msg.mode not in (ControlMode.SETPOINT, ControlMode.RAW_PULSES):
            return NackReason.UNSUPPORTED
        if msg.mode is not self.mode:
            self.mode = msg.mode
            self._log(Severity.INFO, LogCode.STATE, f"mode {msg.mode.name}")
        return None

    def _on_setpoint(self, msg: ActuatorSetpoint) -> None:
        if not motors_enabled(self.state) or self.mode is not ControlMode.SETPOINT:
            self.counters["ignored_setpoints"] += 1
            return
        n = self.config.n_units
        if len(msg.units) != n:
            self.counters["bad_setpoints"] += 1
            self._log(
                Severity.WARNING, LogCode.BAD_COMMAND, f"setpoint for {len(msg.units)} units, board has {n}"
            )
            return
        self.counters["setpoints"] += 1
        if msg.gimbal_mode is not self._gimbal_mode:
            self._gimbal_mode = msg.gimbal_mode
            for u in self.units:
                u.gimbal_mode = msg.gimbal_mode
        self._gimbal_cmd = [u.gimbal for u in msg.units]
        self._rotor_cmd = [u.rotor_speed for u in msg.units]

    def _on_raw_pulses(self, msg: RawPulses) -> None:
        if not motors_enabled(self.state) or self.mode is not ControlMode.RAW_PULSES:
            self.counters["ignored_setpoints"] += 1
            return
        if len(msg.pulses_us) != self.config.n_channels:
            self.counters["bad_setpoints"] += 1
            self._log(
                Severity.WARNING,
                LogCode.BAD_COMMAND,
                f"raw pulses for {len(msg.pulses_us)} channels, board has {self.config.n_channels}",
            )
            return
        self.counters["setpoints"] += 1
        self._raw_cmd = tuple(msg.pulses_us)

    # ------------------------------------------------------------------ calibration transfers
    def _on_calibration_data(self, msg: CalibrationData) -> NackReason | None:
        if self.state is not BoardState.DISARMED:
            return NackReason.BAD_STATE
        if msg.unit >= self.config.n_units:
            return NackReason.OUT_OF_RANGE
        try:
            done = self._reassembler.feed(msg)
            if done is None:
                return None
            unit, data = done
            cal = type(self._cal_or_default(unit)).from_bytes(data, source=f"upload unit {unit}")
        except (HilError, ValueError) as exc:
            self._log(
                Severity.ERROR, LogCode.CALIBRATION, f"calibration upload for unit {msg.unit} refused: {exc}"
            )
            return NackReason.BAD_CALIBRATION
        self.calibrations[unit] = cal
        self.units[unit].calibration = cal
        self._conv_cache.clear()
        self._log(
            Severity.INFO, LogCode.CALIBRATION, f"calibration for unit {unit} stored ({len(data)} bytes)"
        )
        return None

    def _on_calibration_request(self, msg: CalibrationRequest, t: int) -> NackReason | None:
        if self.state is BoardState.BOOT:
            return NackReason.BAD_STATE
        if msg.unit >= self.config.n_units:
            return NackReason.OUT_OF_RANGE
        cal = self.calibrations[msg.unit]
        if cal is None:
            return NackReason.BAD_CALIBRATION
        if self._cal_out:
            return NackReason.BUSY
        for part in fragment(msg.unit, msg.transfer_id, cal.to_bytes()):
            seq = self.link.send(part)
            if seq is not None:
                self._cal_out[seq] = [part, 1, t + self._us(_CAL_RETRY_S)]
        return None

    def _retry_calibration(self, seq: int, entry: list[Any], t: int) -> None:
        if entry[1] >= _CAL_TRIES:
            self._cal_out.clear()
            self._log(
                Severity.ERROR,
                LogCode.CALIBRATION,
                f"calibration download abandoned: no ACK after {_CAL_TRIES} tries",
            )
            return
        entry[1] += 1
        entry[2] = t + self._us(_CAL_RETRY_S)
        self.link.send(entry[0], seq=seq)

    def _on_answer(self, msg: Ack | Nack) -> None:
        if msg.msg_id != CalibrationData.MSG_ID or msg.seq not in self._cal_out:
            self.link.stats.ignored += 1
            return
        if isinstance(msg, Nack):
            self._cal_out.clear()
            self._log(
                Severity.WARNING, LogCode.CALIBRATION, f"host refused calibration fragment: {msg.reason.name}"
            )
            return
        del self._cal_out[msg.seq]

    # ================================================================== outputs
    def _battery_for_conversion(self) -> float:
        f = self.power_manager.filtered_v_cell
        v = self.power.battery_v if f is None else f * self.power_manager.cells
        return round(v / _VOLT_QUANTUM) * _VOLT_QUANTUM

    def _compute_outputs(self) -> tuple[int | None, ...]:
        """The firmware's pulse widths for the present state, command and power stage."""
        n = self.config.n_units
        safe = self.config.rotor_safe_us
        v = self._battery_for_conversion()
        out: list[int | None] = []
        clamped = False
        armed = motors_enabled(self.state)
        shed = self._shed_latched or self.power_state >= PowerState.SHED
        raw = self._raw_cmd if (armed and self.mode is ControlMode.RAW_PULSES) else None
        for i in range(n):
            cal = self.calibrations[i]
            # gimbal channel
            if raw is not None:
                g: int | None = raw[2 * i]
            elif cal is None:
                g = None
            else:
                conv = self._convert(cal, "g", self._gimbal_cmd[i], self._gimbal_mode)
                clamped |= conv.saturated and armed
                g = round(conv.value)
            # rotor channel
            if not armed or shed:
                r: int | None = safe
            elif raw is not None:
                r = raw[2 * i + 1]
            elif cal is None:
                r = safe
            else:
                conv = self._convert(cal, "r", self._rotor_cmd[i], v)
                clamped |= conv.saturated
                r = round(conv.value)
            if (
                armed
                and not shed
                and self.power_state is PowerState.LIMIT
                and cal is not None
                and r is not None
            ):
                cap = self._rotor_cap(cal, v)
                if r > cap:
                    r = cap
                    clamped = True
            out.append(g)
            out.append(r)
        self._clamped = clamped
        return tuple(out)

    def _rotor_cap(self, cal: Any, v: float) -> int:
        lo = self._convert(cal, "r", 0.0, v).value
        hi = self._convert(cal, "r", 1e9, v).value
        return round(lo + self.config.power.thresholds.limit_throttle * (hi - lo))

    def _convert(self, cal: Any, kind: str, value: float, arg: Any) -> Any:
        key = (id(cal), kind, value, arg)
        hit = self._conv_cache.get(key)
        if hit is None:
            if len(self._conv_cache) > 4096:
                self._conv_cache.clear()
            if kind == "r":
                hit = cal.rotor_pulse_us(value, arg)
            else:
                hit = cal.gimbal_pulse_us(value, arg)
            self._conv_cache[key] = hit
        return hit

    def _pulse_frame(self, t: int) -> None:
        if self.phase is McuPhase.RUNNING:
            self.outputs = self._compute_outputs()
        # HUNG: the timers keep generating the last widths.
        self.timeline.record(t / 1e6, self.outputs)

    def _ppm_frame(self, t: int) -> None:
        from protocol.pulses import clamp_ppm_width, encode_ppm  # optional output: imported on first use

        # Like a PPM output stage, limit each width to the PPM channel range (raw pulses may reach 500-2500).
        safe = self.config.rotor_safe_us
        widths = [clamp_ppm_width(w if w is not None else safe) for w in self.outputs[:8]]
        train = encode_ppm(widths)
        self.timeline.ppm.append(PpmTrain(t / 1e6, tuple(float(e) for e in train)))

    # ================================================================== physics and power
    def _cal_or_default(self, unit: int) -> Any:
        cal = self.calibrations[unit]
        return cal if cal is not None else default_unit_calibration()

    def _physics(self, t: int) -> None:
        """Advance motors, battery and UBEC from the last physics time to ``t`` (hardware: always runs)."""
        dt = (t - self._phys_us) / 1e6
        if dt <= 0.0:
            return
        self._phys_us = t
        now = t / 1e6
        outputs = self.outputs
        v = self.power.battery_v
        dead = self.faults.dead_escs
        for i, unit in enumerate(self.units):
            if dead:
                unit.rotor_dead = self.faults.channel_dead(2 * i + 1, now)
                unit.gimbal_dead = self.faults.channel_dead(2 * i, now)
            unit.advance(dt, outputs[2 * i], outputs[2 * i + 1], v)
        self.battery.discharge(self.power.battery_a, dt)
        self._solve_power(now)

    def _solve_power(self, now: float) -> None:
        if self.faults.sags or self.battery.sag_v or self.battery.extra_resistance_ohm:
            self.battery.sag_v, self.battery.extra_resistance_ohm = self.faults.battery_sag(now)
        ubec = self.config.power.ubec
        rail_load = ubec.electronics_current_a + sum(u.gimbal_current_a() for u in self.units)
        # The loads are solved as constant power at the last voltage (their weak voltage dependence lags
        # one physics step, a few ms).
        v = self.power.battery_v if self.power.battery_v > 0 else self.battery.ocv()
        rail_v, rail_a, over = ubec_output(ubec, v, rail_load)
        p = sum(u.rotor_power_w(v) for u in self.units) + ubec_input_power(ubec, rail_v, rail_a)
        v, amps = self.battery.terminal(p)
        rail_v, rail_a, over = ubec_output(ubec, v, rail_load)
        pr = self.power
        pr.battery_v, pr.battery_a, pr.soc = v, amps, self.battery.soc
        pr.ubec_v, pr.ubec_a, pr.ubec_overcurrent = rail_v, rail_a, over

    def _power_hardware(self, t: int) -> None:
        """Brown-out detector (hardware) and, when the main loop runs, the firmware's power manager."""
        if self.phase is not McuPhase.RESET and self.power_manager.browned_out(self.power.ubec_v):
            self._reset(ResetCause.BROWN_OUT, t)
            return
        if self.phase is McuPhase.RUNNING:
            self._power_manager_step(t, self.config.power.update_period_s)
            self._detect_dead_outputs(t)

    def _power_manager_step(self, t: int, dt: float) -> None:
        old = self.power_state
        new = self.power_manager.update(self.power.battery_v, dt)
        if self.power.ubec_v < self.config.power.thresholds.brownout_release_v:
            new = PowerState.BROWN_OUT  # the rail is in the MCU's brown-out zone: reset imminent
        self.power_state = new
        if new is PowerState.SHED and not self._shed_latched and motors_enabled(self.state):
            self._shed_latched = True
        if new is not old:
            sev = (
                Severity.INFO
                if new < old
                else (Severity.ERROR if new >= PowerState.SHED else Severity.WARNING)
            )
            self._log(
                sev,
                LogCode.POWER,
                f"power {old.name} -> {new.name} (battery {self.power.battery_v:.2f} V, "
                f"{self.power_manager.filtered_v_cell or 0:.3f} V/cell, rail {self.power.ubec_v:.2f} V)",
            )
        over = self.power.ubec_overcurrent
        if over and not self._ubec_over:
            self._log(
                Severity.WARNING,
                LogCode.UBEC_OVERCURRENT,
                f"UBEC over current: {self.power.ubec_a:.2f} A > "
                f"{self.config.power.ubec.current_limit_a:.2f} A",
            )
        self._ubec_over = over

    def _detect_dead_outputs(self, t: int) -> None:
        """An output commanded to move that shows no response for ``dead_esc_detect_s`` is a dead ESC."""
        now = t / 1e6
        v = self.power.battery_v
        for i, unit in enumerate(self.units):
            g_ch, r_ch = 2 * i, 2 * i + 1
            rotor_us = self.outputs[r_ch]
            expected = 0.0 if rotor_us is None else unit.rotor_speed_for(rotor_us, v)
            rotor_bad = (
                expected > 0.1 * self.config.motor.rated_speed_rad_s
                and abs(unit.rotor_speed) < 0.05 * expected
            )
            gimbal_us = self.outputs[g_ch]
            if gimbal_us is None or self._gimbal_mode is not GimbalMode.RATE:
                gimbal_bad = False
            else:
                want = abs(unit.gimbal_value_for(gimbal_us, GimbalMode.RATE))
                gimbal_bad = want > 0.1 and abs(unit.gimbal_rate) < 0.1 * want
            for ch, bad in ((g_ch, gimbal_bad), (r_ch, rotor_bad)):
                if not bad:
                    self._dead_since[ch] = None
                    continue
                since = self._dead_since[ch]
                if since is None:
                    self._dead_since[ch] = now
                elif now - since >= self.config.dead_esc_detect_s and ch not in self._dead_found:
                    self._dead_found.add(ch)
                    kind = "gimbal" if ch % 2 == 0 else "rotor"
                    self._log(
                        Severity.ERROR,
                        LogCode.DEAD_ESC,
                        f"{kind} ESC on channel {ch} (unit {ch // 2}) not responding",
                    )

    # ================================================================== messages out
    def _uptime_ms(self, t: int) -> int:
        return ((t - self._us(self.resets[-1].t)) // 1000) & 0xFFFFFFFF

    def _send(self, message: Any) -> None:
        self.link.send(message)

    def _log(self, severity: Severity, code: LogCode, text: str) -> None:
        logger.debug("board log [%s] %s: %s", severity.name, code.name, text)
        if self.phase is McuPhase.RESET:
            return
        self._send(
            Log(severity=severity, code=int(code), text=text.encode("utf-8")[:200].decode("utf-8", "ignore"))
        )

    def _send_telemetry(self, t: int) -> None:
        pr = self.power
        age = _U16 if self._last_rx_us is None else min((t - self._last_rx_us) // 1000, _U16)
        counters = self.link.deframer.counters
        self._send(
            Telemetry(
                time_ms=self._uptime_ms(t),
                state=self.state,
                mode=self.mode,
                watchdog=self.watchdog_state,
                power=self.power_state,
                faults=int(self.fault_flags()),
                link_age_ms=age,
                battery_mv=_clip16(pr.battery_v * 1000.0),
                battery_ma=_clip16(pr.battery_a * 1000.0),
                battery_soc=max(0, min(100, round(pr.soc * 100.0))),
                ubec_mv=_clip16(pr.ubec_v * 1000.0),
                ubec_ma=_clip16(pr.ubec_a * 1000.0),
                rx_frames=counters.frames & 0xFFFFFFFF,
                rx_bad=counters.bad_total & 0xFFFFFFFF,
                seq_gaps=counters.seq_gaps & 0xFFFFFFFF,
                pulses_us=tuple(0 if w is None else w for w in self.outputs),
                units=self.unit_states(),
            )
        )


def _clip16(x: float) -> int:
    if not math.isfinite(x):
        return 0
    return max(0, min(_U16, round(x)))
