"""Beside the tested clocks (finite, forward) and callbacks (ones that send or abandon): an injected clock
that steps back at drawn moments, and an ``on_settled`` that raises at a drawn settlement.

A clock stepped back left every pending try waiting for the time it had been given first: a minute back, no
retry for a minute past its timeout (``next_deadline`` a minute ahead), while a command sent meanwhile was
retried and failed first. Then a poll came that found the old command's retry due together with the new
one's failure; ``on_settled`` raised on that failure, and the retry's bytes — gathered, counted, its
deadline moved on — never reached the wire: the command had ``tries`` one higher than the board ever saw,
and failed one try early. ``abandon`` whose callback raised left every command after the first removed
from the sender but PENDING for ever, never told.

Checked on what went out: every command's ``tries`` equals the frames of it that the caller was given, a
pending one is never more than its try's timeout from being retried, and every command is told once."""

from __future__ import annotations

import hypothesis.strategies as st
import numpy as np
import pytest
from hypothesis import example, given, settings

from protocol.errors import ConfigError
from protocol.frame import Deframer, Frame
from protocol.messages import Arm, CalibrationRequest, ControlMode, Disarm, EscCalibrate, SetMode
from protocol.reliable import Command, CommandState, ReliableSender, RetryPolicy

MESSAGES = (Arm(), SetMode(ControlMode.SETPOINT), Disarm(), SetMode(ControlMode.RAW_PULSES))
UNRELATED = (Arm(), SetMode(ControlMode.SETPOINT), EscCalibrate(unit=0), CalibrationRequest(unit=1))
"""Four commands of which none supersedes another."""
POLICY = RetryPolicy(timeout_s=0.1, max_tries=4)


class CallbackFailed(Exception):
    """What the user's ``on_settled`` raises."""


def _drive(steps: list[tuple[str, float]], raise_at: int) -> None:
    """Run ``steps`` — ``("send", dt)``: a command at the clock moved by dt (s, may be negative);
    ``("poll", dt)``: a poll there — then poll on until every command has settled, ``on_settled`` raising at
    the ``raise_at``-th settlement; check what went out against each command's count of tries."""
    sender = ReliableSender(policy=POLICY)
    told: list[Command] = []
    on_wire: dict[int, int] = {}  # seq → frames of it the caller was given
    deframer = Deframer()

    def on_settled(cmd: Command) -> None:
        told.append(cmd)
        if len(told) - 1 == raise_at:
            raise CallbackFailed(f"told of {cmd!r}")

    def put(data: bytes) -> None:
        for frame in deframer.feed(data):
            assert isinstance(frame, Frame)
            on_wire[frame.seq] = on_wire.get(frame.seq, 0) + 1

    sender.on_settled = on_settled
    cmds: list[Command] = []
    now = 100.0
    for i, (what, dt) in enumerate(steps):
        now += dt
        try:
            if what == "send":
                cmd, data = sender.send(MESSAGES[i % len(MESSAGES)], now)
                cmds.append(cmd)
                put(data)
            else:
                put(sender.poll(now))
        except CallbackFailed:
            pass
        _check(sender, cmds, on_wire, now)
    while sender.pending:
        deadline = sender.next_deadline()
        assert deadline is not None
        now = max(now, deadline)
        try:
            put(sender.poll(now))
        except CallbackFailed:
            pass
        _check(sender, cmds, on_wire, now)
    for cmd in cmds:
        assert cmd.state is CommandState.FAILED
        assert on_wire.get(cmd.seq, 0) == cmd.tries, f"{cmd!r}: {on_wire.get(cmd.seq, 0)} frames went out"
        assert cmd.tries == POLICY.max_tries or cmd.superseded_by is not None, cmd
    assert sorted(map(id, told)) == sorted(map(id, cmds))  # each told once


def _check(sender: ReliableSender, cmds: list[Command], on_wire: dict[int, int], now: float) -> None:
    for cmd in sender.pending:
        assert on_wire.get(cmd.seq, 0) == cmd.tries, f"{cmd!r}: {on_wire.get(cmd.seq, 0)} frames went out"
        # a step back within the shortest timeout is readings out of order, left alone: a try may wait
        # that much longer
        slack = POLICY.timeout_s + 1e-9
        assert cmd.deadline - now <= POLICY.timeout(cmd.tries) + slack, f"{cmd!r} waits past its timeout"


STEPS = st.lists(
    st.tuples(
        st.sampled_from(["send", "poll", "poll"]),
        st.one_of(st.floats(0.0, 0.3), st.floats(-120.0, -0.001)),  # forward, or the clock steps back
    ),
    min_size=1,
    max_size=14,
)


@settings(max_examples=300, deadline=None)
@given(steps=STEPS, raise_at=st.integers(-1, 6))
@example(  # an Arm at 101, the clock steps back a second, a Disarm retried to its last try; then one poll
    steps=[("send", 1.0), ("send", -1.0), ("poll", 0.1), ("poll", 0.1), ("poll", 0.1), ("poll", 1.0)],
    raise_at=0,
)
def test_a_clock_stepping_back_or_a_raising_callback_loses_no_try_and_stalls_none(steps, raise_at):
    _drive(steps, raise_at)


