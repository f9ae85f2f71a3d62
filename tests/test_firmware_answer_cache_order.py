"""The C firmware's answer cache against the emulator's, with the host's sequence numbers reused (they wrap
at 256, so a key — message id and sequence number — comes back): the last 32 answers, in the order they
were *given*, each retransmission within them answered from the cache, never carried out again.

What a hunt found: the firmware's cache answered a reused key in its old slot of the ring, so it was
overwritten up to 31 answers early, and a late retransmission of an Arm the board had answered since —
after the operator's Disarm — was carried out again: the firmware armed a disarmed board, the emulator
(an ordered dict, the key moved to the newest) answered it from its cache. Both now keep the same order
(``firmware/src/link.c``, ``answers_remember``).
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_firmware_differential import RELIABLE, RETRY, Pair, hello

from firmware_sim.board.config import BoardConfig
from protocol.messages import Arm, BoardState, ControlMode, Disarm, SetMode


def _late_arm_after_disarm(pair: Pair, commands_between: int) -> None:
    """An Arm at seq 5 and a Disarm at 6; the same key reused by a new Arm after the sequence wrapped;
    ``commands_between`` other commands; the operator's Disarm; then the seq-5 Arm retransmitted late."""
    pair.run(0.15)
    pair.send(hello(), 0, seq=0)
    pair.run(0.05)
    pair.send(Arm(), RELIABLE, seq=5)
    pair.run(0.02)
    pair.send(Disarm(), RELIABLE, seq=6)
    pair.run(0.02)
    pair.send(Arm(), RELIABLE, seq=5)  # the same key again, not flagged a retransmission: carried out
    pair.run(0.02)
    for k in range(commands_between):
        pair.send(SetMode(mode=ControlMode.SETPOINT), RELIABLE, seq=6 + k)
        pair.run(0.012)
    pair.send(Disarm(), RELIABLE, seq=6 + commands_between)
    pair.run(0.03)
    assert pair.fw.state is pair.py.state is BoardState.DISARMED
    pair.send(Arm(), RETRY, seq=5)  # the seq-5 Arm, retried late
    pair.run(0.05)


@pytest.mark.firmware
@pytest.mark.parametrize("commands_between", [1, 30, 31])
def test_a_late_retransmission_of_a_reused_key_is_answered_from_the_cache_on_both(commands_between):
    """Within the last 32 answers (the reused Arm's and up to 30 SetModes and the Disarm after it) the late
    retry is answered from the cache on both: the board stays DISARMED. One command more and its answer
    is no longer held: carried out anew, on both alike."""
    pair = Pair(BoardConfig())
    try:
        _late_arm_after_disarm(pair, commands_between)
        pair.compare(final=True)
        held = commands_between + 1 < 32  # the answers given after the reused Arm's
        expected = BoardState.DISARMED if held else BoardState.ARMED
        assert pair.fw.state is pair.py.state is expected
    finally:
        pair.close()


@pytest.mark.firmware
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.tuples(st.sampled_from(["arm", "disarm", "setmode"]), st.integers(0, 40), st.booleans()),
        min_size=1,
        max_size=70,
    )
)
def test_reliable_commands_with_reused_keys_are_answered_alike(commands):
    """Any sequence of reliable commands over a few sequence numbers (keys come back often), some flagged
    retransmissions: the firmware and the emulator give the same answers and end in the same state."""
    messages = {"arm": Arm(), "disarm": Disarm(), "setmode": SetMode(mode=ControlMode.SETPOINT)}
    pair = Pair(BoardConfig())
    try:
        pair.run(0.15)
        pair.send(hello(), 0, seq=0)
        pair.run(0.05)
        for name, seq, retransmit in commands:
            pair.send(messages[name], RETRY if retransmit else RELIABLE, seq=seq)
            pair.run(0.012)
        pair.run(0.05)
        pair.compare(final=True)
        assert pair.fw.state is pair.py.state
    finally:
        pair.close()
