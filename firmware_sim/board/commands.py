"""The board's protocol state machine as the main loop runs it: frames from the host are answered
(ACK/NACK, retransmissions from the answer cache) and executed — the handshake (``Hello``), arming and
disarming, the control mode, setpoints and raw pulses, calibration transfers — and the link watchdog
puts an armed board into FAILSAFE when nothing valid arrives for ``link_timeout_s``.

The transitions themselves are the pure function :func:`firmware_sim.board.state.transition`; this module
adds what a state change does (stop the rotors, hold the gimbals, log, send a ``Heartbeat``). What each
message does is :data:`EXECUTE`, a table with an entry for every message of the catalogue.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from types import MethodType
from typing import Any

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
    EscCalAbort,
    EscCalibrate,
    EscCalibrationStatus,
    Flags,
    GimbalMode,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    Message,
    Nack,
    NackReason,
    RawPulses,
    SetMode,
    Severity,
    Telemetry,
    WatchdogState,
)

from .actuators import UnitModel
from .calibration import CalibrationTransfers
from .codes import LogCode
from .config import BoardConfig
from .esc_calibration import EscCalibration
from .link import BoardLink
from .periodic import Periodic
from .power import PowerSupervisor
from .state import Event, motors_enabled, transition
from .telemetry import Outbox, hello_reply, uptime_ms
from .timeline import ResetEvent

_NEVER = math.inf
_ACK_REQUESTED = int(Flags.ACK_REQUESTED)  # tested as an int: IntFlag's ``&`` runs in Python (~1 µs a frame)


@dataclass
class Command:
    """The host's last command as the firmware holds it, per unit: the gimbal rate (rad/s) or angle (rad)
    (``gimbal_mode``) and the rotor speed (rad/s); in RAW_PULSES mode the widths (µs) per channel."""

    n_units: int
    gimbal_mode: GimbalMode = field(init=False)
    gimbal: list[float] = field(init=False)
    rotor: list[float] = field(init=False)
    raw: tuple[int, ...] | None = field(init=False)

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """After an MCU reset: RATE mode, zero rates, rotors stopped."""
        self.gimbal_mode = GimbalMode.RATE
        self.gimbal = [0.0] * self.n_units
        self.stop_rotors()

    def stop_rotors(self) -> None:
        self.rotor = [0.0] * self.n_units
        self.raw = None


class CommandHandler:
    """The protocol side of the main loop. ``state`` and ``mode`` are the board's; ``counters`` counts
    setpoints (accepted, malformed, ignored because disarmed or in the other mode).

    Parts of the board it works with: ``calibrations`` (one per unit, ``None``: missing; ``Arm`` needs
    all), ``units`` (gimbal mode, held angles), ``power`` (``Arm`` is refused while shedding load, and
    clears the SHED latch), ``transfers`` (calibration upload/download), ``telemetry`` (the schedule a
    session starts), ``resets`` (the MCU's reset record: uptime and reset cause). ``catch_up(t)`` brings
    the hardware models to ``t`` (µs) before the gimbals' present angles are held; ``apply_outputs()``
    makes the board aim its outputs at what the present state and command give, at once (leaving ARMED
    must not wait for the next pulse frame: see :meth:`_set_state`)."""

    def __init__(
        self,
        config: BoardConfig,
        link: BoardLink,
        outbox: Outbox,
        *,
        calibrations: Sequence[Any | None],
        units: Sequence[UnitModel],
        power: PowerSupervisor,
        transfers: CalibrationTransfers,
        esc_calibration: EscCalibration,
        telemetry: Periodic,
        resets: Sequence[ResetEvent],
        catch_up: Callable[[int], None],
        apply_outputs: Callable[[], None],
    ) -> None:
        self.config = config
        self.link = link
        self.calibrations = calibrations
        self.units = units
        self.power = power
        self.transfers = transfers
        self.esc_calibration = esc_calibration
        self.telemetry = telemetry
        self.resets = resets
        self.counters = {"setpoints": 0, "bad_setpoints": 0, "ignored_setpoints": 0}
        self.command = Command(config.n_units)
        self.state = BoardState.BOOT
        self.boot_id = 0  # this boot's id (HelloReply, Heartbeat): the board draws one at every reset
        self.mode = ControlMode.SETPOINT
        self.session = False  # a compatible Hello since reset (telemetry runs)
        self.link_lost = False
        self.last_rx_us: int | None = None
        self._timeout_us = round(config.link_timeout_s * 1e6)
        self.link_deadline_us: float = _NEVER
        """Board time (µs) the link watchdog expires (inf: not watching: no session, or already lost)."""
        self._out = outbox
        self._catch_up = catch_up
        self._apply_outputs = apply_outputs
        self._execute: dict[type[Message], Callable[[Any, int], NackReason | None] | None] = {
            cls: None if execute is None else MethodType(execute, self) for cls, execute in EXECUTE.items()
        }
        """:data:`EXECUTE` bound to this board: a frame's handler is one look-up by its message's type."""

    def reset(self) -> None:
        """MCU reset: BOOT, SETPOINT mode, no session, the command forgotten."""
        self.state = transition(self.state, Event.RESET).state
        self.mode = ControlMode.SETPOINT
        self.last_rx_us = None
        self.link_lost = False
        self.session = False
        self.command.reset()
        self._watch()

    @property
    def reported_mode(self) -> ControlMode:
        """The mode telemetry carries: ESC_CALIBRATION while that procedure runs, else ``mode``."""
        return ControlMode.ESC_CALIBRATION if self.esc_calibration.active else self.mode

    @property
    def watchdog_state(self) -> WatchdogState:
        return WatchdogState.LINK_LOST if self.link_lost else WatchdogState.OK

    # ------------------------------------------------------------------ link watchdog
    def _watch(self) -> None:
        """Set :attr:`link_deadline_us` anew after the session, the link state or the last frame changed
        (a plain attribute, not a property: the board reads it at every event)."""
        if self.session and not self.link_lost and self.last_rx_us is not None:
            self.link_deadline_us = self.last_rx_us + self._timeout_us
        else:
            self.link_deadline_us = _NEVER

    def check_link(self, t: int) -> None:
        """The link watchdog at ``t`` (µs): nothing valid for ``link_timeout_s`` → link lost."""
        if t >= self.link_deadline_us:
            self._on_link_lost(t)

    def _on_valid_rx(self, t: int) -> None:
        self.last_rx_us = t
        if self.link_lost:
            self.link_lost = False
            self._out.log(Severity.INFO, LogCode.LINK_RESTORED, "link restored")
        self._watch()

    def _on_link_lost(self, t: int) -> None:
        self.link_lost = True
        self._watch()
        self._out.log(
            Severity.WARNING,
            LogCode.LINK_LOST,
            f"link lost: nothing valid for {self.config.link_timeout_s * 1000:.0f} ms",
        )
        self.esc_calibration.abort(EscCalAbort.LINK_LOST, t)
        self._apply(Event.LINK_LOST, t)

    # ------------------------------------------------------------------ frames in
    def receive(self, t: int) -> None:
        """Everything in the UART ring at ``t`` (µs): deframe, answer and execute each valid frame."""
        before = self.link.stats.rx_overflow
        for event in self.link.drain():
            if isinstance(event, BadFrame):
                continue
            self._handle_frame(event, t)
        if self.link.stats.rx_overflow != before:
            self._out.log(
                Severity.WARNING,
                LogCode.RX_OVERFLOW,
                f"receive buffer overflow ({self.link.stats.rx_overflow} bytes lost)",
            )

    def _handle_frame(self, frame: Frame, t: int) -> None:
        msg = frame.message
        wants_answer = bool(int(frame.flags) & _ACK_REQUESTED) or type(msg).RELIABLE
        execute = self._execute[type(msg)]
        if execute is None:
            self.link.stats.ignored += 1  # board-to-host messages echoed back: not ours
            return
        self._on_valid_rx(t)
        if wants_answer:
            cached = self.link.cached_answer(frame)
            if cached is not None:
                self._out.send(cached)
                return
        refused = execute(msg, t)
        if wants_answer:
            answer: Ack | Nack
            if refused is None:
                answer = Ack(msg_id=frame.msg_id, seq=frame.seq)
            else:
                answer = Nack(msg_id=frame.msg_id, seq=frame.seq, reason=refused)
            self.link.remember_answer(frame, answer)
            self._out.send(answer)

    # ------------------------------------------------------------------ state changes
    def _apply(self, event: Event, t: int) -> NackReason | None:
        tr = transition(self.state, event, power_ok=self.power.power_ok)
        if tr.accepted:
            self._set_state(tr.state, t)
        return tr.refused

    def _set_state(self, new: BoardState, t: int) -> None:
        """Enter ``new``. Leaving ARMED (Disarm, Hello, link loss) stops the rotors and holds the gimbals
        *in this main-loop pass*, before the change is reported, as the C firmware's ``enter_state``
        does: the widths the board aims at (and reports in ``Telemetry.pulses_us``) are the safe ones
        from this tick on, and the next pulse frame carries them. Waiting for that frame to recompute
        them left telemetry reporting the armed rotor pulse with state DISARMED for up to a frame
        (issue 25, finding 7). The frame under way keeps its width: the pins change at a frame start."""
        old = self.state
        if new is old:
            return
        self.state = new
        if not motors_enabled(new):
            self._hold_gimbals(t)
            self.command.stop_rotors()
            self._apply_outputs()
        self._out.log(
            Severity.WARNING if new is BoardState.FAILSAFE else Severity.INFO,
            LogCode.STATE,
            f"state {old.name} -> {new.name}",
        )
        self._out.send(Heartbeat(time_ms=uptime_ms(t, self.resets[-1]), state=int(new), boot_id=self.boot_id))

    def _hold_gimbals(self, t: int) -> None:
        """Gimbals hold: zero rate in RATE mode, the present angle in ANGLE mode."""
        if self.command.gimbal_mode is GimbalMode.RATE:
            self.command.gimbal = [0.0] * self.config.n_units
        else:
            self._catch_up(t)
            self.command.gimbal = [u.gimbal_angle for u in self.units]

    # ------------------------------------------------------------------ commands (EXECUTE's handlers)
    def _on_hello(self, msg: Hello, t: int) -> None:
        compatible = msg.protocol_version == PROTOCOL_VERSION and msg.schema_hash == SCHEMA_HASH
        if compatible:
            self.esc_calibration.abort(EscCalAbort.HELLO, t)
            self.mode = ControlMode.SETPOINT
            self.link.forget_answers()
            self.transfers.new_session()
            self._apply(Event.HELLO, t)
            if not self.session:
                self.session = True
                self._watch()
                self.telemetry.start(t, first_offset=True)
        else:
            self._out.log(
                Severity.ERROR,
                LogCode.HANDSHAKE,
                f"incompatible host: protocol {msg.protocol_version} schema {msg.schema_hash:#010x} "
                f"(board: {PROTOCOL_VERSION}, {SCHEMA_HASH:#010x})",
            )
        self._out.send(hello_reply(self.config, self.resets[-1].cause, self.state, self.boot_id))

    def _on_arm(self, msg: Arm, t: int) -> NackReason | None:
        if self.state is not BoardState.BOOT and any(c is None for c in self.calibrations):
            return NackReason.BAD_CALIBRATION
        if self.esc_calibration.active:
            return NackReason.BUSY
        was = self.state
        refused = self._apply(Event.ARM, t)
        if refused is None:
            self.power.shed_latched = False
            if was is not BoardState.ARMED:
                self.command.stop_rotors()
        return refused

    def _on_disarm(self, msg: Disarm, t: int) -> NackReason | None:
        self.esc_calibration.abort(EscCalAbort.DISARM, t)
        return self._apply(Event.DISARM, t)

    def _on_esc_calibrate(self, msg: EscCalibrate, t: int) -> NackReason | None:
        return self.esc_calibration.command(msg, self.state, self.power.power_ok, t)

    def _on_calibration_data(self, msg: CalibrationData, t: int) -> NackReason | None:
        return self.transfers.upload(msg, self.state)

    def _on_calibration_request(self, msg: CalibrationRequest, t: int) -> NackReason | None:
        return self.transfers.download(msg, self.state, t)

    def _on_answer(self, msg: Ack | Nack, t: int) -> None:
        """The host's Ack or Nack: of a download fragment, or counted as ignored by the transfers."""
        self.transfers.on_answer(msg)

    def _on_nothing_to_do(self, msg: Any, t: int) -> None:
        """A valid frame that asks nothing of the board (a Heartbeat: it only feeds the link watchdog),
        answered if it asked to be."""

    def _on_set_mode(self, msg: SetMode, t: int) -> NackReason | None:
        refused = transition(self.state, Event.SET_MODE).refused
        if refused is not None:
            return refused
        if msg.mode not in (ControlMode.SETPOINT, ControlMode.RAW_PULSES):
            return NackReason.UNSUPPORTED  # ESC_CALIBRATION is entered only by EscCalibrate
        if self.esc_calibration.active:
            return NackReason.BUSY
        if msg.mode is not self.mode:
            self.mode = msg.mode
            self._out.log(Severity.INFO, LogCode.STATE, f"mode {msg.mode.name}")
        return None

    def _on_setpoint(self, msg: ActuatorSetpoint, t: int) -> None:
        if not motors_enabled(self.state) or self.mode is not ControlMode.SETPOINT:
            self.counters["ignored_setpoints"] += 1
            return
        n = self.config.n_units
        if len(msg.units) != n:
            self.counters["bad_setpoints"] += 1
            self._out.log(
                Severity.WARNING, LogCode.BAD_COMMAND, f"setpoint for {len(msg.units)} units, board has {n}"
            )
            return
        self.counters["setpoints"] += 1
        cmd = self.command
        if msg.gimbal_mode is not cmd.gimbal_mode:
            cmd.gimbal_mode = msg.gimbal_mode
            for u in self.units:
                u.gimbal_mode = msg.gimbal_mode
        cmd.gimbal = [u.gimbal for u in msg.units]
        cmd.rotor = [u.rotor_speed for u in msg.units]

    def _on_raw_pulses(self, msg: RawPulses, t: int) -> None:
        if not motors_enabled(self.state) or self.mode is not ControlMode.RAW_PULSES:
            self.counters["ignored_setpoints"] += 1
            return
        if len(msg.pulses_us) != self.config.n_channels:
            self.counters["bad_setpoints"] += 1
            self._out.log(
                Severity.WARNING,
                LogCode.BAD_COMMAND,
                f"raw pulses for {len(msg.pulses_us)} channels, board has {self.config.n_channels}",
            )
            return
        self.counters["setpoints"] += 1
        self.command.raw = tuple(msg.pulses_us)


Execute = Callable[[CommandHandler, Any, int], NackReason | None]
"""A message's handler: ``(board's handler, message, t µs) -> None (accepted) or the NACK reason``."""

EXECUTE: dict[type[Message], Execute | None] = {
    # host to board: what the board does, returning None (accepted) or the NACK reason
    Hello: CommandHandler._on_hello,
    Heartbeat: CommandHandler._on_nothing_to_do,
    Arm: CommandHandler._on_arm,
    Disarm: CommandHandler._on_disarm,
    SetMode: CommandHandler._on_set_mode,
    EscCalibrate: CommandHandler._on_esc_calibrate,
    ActuatorSetpoint: CommandHandler._on_setpoint,
    RawPulses: CommandHandler._on_raw_pulses,
    CalibrationData: CommandHandler._on_calibration_data,  # an upload's fragment
    CalibrationRequest: CommandHandler._on_calibration_request,
    Ack: CommandHandler._on_answer,
    Nack: CommandHandler._on_answer,
    # board to host, echoed back (a loopback, a crossed wire): not ours, counted in ``link.stats.ignored``
    # and not a valid frame for the link watchdog (firmware/src/app.c tests the same three ids)
    HelloReply: None,
    Telemetry: None,
    Log: None,
    # board to host as well, but taken as a valid frame that asks nothing (as app.c's switch does)
    EscCalibrationStatus: CommandHandler._on_nothing_to_do,
}
"""What the board does with each message of the catalogue (``protocol.messages.CATALOGUE``), by type:
``None`` for the board-to-host messages it ignores. Every catalogue message has an entry —
``tests/test_message_dispatch.py`` fails naming one that has not (docs/protocol.md, "Adding a message")."""
