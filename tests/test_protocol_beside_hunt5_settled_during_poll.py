"""Beside the tested retries (commands that each time out on their own): ``on_settled``, told of one command
failing inside ``ReliableSender.poll``, sends another command or abandons them all — as the session does (its
handshake failure takes the link down; an operator answers a failed command with a Disarm). ``poll`` went on
with the commands it had taken as due at its call: one the callback had superseded or abandoned was sent
again (a superseded Disarm retried after the command that superseded it, its ``tries`` still growing though
it was FAILED) or, at its last try, settled a second time — ``KeyError`` out of ``poll``. And a command
sent from ``on_settled`` while ``send`` was settling an older one did not supersede the command being
sent (not yet pending): both stayed pending, retried side by side, the older one after the newer."""

from __future__ import annotations

import hypothesis.strategies as st
from hypothesis import example, given, settings

from protocol.frame import Deframer, Frame
from protocol.messages import Arm, ControlMode, Disarm, SetMode
from protocol.reliable import Command, CommandState, ReliableSender, RetryPolicy

MESSAGES = (Arm(), Disarm(), SetMode(ControlMode.SETPOINT), SetMode(ControlMode.RAW_PULSES))


@settings(max_examples=200, deadline=None)
@given(
    first=st.lists(st.sampled_from(MESSAGES), min_size=1, max_size=6),
    max_tries=st.integers(1, 4),
    react_at=st.integers(0, 5),
    reaction=st.one_of(st.sampled_from(MESSAGES), st.just("abandon")),
)
@example(first=[SetMode(ControlMode.SETPOINT), Disarm()], max_tries=1, react_at=0, reaction=Disarm())
@example(first=[Arm(), SetMode(ControlMode.SETPOINT)], max_tries=3, react_at=0, reaction="abandon")
@example(first=[Arm(), Arm()], max_tries=1, react_at=0, reaction=Arm())  # sent from inside send
def test_a_command_settled_by_a_callback_during_poll_is_neither_sent_again_nor_settled_twice(
    first: list[object], max_tries: int, react_at: int, reaction: object
) -> None:
    sender = ReliableSender(policy=RetryPolicy(timeout_s=0.125, max_tries=max_tries))
    told: list[Command] = []
    tries_when_settled: dict[int, int] = {}

    def on_settled(cmd: Command) -> None:
        assert id(cmd) not in tries_when_settled, f"{cmd!r} settled twice"
        tries_when_settled[id(cmd)] = cmd.tries
        told.append(cmd)
        if len(told) - 1 == react_at:  # the react_at-th settlement: the caller reacts inside poll
            if reaction == "abandon":
                sender.abandon(now, "link lost")
            else:
                cmds.append(sender.send(reaction, now)[0])

    sender.on_settled = on_settled
    now = 0.0
    cmds: list[Command] = []
    for message in first:  # a newer one may supersede an older one already: told, too
        cmds.append(sender.send(message, now)[0])
    deframer = Deframer()
    _one_pending_per_setting(sender)
    while sender.pending:
        deadline = sender.next_deadline()
        assert deadline is not None
        now = deadline
        for frame in deframer.feed(sender.poll(now)):
            assert isinstance(frame, Frame)
            [cmd] = [c for c in cmds if c.key == (frame.msg_id, frame.seq)]
            assert cmd.state is CommandState.PENDING, f"{cmd!r} sent again after it was settled"
        _one_pending_per_setting(sender)
    for cmd in cmds:
        assert cmd.state is not CommandState.PENDING
        assert tries_when_settled[id(cmd)] == cmd.tries, f"{cmd!r} tried again after it was settled"
        assert cmd.tries <= max_tries
    assert len(told) == len(cmds) == sender.stats.acked + sender.stats.nacked + sender.stats.failed


def _one_pending_per_setting(sender: ReliableSender) -> None:
    """At most one pending command sets each thing (``SETS``): the newest; older ones are superseded."""
    settings_pending = [c.message.SETS for c in sender.pending]
    assert len(settings_pending) == len(set(settings_pending)), sender.pending
