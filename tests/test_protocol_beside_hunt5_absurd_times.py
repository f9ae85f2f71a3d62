"""Beside the tested clocks (finite times, jumps forward), times given to the reliable sender that are absurd:
not a finite number of seconds, or so far out that a try's timeout is lost in their rounding. A command sent
at NaN got a NaN deadline — no later time is past it — so it was never retried and never failed: PENDING for
ever, ``next_deadline()`` NaN, a caller waiting on it hung. A poll at NaN did nothing, silently; one at
``inf`` moved every deadline to inf, the same hang one poll later. Each is now refused with a ConfigError
naming the call, and the sender keeps its state (no sequence number used, nothing settled)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.errors import ConfigError
from protocol.frame import decode_stream, encode_frame
from protocol.messages import Ack, Arm, Disarm
from protocol.reliable import CommandState, ReliableSender, RetryPolicy

NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf, -math.nan])


@settings(max_examples=60, deadline=None)
@given(
    bad=NON_FINITE, good=st.floats(-1e9, 1e9), call=st.sampled_from(["send", "poll", "on_frame", "abandon"])
)
def test_a_time_that_is_not_finite_is_refused_and_the_sender_keeps_its_state(bad, good, call):
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.1, max_tries=3))
    earlier, _ = sender.send(Arm(), good)
    next_seq = sender.framer.next_seq
    [ack] = decode_stream(encode_frame(Ack(msg_id=earlier.msg_id, seq=earlier.seq), 0, 0))
    args = {
        "send": (Disarm(), bad),
        "poll": (bad,),
        "on_frame": (ack, bad),
        "abandon": (bad,),
    }[call]
    with pytest.raises(ConfigError, match=f"ReliableSender.{call}.*finite"):
        getattr(sender, call)(*args)
    assert sender.framer.next_seq == next_seq  # no sequence number used
    assert earlier.state is CommandState.PENDING and sender.pending == [earlier]
    assert sender.next_deadline() == pytest.approx(good + 0.1)
    # ... and it still retries, then fails, on finite times
    now = good
    while earlier.state is CommandState.PENDING:
        now = sender.next_deadline()
        sender.poll(now)
    assert earlier.state is CommandState.FAILED and earlier.tries == 3


@settings(max_examples=200, deadline=None)
@given(
    now=st.one_of(
        st.floats(allow_nan=False, allow_infinity=False),
        st.sampled_from([1e9, 1.7e18, -1.7e18, 1e160, 1.7e308, 2.0**53, 2.0**52 * 0.1]),
    ),
    timeout_s=st.floats(1e-3, 10.0),
    max_timeout_s=st.floats(10.0, 1e6),
)
def test_a_try_waits_its_timeout_whatever_the_time_or_the_time_is_refused(now, timeout_s, max_timeout_s):
    """A time so far out that ``now + timeout`` rounds back to ``now`` (a time in ns taken for s: 1.7e18)
    made every try time out the moment it was sent: the command failed after all its tries at one instant,
    never waiting for an answer."""
    sender = ReliableSender(policy=RetryPolicy(timeout_s=timeout_s, max_tries=3, max_timeout_s=max_timeout_s))
    try:
        cmd, _ = sender.send(Arm(), now)
    except ConfigError as refused:
        assert "ReliableSender.send" in str(refused)
        assert sender.framer.next_seq == 0 and sender.pending == []
        return
    deadline = sender.next_deadline()
    assert deadline is not None and now < deadline < math.inf
    assert sender.poll(now) == b""  # not due at the instant it was sent
    while cmd.state is CommandState.PENDING:
        assert now < (deadline := sender.next_deadline()) < math.inf
        now = deadline
        sender.poll(now)
    assert cmd.tries == 3