def test_a_clock_stepped_back_a_minute_retries_after_the_timeout_left_not_a_minute_later():
    sender = ReliableSender(policy=POLICY)
    cmd, _ = sender.send(Arm(), 1000.0)
    assert sender.poll(1000.05) == b""
    assert sender.poll(940.0) == b""  # a minute back: 0.05 s of the try's 0.1 s were left, and still are
    assert sender.stats.clock_steps_back == 1
    assert (due := sender.next_deadline()) == pytest.approx(940.05)
    assert len(Deframer().feed(sender.poll(due))) == 1 and cmd.tries == 2
    assert sender.poll(due + 0.09) == b""  # no storm: the next try waits its timeout


@settings(max_examples=100, deadline=None)
@given(n=st.integers(2, 4), raise_at=st.integers(0, 3))
def test_abandon_settles_and_tells_every_command_though_a_callback_raises(n, raise_at):
    told: list[Command] = []

    def on_settled(cmd: Command) -> None:
        told.append(cmd)
        if len(told) - 1 == raise_at:
            raise CallbackFailed(f"told of {cmd!r}")

    sender = ReliableSender(policy=POLICY)
    cmds = [sender.send(UNRELATED[i], 0.0)[0] for i in range(n)]
    sender.on_settled = on_settled
    if raise_at < n:
        with pytest.raises(CallbackFailed):
            sender.abandon(1.0, "link lost")
    else:
        sender.abandon(1.0, "link lost")
    assert sender.pending == []
    assert [c.state for c in cmds] == [CommandState.FAILED] * n
    assert told == cmds and sender.stats.failed == n


@settings(max_examples=300, deadline=None)
@given(
    now=st.one_of(
        st.floats(-(2.0**60), 2.0**60),
        st.builds(lambda k, d: 2.0**k - d, st.integers(40, 56), st.floats(0.0, 64.0)),  # below a binade's end
    ),
    timeout_s=st.floats(1e-3, 10.0),
    max_tries=st.integers(1, 6),
)
def test_a_command_sent_is_polled_at_its_own_deadlines_without_one_refused(now, timeout_s, max_tries):
    """Sent at 9007199254740989.0 s (just below 2**53) with a 1 s timeout, a command's third deadline,
    2**53, had floats 2 s apart: ``poll`` at the sender's own ``next_deadline()`` raised ConfigError."""
    sender = ReliableSender(policy=RetryPolicy(timeout_s=timeout_s, max_tries=max_tries, max_timeout_s=10.0))
    try:
        cmd, _ = sender.send(Arm(), now)
    except ConfigError as refused:
        assert "ReliableSender.send" in str(refused)
        return
    while cmd.state is CommandState.PENDING:
        deadline = sender.next_deadline()
        assert deadline is not None and deadline > now
        now = deadline
        sender.poll(now)
    assert cmd.tries == max_tries


@pytest.mark.parametrize(
    "now", [True, 10**400, -(10**400), "12.5", None], ids=["bool", "1e400", "-1e400", "str", "None"]
)
def test_a_time_that_is_no_number_is_refused_naming_the_call(now):
    sender = ReliableSender(policy=POLICY)
    for call, args in (("send", (Arm(), now)), ("poll", (now,)), ("abandon", (now,))):
        with pytest.raises(ConfigError, match=f"ReliableSender.{call}.*finite"):
            getattr(sender, call)(*args)
    assert sender.framer.next_seq == 0 and sender.pending == []


@pytest.mark.parametrize("name", ["timeout_s", "backoff", "max_timeout_s"])
@pytest.mark.parametrize("value", [10**400, -(10**400), True, "0.1"], ids=["1e400", "-1e400", "bool", "str"])
def test_a_retry_policy_refuses_what_is_no_finite_number_naming_the_field(name, value):
    """10**400 was an ``OverflowError`` out of ``math.isfinite``, not the policy's ConfigError."""
    with pytest.raises(ConfigError, match=f"RetryPolicy.{name}"):
        RetryPolicy(**{name: value})


def test_a_retry_policy_takes_numpy_numbers_as_the_floats_they_hold():
    policy = RetryPolicy(timeout_s=np.float32(0.25), backoff=np.array(2.0), max_timeout_s=np.float64(1.0))
    assert policy == RetryPolicy(timeout_s=0.25, backoff=2.0, max_timeout_s=1.0)
    assert [policy.timeout(k) for k in (1, 2, 3, 4)] == [0.25, 0.5, 1.0, 1.0]


@settings(max_examples=100, deadline=None)
@given(jitter=st.lists(st.floats(0.0, 0.99 * POLICY.timeout_s), min_size=1, max_size=50))
def test_readings_given_out_of_order_move_no_deadline(jitter):
    """Two callers' readings of one clock given in the other order (a reader thread's and the loop's: a
    step back within the shortest timeout), any number of times: every deadline stays where it was, not
    pulled earlier by each step back."""
    sender = ReliableSender(policy=POLICY)
    cmd, _ = sender.send(Arm(), 50.0)
    deadline = cmd.deadline
    for back in jitter:
        assert sender.poll(50.0 - back) == b""
        assert sender.poll(50.0) == b""
    assert cmd.deadline == deadline and sender.stats.clock_steps_back == 0
