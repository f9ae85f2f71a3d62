"""Teaching a rotor ESC its endpoints from the host: ``EscCalibrate`` and the board's reports of it.

The board runs and times the procedure (docs/protocol.md, "ESC endpoint programming"); the host starts
it, answers the board's request for the ESC supply on a board without a supply switch (through the
``ask_supply`` callback: the operator connects it, then the host says so), and follows its
``EscCalibrationStatus`` reports to the end. The operator's statement that the rotor is off or unloaded
is required here (``confirm_unloaded``) and carried to the board in the command's ``confirm`` field.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from protocol.errors import ConfigError, LinkTimeout, ProtocolError
from protocol.messages import (
    ESC_CALIBRATION_CONFIRM,
    EscCalAbort,
    EscCalibrate,
    EscCalibrationStatus,
    EscCalPhase,
    EscCalStep,
)

from .benchlink import BenchLink


class EscProgrammingAborted(ProtocolError):
    """The board stopped the procedure early (``abort`` says why); the ESC was left at minimum."""

    def __init__(self, unit: int, abort: EscCalAbort) -> None:
        super().__init__(f"ESC calibration of unit {unit} aborted by the board ({abort.name})")
        self.unit = unit
        self.abort = abort


@dataclass(frozen=True)
class EscProgram:
    """What to teach and how long each step lasts (µs, ms; the board's rules: endpoints ≥ 400 µs apart,
    ``supply_off_ms`` ≥ 100 with a supply switch). ``high_ms`` must exceed the ESC's acknowledgement
    interval (its manual: typically 2 s, with beeps)."""

    low_us: int = 1000
    high_us: int = 2000
    supply_off_ms: int = 1500
    high_ms: int = 3000
    low_ms: int = 2000

    def message(self, unit: int, step: EscCalStep = EscCalStep.START) -> EscCalibrate:
        return EscCalibrate(
            unit=unit,
            step=step,
            confirm=ESC_CALIBRATION_CONFIRM,
            low_us=self.low_us,
            high_us=self.high_us,
            supply_off_ms=self.supply_off_ms,
            high_ms=self.high_ms,
            low_ms=self.low_ms,
        )

    @property
    def duration_s(self) -> float:
        """The procedure's length once the ESC is powered (plus the supply off time with a switch)."""
        return (self.supply_off_ms + self.high_ms + self.low_ms) / 1000.0


@dataclass(frozen=True)
class EscOutcome:
    """A finished procedure: the unit, the endpoints taught, every status the board sent."""

    unit: int
    low_us: int
    high_us: int
    statuses: tuple[EscCalibrationStatus, ...]

    @property
    def phases(self) -> list[EscCalPhase]:
        """The phases the board went through, in order (each once)."""
        out: list[EscCalPhase] = []
        for s in self.statuses:
            if not out or out[-1] is not s.phase:
                out.append(s.phase)
        return out


def program_esc(
    link: BenchLink,
    unit: int,
    program: EscProgram,
    *,
    confirm_unloaded: bool,
    ask_supply: Callable[[str], None] | None = None,
) -> EscOutcome:
    """Teach ``unit``'s rotor ESC ``program``'s endpoints. Raises :class:`ConfigError` without the
    operator's confirmation (nothing is sent), :class:`CommandFailed` if the board refuses (armed:
    BAD_STATE, busy, ...), :class:`EscProgrammingAborted` if it stops early, :class:`LinkTimeout` if it
    never finishes. ``ask_supply(prompt)`` returns once the operator has connected the ESC's supply
    (boards without a supply switch, which wait 60 s for it; without a callback such a board's request
    is an error and the procedure is aborted)."""
    if not confirm_unloaded:
        raise ConfigError(
            "the ESC sees its full-throttle pulse during programming: confirm that the rotor is off or "
            "unloaded (--confirm-unloaded)",
            "confirm_unloaded",
        )
    link.check_unit(unit)
    client = link.client
    link.take_statuses()
    client.wait(client.command(program.message(unit)))
    seen: list[EscCalibrationStatus] = []
    asked = False
    end = link.now + program.duration_s + 5.0
    while True:
        link.wait(max(min(0.1, end - link.now), 0.0))
        seen += [s for s in link.take_statuses() if s.unit == unit]
        phase = seen[-1].phase if seen else None
        if phase is EscCalPhase.DONE:
            return EscOutcome(unit, program.low_us, program.high_us, tuple(seen))
        if phase is EscCalPhase.ABORTED:
            raise EscProgrammingAborted(unit, seen[-1].abort)
        if phase is EscCalPhase.WAIT_SUPPLY and not asked:
            asked = True
            if ask_supply is None:
                client.disarm()  # aborts it: the ESC is left at minimum
                raise ConfigError(
                    "the board has no ESC supply switch and asks for the ESC's supply to be connected; "
                    "run interactively (or give the board a switch)",
                    "ask_supply",
                )
            ask_supply(f"Connect the supply of unit {unit}'s ESC now (it sees {program.high_us} us)")
            client.wait(client.command(program.message(unit, EscCalStep.SUPPLY_APPLIED)))
            end = link.now + (program.high_ms + program.low_ms) / 1000.0 + 5.0
        if link.now >= end:
            name = "nothing" if phase is None else phase.name
            raise LinkTimeout(f"ESC calibration of unit {unit}: no end reported (last phase: {name})")
