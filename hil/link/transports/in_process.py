"""The interface of a board that runs inside the host's process (the built-in emulator, ``emu://``).

``hil`` does not import the emulator: ``firmware_sim`` registers it as the ``emu`` (and ``spawn``)
transport through the ``vscmg_hil.transports`` entry point, and what the host needs of an in-process
board beyond a byte pipe is spelled here, so the layers run one way (``protocol`` ← ``hil`` ←
``firmware_sim``). Such a board runs on the host's clock (a :class:`~hil.timing.clock.LockstepClock` makes
a whole closed loop run faster than real time and replay exactly), tells when it next has something to
do, and may carry a simulated world (spacecraft, VSCMG plant, phone) that its pulses drive.
"""

from __future__ import annotations

import abc
import threading
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

from .base import Transport

if TYPE_CHECKING:
    from hil.estimation.sensors import SensorSample
    from hil.timing.clock import Clock


class WorldTruth(Protocol):
    """What the simulated world really does: attitude ``R`` (3, 3) body → ENU, body rate ``omega`` (3,)
    rad/s, at board time ``t`` (s)."""

    @property
    def t(self) -> float: ...

    @property
    def R(self) -> Any: ...

    @property
    def omega(self) -> Any: ...


class SimulatedWorld(Protocol):
    """A world the board's pulses drive: stepped to the board clock's present, it returns the phone
    samples taken meanwhile.

    A lockstep run advances it every plant step (the board's telemetry and power draw then see the units
    of the present step), and before each estimator and control activation. A world that keeps the board's
    view of its units current by itself between its own steps may say how long one ``advance_to`` may then
    span, as a float attribute ``advance_period_s`` (s): the runtime advances it that often instead (many
    plant steps per call; the phone's samples and the host's view are the same)."""

    def advance_to(self, t: float) -> list[SensorSample]: ...

    def truth(self) -> WorldTruth: ...


class WorldStream(Protocol):
    """A world stepped in real time by its own thread, streaming its phone to a URL; ``check`` raises the
    thread's error, ``max_lag_s`` is the furthest it fell behind the board's clock after start-up (s)."""

    @property
    def max_lag_s(self) -> float: ...

    def check(self) -> None: ...

    def close(self) -> None: ...


class PulseRecord(NamedTuple):
    """Frames from an in-process board's own record (:meth:`InProcessBoard.pulse_record`): ``frames``
    ``(t, widths, state)`` (s, µs per channel or None, ``BoardState`` value), oldest first; ``total`` the
    board's frame count now (ask for the frames since it next time); ``missed`` frames the record no longer
    held; ``rotor_channels`` and ``rotor_safe_us``: the outputs no frame may drive above the safe width
    unless the board is ARMED."""

    frames: list[tuple[float, tuple[float | None, ...], int | None]]
    total: int
    missed: int
    rotor_channels: tuple[int, ...]
    rotor_safe_us: float


class InProcessBoard(Transport):
    """A transport whose board lives in this process. ``lock`` guards the board: hold it to touch the
    board (or its world) from another thread."""

    lock: threading.Condition

    @property
    @abc.abstractmethod
    def clock(self) -> Clock | None:
        """The clock the board runs on (None until bound)."""

    @abc.abstractmethod
    def bind_clock(self, clock: Clock) -> None:
        """Run the board on ``clock`` (the board client calls it with its own clock)."""

    @abc.abstractmethod
    def next_wake(self) -> float:
        """Clock time (s) at which the board next does something (a lockstep driver advances to it)."""

    @abc.abstractmethod
    def pulse_record(self, since: int) -> PulseRecord:
        """The pulse frames the board started after its first ``since`` (its own record of what was on the
        pins, each with the protocol state it started in), for checks on what a run really did."""

    @abc.abstractmethod
    def open_world(self, scenario: Any, seed: int | None = None) -> SimulatedWorld:
        """The scenario's simulated world (:class:`hil.scenario.Scenario`), driven by this board's
        pulses; ``seed`` overrides the scenario's (the phone's noise)."""

    @abc.abstractmethod
    def stream_world(self, world: SimulatedWorld, phone_url: str) -> WorldStream:
        """Step ``world`` in real time in a thread and stream its phone to ``phone_url``."""
