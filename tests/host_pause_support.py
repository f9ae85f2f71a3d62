"""A lockstep run of the short default scenario whose *host* stops for a while, as a host process paused
(SIGSTOP, swapped out) does in real time: at a drawn moment the clock jumps ``pause_s`` at the start of a
control tick, before the host has done anything in it. The board and its world go on meanwhile (the
in-process board is stepped to the present when the host next serves it), so it fails safe by its link
watchdog and its telemetry waits as a backlog — what a wall-clock host finds after SIGCONT, reproduced
by its seed (tests/test_host_paused_at_the_end.py, tests/test_host_paused_mid_run.py)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from fault_support import short_scenario
from observer_support import SilentObserver

from hil.runtime import RunOptions, run
from hil.runtime.observer import Observers, RunStart
from hil.runtime.record import RunRecorder
from hil.scenario import Scenario
from hil.timing.clock import LockstepClock
from protocol.messages import BoardState


class HostPause(SilentObserver):
    """A run observer that stops the host ``pause_s`` at the first control tick at or after ``at_s`` from
    the slew's start (the clock jumps: nothing of the host runs meanwhile, the board does)."""

    def __init__(self, at_s: float, pause_s: float) -> None:
        self.at_s, self.pause_s = at_s, pause_s
        self.paused_at: float | None = None  # host time the pause started
        self.start: RunStart | None = None

    def started(self, start: RunStart) -> None:
        self.start = start

    def tick(self, t: float) -> None:
        assert self.start is not None
        slew = self.start.host.phases.slew_start
        if self.paused_at is None and slew is not None and t >= slew + self.at_s:
            self.paused_at = t
            clock = self.start.scheduler.clock
            assert isinstance(clock, LockstepClock)
            clock.advance(self.pause_s)


@dataclass
class PausedRun:
    scenario: Scenario
    recorder: RunRecorder
    pause: HostPause
    summary: dict[str, Any]
    events: list[dict[str, Any]]

    @property
    def slew_start(self) -> float:
        return next(e["t"] for e in self.events if e["kind"] == "slew_start")

    @property
    def end(self) -> float:
        """Host time the run's time was up (its slew's start + its duration; no operator here)."""
        return self.slew_start + self.scenario.slew.duration_s

    def board_state_after(self, dt: float = 0.1) -> BoardState:
        """The board's own state ``dt`` s after the run let go of it (well within its link watchdog): what
        every command the host sent, the last Disarm included, made of it."""
        board = self.recorder._board
        assert board is not None
        emulated = board.board  # type: ignore[attr-defined]
        clock = emulated.clock
        assert isinstance(clock, LockstepClock)
        clock.advance(dt)
        with board.lock:
            emulated.step()
            return BoardState(emulated.state)


def paused_run(at_s: float, pause_s: float, recover_within_s: float = 15.0) -> PausedRun:
    """The short scenario, its host paused ``pause_s`` from ``at_s`` after the slew's start."""
    sc = short_scenario()
    recorder = RunRecorder(sc.n_units)
    pause = HostPause(at_s, pause_s)
    result = run(
        sc,
        RunOptions(
            out_root=None,
            observer=Observers(recorder, pause),
            rows_to_observer=True,
            recover_within_s=recover_within_s,
        ),
    )
    assert pause.paused_at is not None, "the pause never came"
    return PausedRun(sc, recorder, pause, result.summary, result.events)
