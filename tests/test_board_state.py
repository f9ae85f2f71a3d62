"""The board's state machine: the pure transition table, and a Hypothesis state machine driving the real
sans-IO Board in lockstep against a small model (states, reset causes, ACK/NACK, link loss, hang)."""

from __future__ import annotations

import pytest
from conformance.host import LockstepHost
from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from firmware_sim.board import Board, McuPhase
from firmware_sim.board.config import BoardConfig
from firmware_sim.board.state import Event, motors_enabled, transition
from hil.timing.clock import LockstepClock
from protocol.messages import (
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    Disarm,
    Heartbeat,
    HelloReply,
    Nack,
    NackReason,
    ResetCause,
    UnitSetpoint,
)

B, D, A, F = BoardState.BOOT, BoardState.DISARMED, BoardState.ARMED, BoardState.FAILSAFE


@pytest.mark.parametrize(
    ("state", "event", "power_ok", "new", "refused"),
    [
        (B, Event.ARM, True, B, NackReason.BAD_STATE),
        (B, Event.DISARM, True, B, NackReason.BAD_STATE),
        (B, Event.SET_MODE, True, B, NackReason.BAD_STATE),
        (B, Event.HELLO, True, D, None),
        (B, Event.LINK_LOST, True, B, None),
        (D, Event.ARM, True, A, None),
        (D, Event.ARM, False, D, NackReason.POWER),
        (D, Event.LINK_LOST, True, D, None),
        (A, Event.LINK_LOST, True, F, None),
        (A, Event.SET_MODE, True, A, NackReason.BAD_STATE),
        (A, Event.DISARM, True, D, None),
        (A, Event.HELLO, True, D, None),
        (F, Event.ARM, True, A, None),
        (F, Event.HELLO, True, D, None),
        (F, Event.DISARM, True, D, None),
        (F, Event.SET_MODE, True, F, NackReason.BAD_STATE),
        (F, Event.LINK_LOST, True, F, None),
        (A, Event.RESET, True, B, None),
        (F, Event.RESET, True, B, None),
    ],
)
def test_transition_table(state, event, power_ok, new, refused):
    tr = transition(state, event, power_ok=power_ok)
    assert (tr.state, tr.refused) == (new, refused)
    assert tr.accepted is (refused is None)


def test_only_armed_moves_motors():
    assert [s for s in BoardState if motors_enabled(s)] == [A]


CFG = BoardConfig(
    n_units=2,
    frame_rate_hz=100.0,
    telemetry_rate_hz=10.0,
    link_timeout_s=0.25,
    mcu_watchdog_s=0.3,
    boot_time_s=0.05,
)
MS = 0.001


