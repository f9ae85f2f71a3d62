"""Teaching a rotor ESC its endpoints from the host: ``EscCalibrate`` and the board's reports of it.

The board runs and times the procedure (docs/protocol.md, "ESC endpoint programming"); the host starts
it, answers the board's request for the ESC supply on a board without a supply switch (an
:class:`~hil.calibration.operator.Operator` is asked; the operator connects it, then the host says so),
and follows its ``EscCalibrationStatus`` reports to the end. The board holds that request only while its
link lives, so the host never blocks on the operator: it keeps servicing the link and looks at the answer
between waits. The operator's statement that the rotor is off or unloaded
is required here (``confirm_unloaded``) and carried to the board in the command's ``confirm`` field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from protocol.errors import CommandFailed, ConfigError, FieldRangeError, HilError, LinkTimeout, ProtocolError
from protocol.messages import (
    ESC_CALIBRATION_CONFIRM,
    ESC_SUPPLY_WAIT_MS,
    EscCalAbort,
    EscCalibrate,
    EscCalibrationStatus,
    EscCalPhase,
    EscCalStep,
    encode_payload,
)

from .benchlink import BenchLink
from .operator import Answer, Operator
from .progress import Report, duration, no_report

OPERATOR_POLL_S = 0.05
"""While the operator is asked, the link is serviced in waits this long (s) between looks at the answer."""
REMIND_S = 10.0
"""While the operator is asked, how often the time the board still waits is reported (s)."""


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

    OPTIONS: ClassVar[dict[str, str]] = {
        "low_us": "--esc-low",
        "high_us": "--esc-high",
        "supply_off_ms": "--supply-off-ms",
        "high_ms": "--high-ms",
        "low_ms": "--low-ms",
    }
    """The ``hil calibrate esc``/``unit`` option that sets each field."""

    def __post_init__(self) -> None:
        """Refuse a field its ``EscCalibrate`` cannot carry (a ``--high-ms -1``, a ``--supply-off-ms`` of
        hours), as a :class:`ConfigError` naming its option, before a board is opened: it was found when
        the command was encoded, with the board connected and put to rest, and named the wire's field
        (``EscCalibrate.high_ms``), not the option. The ranges are the message's own (its codec checks)."""
        try:
            encode_payload(self.message(0))
        except FieldRangeError as exc:
            option = self.OPTIONS.get(exc.field, exc.field)
            raise ConfigError(f"{exc.value!r} is outside what the board takes ({exc})", option) from None

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
    operator: Operator | None = None,
    report: Report = no_report,
) -> EscOutcome:
    """Teach ``unit``'s rotor ESC ``program``'s endpoints. Raises :class:`ConfigError` without the
    operator's confirmation (nothing is sent), :class:`CommandFailed` if the board refuses (armed:
    BAD_STATE, busy, ...), :class:`EscProgrammingAborted` if it stops early,
    :class:`~hil.calibration.benchlink.BoardLost` at once if the board resets or its link is lost
    meanwhile (the procedure is gone with it), :class:`LinkTimeout` if it never finishes. A board
    without a supply switch asks for the ESC's supply and holds the procedure (up to
    ``ESC_SUPPLY_WAIT_MS``) while its link lives: ``operator.ask`` shows the request and the link
    keeps being serviced until the answer comes (without an operator such a board's request is an error
    and the procedure is aborted). ``report`` gets one line per phase, with the time left."""
    if not confirm_unloaded:
        raise ConfigError(
            "the ESC sees its full-throttle pulse during programming: confirm that the rotor is off or "
            "unloaded (--confirm-unloaded)",
            "confirm_unloaded",
        )
    link.check_unit(unit)
    client = link.client
    link.take_statuses()
    link.check_board(f"the time before the ESC programming of unit {unit}")
    link.touched = True
    client.wait(client.command(program.message(unit)))
    seen: list[EscCalibrationStatus] = []
    answer: Answer | None = None
    waiting = False  # the operator is being waited for
    shown: EscCalPhase | None = None
    reminded = link.now
    end = link.now + program.duration_s + 5.0
    while True:
        given = False
        if waiting:
            assert answer is not None
            link.wait(OPERATOR_POLL_S)
            try:  # a lockstep board waits in the operator's time: the wall clock paces it
                given = answer.wait(OPERATOR_POLL_S) if client.lockstep else answer.ready()
            except HilError:
                client.disarm()  # nobody can answer: abort it, the ESC is left at minimum
                raise
        else:
            link.wait(max(min(0.1, end - link.now), 0.0))
        seen += [s for s in link.take_statuses() if s.unit == unit]
        phase = seen[-1].phase if seen else None
        if phase not in (EscCalPhase.DONE, EscCalPhase.ABORTED):
            # reset or link lost: the procedure is gone with it (a reset board starts idle, a board that
            # loses its link aborts it), so say so now rather than wait out the procedure's time
            at = "before its first report" if phase is None else f"in phase {phase.name}"
            link.check_board(f"the ESC programming of unit {unit} ({at}): its ESC was not taught")
        if phase is not None and phase is not shown:
            shown = phase
            report(_phase_line(unit, program, phase))
        if phase is EscCalPhase.DONE:
            return EscOutcome(unit, program.low_us, program.high_us, tuple(seen))
        if phase is EscCalPhase.ABORTED:
            raise EscProgrammingAborted(unit, seen[-1].abort)
        if phase is EscCalPhase.WAIT_SUPPLY and answer is None:
            if operator is None:
                client.disarm()  # aborts it: the ESC is left at minimum
                raise ConfigError(
                    "the board has no ESC supply switch and asks for the ESC's supply to be connected; "
                    "run interactively (or give the board a switch)",
                    "ask_supply",
                )
            answer = operator.ask(
                f"Connect the supply of unit {unit}'s ESC now (it sees {program.high_us} us)"
            )
            waiting = True
            reminded = link.now
            end = link.now + ESC_SUPPLY_WAIT_MS / 1000.0 + 5.0  # the board gives up first
        if waiting and given:
            waiting = False
            _supply_applied(link, unit, program, seen)
            end = link.now + (program.high_ms + program.low_ms) / 1000.0 + 5.0
        elif waiting and link.now - reminded >= REMIND_S and seen:
            reminded = link.now
            left = ESC_SUPPLY_WAIT_MS / 1000.0 - seen[-1].phase_ms / 1000.0
            report(f"unit {unit} ESC: still waiting for its supply; the board gives up in {duration(left)}")
        if link.now >= end:
            name = "nothing" if phase is None else phase.name
            raise LinkTimeout(f"ESC calibration of unit {unit}: no end reported (last phase: {name})")


