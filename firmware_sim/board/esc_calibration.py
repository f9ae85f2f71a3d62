"""ESC endpoint programming on the board: the usual hobby-ESC procedure on one rotor channel, timed by the
board, entered only from DISARMED with the operator's explicit confirmation (``EscCalibrate``).

::

    EscCalibrate(START) ──► SUPPLY_OFF (switch: ESC supply cut, channel at high_us, supply_off_ms)
                        └─► WAIT_SUPPLY (no switch: channel at high_us, the operator connects the supply
                                         and the host sends EscCalibrate(SUPPLY_APPLIED); 60 s at most)
                            ──► HIGH (supply on, channel at high_us, high_ms: the ESC's acknowledgement)
                            ──► LOW (channel at low_us, low_ms: the ESC stores both) ──► DONE (safe pulse)

Any of DISARM, a new session (Hello), link loss, load shedding or the supply wait running out aborts it:
the channel goes to the safe (minimum) pulse at once and the supply switch is released; an MCU reset
stops it with everything else. While it runs the board reports ``ControlMode.ESC_CALIBRATION`` in
``Telemetry.mode`` (arming and mode changes are refused ``BUSY``); every phase change is a ``Log``
(code ``ESC_CALIBRATION``) and an ``EscCalibrationStatus``, sent again at the telemetry rate.

In emulation the board also plays the operator of a board without a supply switch: the unit's ESC is
disconnected when the procedure asks for it and connected when the host says it was
(``UnitModel.esc_connected``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from protocol.messages import (
    ESC_CALIBRATION_CONFIRM,
    ESC_SUPPLY_WAIT_MS,
    BoardState,
    EscCalAbort,
    EscCalibrate,
    EscCalibrationStatus,
    EscCalPhase,
    EscCalStep,
    NackReason,
    Severity,
)
from protocol.pulse_widths import whole_us

from .actuators import UnitModel
from .codes import LogCode
from .config import BoardConfig, longest_pulse_fine
from .telemetry import Outbox

ESC_MIN_SPAN_US = 400
"""The endpoints taught must lie at least this far apart."""
ESC_MIN_SUPPLY_OFF_MS = 100
"""With a supply switch, the ESC is kept off at least this long (its capacitors discharge)."""
SUPPLY_WAIT_MS = ESC_SUPPLY_WAIT_MS
"""Without a switch, how long the board waits for the operator to connect the ESC's supply (the
protocol's figure: the host shows the operator how long is left)."""

_NEVER = math.inf
_RUNNING = (EscCalPhase.SUPPLY_OFF, EscCalPhase.WAIT_SUPPLY, EscCalPhase.HIGH, EscCalPhase.LOW)