class BoardModel(RuleBasedStateMachine):
    """Rules send host messages (or let time pass / hang the MCU); the model predicts the board."""

    @initialize()
    def start(self):
        self.clock = LockstepClock()
        self.board = Board(CFG, self.clock)
        self.host = LockstepHost(self.board, self.clock)
        self.state = B
        self.cause = ResetCause.POWER_ON
        self.ready_at = CFG.boot_time_s
        self.last_rx: float | None = None
        self.session = False
        self.armed_setpoint = False
        self._advance_to(self.ready_at + MS)

    # ------------------------------------------------------------ helpers
    def _advance_to(self, t: float) -> None:
        self.clock.set(max(t, self.clock.now()))
        self.board.step()
        self.host.poll(0.0)

    def _let_time_pass(self, dt: float) -> None:
        """Advance ``dt``, applying the link watchdog to the model exactly when it expires."""
        t0, t1 = self.clock.now(), self.clock.now() + dt
        if self.session and self.last_rx is not None:
            expiry = self.last_rx + CFG.link_timeout_s
            if expiry <= t1 + 1e-9 and self.state is A:
                self.state = F
        self._advance_to(t1)
        assert self.clock.now() >= t0

    def _exchange(self, message):
        """Send one frame now (the board handles it on this tick) and give it 2 ms to answer."""
        start = len(self.host.received)
        self.host.send(message)
        self.last_rx = self.clock.now()
        self._let_time_pass(2 * MS)
        return self.host.received[start:]

    def _answer(self, replies):
        answers = [m for m in replies if isinstance(m, (Ack, Nack))]
        assert len(answers) == 1, replies
        return answers[0]

    # ------------------------------------------------------------ rules
    @rule()
    def hello(self):
        replies = self._exchange(self.host_hello())
        reply = [m for m in replies if isinstance(m, HelloReply)]
        assert len(reply) == 1
        assert reply[0].reset_cause == self.cause
        assert reply[0].state == D
        self.state = D
        self.session = True

    def host_hello(self):
        from protocol.messages import SCHEMA_HASH, Hello

        return Hello(schema_hash=SCHEMA_HASH)

    @rule()
    def arm(self):
        answer = self._answer(self._exchange(Arm()))
        if self.state is B:
            assert isinstance(answer, Nack) and answer.reason == NackReason.BAD_STATE
        else:
            assert isinstance(answer, Ack)
            if self.state is not A:
                self.armed_setpoint = False
            self.state = A

    @rule()
    def disarm(self):
        answer = self._answer(self._exchange(Disarm()))
        if self.state is B:
            assert isinstance(answer, Nack) and answer.reason == NackReason.BAD_STATE
        else:
            assert isinstance(answer, Ack)
            self.state = D

    @rule(speed=st.sampled_from([0.0, 200.0, 400.0]))
    def setpoint(self, speed):
        self._exchange(ActuatorSetpoint(units=(UnitSetpoint(0.0, speed), UnitSetpoint(0.0, speed))))
        if self.state is A:
            self.armed_setpoint = speed > 0

    @rule()
    def heartbeat(self):
        self._exchange(Heartbeat())

    @rule(dt=st.sampled_from([0.01, 0.1, 0.2, 0.3]))
    def wait(self, dt):
        self._let_time_pass(dt)

    @rule(speed=st.sampled_from([0.0, 400.0]))
    def handshake_arm_and_command(self, speed):
        """The host's usual opening, as one step: the states the faults act on are reached often."""
        self.hello()
        self.arm()
        self.setpoint(speed)

    @precondition(lambda self: self.state is A)
    @rule(extra=st.sampled_from([0.0, 0.5]))
    def lose_the_link(self, extra):
        """Silence for the link timeout plus a pulse frame (and more): the board must be in FAILSAFE."""
        self._let_time_pass(CFG.link_timeout_s + 1.0 / CFG.frame_rate_hz + extra * CFG.link_timeout_s)
        assert self.state is F

    @precondition(lambda self: self.board.phase is McuPhase.RUNNING)
    @rule()
    def hang(self):
        t = self.clock.now()
        self.board.faults.hang()
        reset_at = t + CFG.mcu_watchdog_s
        # While hung the link watchdog does not run: the state is frozen until the reset.
        self.clock.set(reset_at - MS)
        self.board.step()
        assert self.board.phase is McuPhase.HUNG
        assert self.board.state is self.state
        self._advance_to(reset_at + CFG.boot_time_s + MS)
        assert self.board.resets[-1].t == pytest.approx(reset_at, abs=1e-6)
        self.state, self.cause = B, ResetCause.WATCHDOG
        self.session, self.last_rx, self.armed_setpoint = False, None, False

    # ------------------------------------------------------------ invariants
    @invariant()
    def same_state(self):
        assert self.board.state is self.state

    @invariant()
    def same_reset_cause(self):
        assert self.board.reset_cause is self.cause

    @invariant()
    def rotors_move_only_when_armed(self):
        board = self.board
        if board.phase is not McuPhase.RUNNING:
            return
        v = board.power.battery_v
        rotors = board.commanded_outputs()[1::2]
        speeds = [board.units[i].steady_rotor_speed(w, v) for i, w in enumerate(rotors)]
        if self.state is not A:
            assert all(w == CFG.rotor_safe_us for w in rotors), rotors
            assert speeds == [0.0] * CFG.n_units
        elif not self.armed_setpoint:
            assert speeds == [0.0] * CFG.n_units, (rotors, speeds)
        else:
            assert all(s > 0 for s in speeds), (rotors, speeds)


BoardModel.TestCase.settings = settings(max_examples=150, stateful_step_count=30, deadline=None)
TestBoardStateMachine = BoardModel.TestCase
