"""Beside the tested retry policies (backoff 1, a handful of tries): a policy its own checks accept, with a
backoff or a number of tries that takes the growing timeout past the float range. ``RetryPolicy.timeout``
raised ``OverflowError`` (a float power does not give inf) from ``ReliableSender.poll``: the command was
neither retried nor failed, and the board client's loop died with a traceback."""

from __future__ import annotations

import hypothesis.strategies as st
from hypothesis import example, given, settings

from protocol.frame import Deframer, Frame
from protocol.messages import Arm, Flags
from protocol.reliable import CommandState, ReliableSender, RetryPolicy


@settings(max_examples=150, deadline=None)
@given(
    timeout_s=st.floats(1e-3, 10.0),
    backoff=st.one_of(st.floats(1.0, 1e300), st.sampled_from([1.0, 2.0, 10.0, 1e160])),
    max_tries=st.integers(1, 40),
)
@example(timeout_s=0.1, backoff=1e160, max_tries=5)
@example(timeout_s=0.1, backoff=2.0, max_tries=1100)
def test_an_unanswered_command_is_retried_then_fails_whatever_the_backoff(
    timeout_s: float, backoff: float, max_tries: int
) -> None:
    policy = RetryPolicy(timeout_s=timeout_s, backoff=backoff, max_tries=max_tries, max_timeout_s=20.0)
    sender = ReliableSender(policy=policy)
    cmd, first = sender.send(Arm(), 0.0)
    deframer = Deframer()
    (sent,) = deframer.feed(first)
    assert isinstance(sent, Frame)
    now, retries, last_deadline = 0.0, 0, 0.0
    while cmd.state is CommandState.PENDING:
        deadline = sender.next_deadline()
        assert deadline is not None and last_deadline < deadline <= now + policy.max_timeout_s
        now = last_deadline = deadline
        for frame in deframer.feed(sender.poll(now)):
            assert isinstance(frame, Frame) and frame.seq == cmd.seq and frame.flags & Flags.RETRANSMIT
            retries += 1
    assert cmd.state is CommandState.FAILED and cmd.failure == f"no answer after {max_tries} tries"
    assert retries == max_tries - 1 == sender.stats.retransmits
    assert sender.next_deadline() is None
