"""The C firmware's answers are never crowded out of its transmit ring by what it sends again anyway.

At 115200 baud, six units' telemetry and a download the host does not acknowledge (retried) keep the
firmware's 1 KiB transmit ring full. A frame that finds no room is dropped, and the differential fuzz
(tests/test_firmware_differential.py, seed 44) found a Hello left without its HelloReply, where the
emulator's 64 KiB answered it. Telemetry, heartbeats and download fragments now leave the ring's last
``SAID_ONCE_ROOM`` bytes (firmware/src/report.c) to answers and Logs.

Drawn: the configuration (up to six units, 490 Hz frames, 100 Hz telemetry), and commands (SetMode,
Arm, Disarm, a heartbeat, at most one Hello) sent alone or in bursts at drawn moments while the
download runs.
Invariant: every Hello gets its HelloReply and every reliable command exactly one answer.
"""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from firmware_lockstep_support import Host, loaded_configs
from hypothesis import HealthCheck, given, settings

from protocol.messages import (
    SCHEMA_HASH,
    Arm,
    CalibrationRequest,
    ControlMode,
    Disarm,
    Heartbeat,
    Hello,
    SetMode,
)

HELLO = Hello(schema_hash=SCHEMA_HASH, manufacturer="tx", model="answers", serial="T1")

commands = st.sampled_from(
    [SetMode(mode=ControlMode.SETPOINT), Arm(), Disarm(), Heartbeat(time_ms=0, state=0)]
)
# at most one Hello a burst: a host waits for its reply (~240 bytes, 21 ms of line), and four unanswered
# Hellos at once would ask for more than the whole ring
bursts = st.tuples(
    st.lists(commands, max_size=6).flatmap(
        lambda cmds: st.integers(0, len(cmds)).flatmap(
            lambda at: st.sampled_from([cmds, [*cmds[:at], HELLO, *cmds[at:]]])
        )
    ),
    st.sampled_from([0.0, 0.003, 0.02, 0.1]),
)


@pytest.mark.firmware
@settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
@given(config=loaded_configs, plan=st.lists(bursts, min_size=1, max_size=6))
def test_every_hello_and_reliable_command_is_answered_while_the_ring_is_full(config, plan):
    host = Host(config)
    hellos = 1
    reliable: list[tuple[int, int]] = []
    try:
        host.run(0.15)
        host.send(HELLO, flags=0)
        host.run(0.1)
        (seq,) = host.send(CalibrationRequest(unit=config.n_units - 1, transfer_id=3))  # never acknowledged
        reliable.append((CalibrationRequest.MSG_ID, seq))
        host.run(0.01)
        for burst, pause in plan:
            for msg in burst:
                if isinstance(msg, Hello):
                    host.send(msg, flags=0)
                    hellos += 1
                elif isinstance(msg, Heartbeat):
                    host.send(msg, flags=0)
                else:
                    (seq,) = host.send(msg)
                    reliable.append((msg.MSG_ID, seq))
            host.run(pause, heartbeat_s=0.05)
        host.run(0.4, heartbeat_s=0.05)  # the queue ahead of the last answers drains (89 ms a full ring)
    finally:
        host.close()
    assert host.hello_replies == hellos
    not_once = {key: host.answers.get(key, []) for key in reliable if len(host.answers.get(key, [])) != 1}
    assert not not_once, f"reliable commands not answered exactly once: {not_once}"