def _supply_applied(
    link: BenchLink, unit: int, program: EscProgram, seen: list[EscCalibrationStatus]
) -> None:
    """Tell the board the operator connected the supply; if the board gave up meanwhile (its wait ran
    out), say that rather than its refusal of a step it no longer waits for."""
    client = link.client
    try:
        client.wait(client.command(program.message(unit, EscCalStep.SUPPLY_APPLIED)))
    except CommandFailed:
        link.wait(0.0)
        seen += [s for s in link.take_statuses() if s.unit == unit]
        if seen and seen[-1].phase is EscCalPhase.ABORTED:
            raise EscProgrammingAborted(unit, seen[-1].abort) from None
        raise


def _phase_line(unit: int, program: EscProgram, phase: EscCalPhase) -> str:
    """What the board does in ``phase`` and how long the procedure has left from its start (s)."""
    high, low, channel = program.high_us, program.low_us, 2 * unit + 1
    high_s, low_s = program.high_ms / 1000.0, program.low_ms / 1000.0
    steps: dict[EscCalPhase, tuple[int, str, float]] = {
        EscCalPhase.SUPPLY_OFF: (
            1,
            f"ESC supply cut for {duration(program.supply_off_ms / 1000.0)}, {high} us on channel {channel}",
            program.supply_off_ms / 1000.0 + high_s + low_s,
        ),
        EscCalPhase.WAIT_SUPPLY: (
            1,
            f"{high} us on channel {channel}, waiting for the operator to connect the ESC's supply (the "
            f"board waits {duration(ESC_SUPPLY_WAIT_MS / 1000.0)})",
            math.inf,
        ),
        EscCalPhase.HIGH: (
            2,
            f"{high} us for {duration(high_s)}: the ESC acknowledges (beeps)",
            high_s + low_s,
        ),
        EscCalPhase.LOW: (3, f"{low} us for {duration(low_s)}: the ESC stores both endpoints", low_s),
    }
    if phase in steps:
        index, what, left = steps[phase]
        after = (
            f"then about {duration(high_s + low_s)}" if math.isinf(left) else f"about {duration(left)} left"
        )
        return f"unit {unit} ESC: step {index}/3 {phase.name}: {what}; {after}"
    return f"unit {unit} ESC: {phase.name}"
