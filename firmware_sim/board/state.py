"""The board's state machine as a pure transition function (no clocks, no outputs).

::

            reset (power-on, watchdog, brown-out)
                 │
                 ▼
    ┌──────►  BOOT ──Hello──►  DISARMED ◄──Disarm / Hello── ARMED, FAILSAFE
    │                           │    ▲
    │                          Arm   │ Disarm / Hello
    │                           ▼    │
    │                          ARMED ──link lost──► FAILSAFE ──Arm──► ARMED
    └── any state on reset

* Motors move only in ARMED (after an acknowledged ``Arm``).
* Leaving FAILSAFE needs a fresh ``Hello`` (→ DISARMED) or ``Arm`` (→ ARMED), never just a setpoint.
* ``Arm`` is refused in BOOT (no session: ``BAD_STATE``) and while the power manager sheds load
  (``POWER``); ``Disarm`` and ``SetMode`` are refused in BOOT; ``SetMode`` only in DISARMED.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from protocol.messages import BoardState, NackReason


class Event(enum.Enum):
    RESET = "reset"
    HELLO = "hello"  # a compatible Hello (version and schema hash match)
    ARM = "arm"
    DISARM = "disarm"
    SET_MODE = "set_mode"
    LINK_LOST = "link_lost"


@dataclass(frozen=True, slots=True)
class Transition:
    """Result of an event: the new state, and for commands the NACK reason (None = accepted)."""

    state: BoardState
    refused: NackReason | None = None

    @property
    def accepted(self) -> bool:
        return self.refused is None


def transition(state: BoardState, event: Event, *, power_ok: bool = True) -> Transition:
    """Apply ``event`` to ``state``. ``power_ok`` is False while load is shed (Arm is then refused)."""
    if event is Event.RESET:
        return Transition(BoardState.BOOT)
    if event is Event.HELLO:
        return Transition(BoardState.DISARMED)
    if event is Event.LINK_LOST:
        return Transition(BoardState.FAILSAFE if state is BoardState.ARMED else state)
    if state is BoardState.BOOT:
        return Transition(state, NackReason.BAD_STATE)
    if event is Event.ARM:
        if not power_ok:
            return Transition(state, NackReason.POWER)
        return Transition(BoardState.ARMED)
    if event is Event.DISARM:
        return Transition(BoardState.DISARMED)
    if event is Event.SET_MODE:
        if state is not BoardState.DISARMED:
            return Transition(state, NackReason.BAD_STATE)
        return Transition(state)
    raise ValueError(f"unknown event {event!r}")  # pragma: no cover - Event is closed


def motors_enabled(state: BoardState) -> bool:
    """Whether setpoints may move the motors in ``state``."""
    return state is BoardState.ARMED