class EscCalibration:
    """The procedure's state (board time in µs). ``supply_cut`` is the board's ESC-supply switch output."""

    def __init__(
        self,
        config: BoardConfig,
        outbox: Outbox,
        units: Sequence[UnitModel],
        on_change: Callable[[], None] | None = None,
    ) -> None:
        self.config = config
        self.units = units
        self._out = outbox
        self._on_change = on_change
        """Called at every phase change, the procedure's width (:meth:`rotor_width`) changed: the board
        aims its outputs again in this main-loop pass (the firmware's ``enter`` sets ``outputs_dirty``),
        so telemetry never reports an endpoint width the procedure no longer puts out (after an abort,
        the high endpoint: full throttle) for up to a pulse frame."""
        self.reset()

    def reset(self) -> None:
        """MCU reset: the procedure is forgotten and the switch output released (the supply is on)."""
        self.phase = EscCalPhase.IDLE
        self.active = False
        """Whether the procedure runs (kept with ``phase``: the board asks at every event)."""
        self.abort_reason = EscCalAbort.NONE
        self.unit = 0
        self.low_us = self.high_us = 0
        self.high_ms = self.low_ms = 0
        self.supply_cut = False
        self.phase_start_us = 0
        self.deadline_us: float = _NEVER
        """Board time (µs) of the next phase change: inf whenever the procedure is not running."""

    def rotor_width(self) -> tuple[int, int] | None:
        """(channel, width µs) the procedure puts on its rotor channel now, or None (not running)."""
        if not self.active:
            return None
        width = self.low_us if self.phase is EscCalPhase.LOW else self.high_us
        return 2 * self.unit + 1, width

    # ------------------------------------------------------------------ commands
    def command(self, msg: EscCalibrate, state: BoardState, power_ok: bool, t: int) -> NackReason | None:
        """``EscCalibrate`` at ``t`` (µs): None (accepted) or the NACK reason."""
        if state is BoardState.BOOT:
            return NackReason.BAD_STATE
        if msg.confirm != ESC_CALIBRATION_CONFIRM:
            return NackReason.UNCONFIRMED
        if msg.step is EscCalStep.SUPPLY_APPLIED:
            return self._supply_applied(msg, t)
        return self._start(msg, state, power_ok, t)

    def _start(self, msg: EscCalibrate, state: BoardState, power_ok: bool, t: int) -> NackReason | None:
        if state is not BoardState.DISARMED:
            return NackReason.BAD_STATE
        if self.active:
            return NackReason.BUSY
        switched = self.config.esc_supply_switch
        if (
            msg.unit >= self.config.n_units
            or msg.high_us - msg.low_us < ESC_MIN_SPAN_US
            # an endpoint the frame cannot carry would be taught cut short (config.longest_pulse_fine)
            or whole_us(msg.high_us) > longest_pulse_fine(self.config.frame_rate_hz)
            or (switched and msg.supply_off_ms < ESC_MIN_SUPPLY_OFF_MS)
        ):
            return NackReason.OUT_OF_RANGE
        if not power_ok:
            return NackReason.POWER
        self.unit, self.low_us, self.high_us = msg.unit, msg.low_us, msg.high_us
        self.high_ms, self.low_ms = msg.high_ms, msg.low_ms
        self.abort_reason = EscCalAbort.NONE
        how = f"supply off for {msg.supply_off_ms} ms" if switched else "connect the ESC's supply when asked"
        self._log(
            Severity.INFO,
            f"ESC calibration of unit {self.unit}: teaching {self.low_us}-{self.high_us} us ({how})",
        )
        if switched:
            self.supply_cut = True
            self._enter(EscCalPhase.SUPPLY_OFF, t, t + msg.supply_off_ms * 1000)
        else:
            self.units[self.unit].esc_connected = False  # the emulated operator disconnects it
            self._enter(EscCalPhase.WAIT_SUPPLY, t, t + SUPPLY_WAIT_MS * 1000)
            self._log(
                Severity.WARNING,
                f"ESC calibration of unit {self.unit}: connect the ESC's supply now ({self.high_us} us on "
                f"channel {2 * self.unit + 1}); waiting {SUPPLY_WAIT_MS // 1000} s",
            )
        return None

    def _supply_applied(self, msg: EscCalibrate, t: int) -> NackReason | None:
        if self.phase is not EscCalPhase.WAIT_SUPPLY or msg.unit != self.unit:
            return NackReason.BAD_STATE
        self.units[self.unit].esc_connected = True  # the emulated operator did what the host says
        self._enter(EscCalPhase.HIGH, t, t + self.high_ms * 1000)
        return None

    def abort(self, why: EscCalAbort, t: int) -> None:
        """Stop now (if running): the channel to the safe pulse, the supply switch released."""
        if not self.active:
            return
        self.supply_cut = False
        self.units[self.unit].esc_connected = True  # the emulated operator restores the supply
        self.abort_reason = why
        self._enter(EscCalPhase.ABORTED, t, _NEVER)
        self._log(
            Severity.WARNING,
            f"ESC calibration of unit {self.unit} aborted ({why.name}): channel at "
            f"{self.config.rotor_safe_us} us",
        )

    # ------------------------------------------------------------------ time
    def poll(self, t: int) -> None:
        """Move through the phases whose deadlines have passed at ``t`` (µs), each at its own time."""
        while self.active and t >= self.deadline_us:
            due = int(self.deadline_us)
            if self.phase is EscCalPhase.SUPPLY_OFF:
                self.supply_cut = False
                self._enter(EscCalPhase.HIGH, due, due + self.high_ms * 1000)
            elif self.phase is EscCalPhase.WAIT_SUPPLY:
                self.abort(EscCalAbort.SUPPLY_TIMEOUT, due)
            elif self.phase is EscCalPhase.HIGH:
                self._enter(EscCalPhase.LOW, due, due + self.low_ms * 1000)
            else:
                self._enter(EscCalPhase.DONE, due, _NEVER)
                self._log(
                    Severity.INFO,
                    f"ESC calibration of unit {self.unit} done: endpoints {self.low_us}-{self.high_us} us; "
                    f"channel back at {self.config.rotor_safe_us} us",
                )

    def report(self, t: int) -> None:
        """The periodic status while the procedure runs (called at the telemetry rate)."""
        if self.active:
            self._out.send(self.status(t))

    def status(self, t: int) -> EscCalibrationStatus:
        width = self.rotor_width()
        return EscCalibrationStatus(
            unit=self.unit,
            phase=self.phase,
            abort=self.abort_reason,
            pulse_us=width[1] if width is not None else self.config.rotor_safe_us,
            supply_on=0 if self.supply_cut else 1,
            phase_ms=min(max(t - self.phase_start_us, 0) // 1000, 0xFFFFFFFF),
        )

    def _enter(self, phase: EscCalPhase, t: int, deadline: float) -> None:
        self.phase = phase
        self.active = phase in _RUNNING
        self.phase_start_us = t
        self.deadline_us = deadline
        if self._on_change is not None:
            self._on_change()
        if phase in (EscCalPhase.SUPPLY_OFF, EscCalPhase.HIGH, EscCalPhase.LOW):
            self._log(Severity.INFO, f"ESC calibration of unit {self.unit}: {phase.name}")
        self._out.send(self.status(t))

    def _log(self, severity: Severity, text: str) -> None:
        self._out.log(severity, LogCode.ESC_CALIBRATION, text)
