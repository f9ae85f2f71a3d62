"""The C firmware (on simavr, in lockstep) at the shortest MCU watchdog it takes (``MCU_WATCHDOG_MIN_S``):
host input alone never resets it. Calibration sets uploaded to unit after unit, while the sets already
acknowledged are still being written to EEPROM, on boards from light to the heaviest load the tests put
on the main loop (up to six units, 490 Hz frames, 100 Hz telemetry): every fragment answered exactly once,
no reset, and every set stored is whole after a fresh boot.

What a hunt found: the floor was 15 ms. Below 32 ms the main loop itself restarts the 16 ms hardware
watchdog, and a set reassembled, validated and stored takes ~33 ms of one pass: at 15–30 ms three uploads
in a row reset the board by its watchdog, one fragment went unanswered, and the set of another unit, which
the board had acknowledged, came back damaged from EEPROM ("upload one before arming").
"""

from __future__ import annotations

import dataclasses

import hypothesis.strategies as st
import pytest
from firmware_lockstep_support import Host, loaded_configs
from hypothesis import HealthCheck, given, settings

from firmware_sim.board.config import MCU_WATCHDOG_MIN_S
from protocol.calibration import default_unit_calibration, fragment
from protocol.messages import SCHEMA_HASH, CalibrationData, Hello


@pytest.mark.firmware
@settings(max_examples=6, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(config=loaded_configs, gap_s=st.sampled_from([0.0, 0.01, 0.05]))
def test_uploads_unit_after_unit_never_trip_the_shortest_watchdog(config, gap_s):
    config = dataclasses.replace(config, mcu_watchdog_s=MCU_WATCHDOG_MIN_S)
    set_bytes = default_unit_calibration().to_bytes()
    host = Host(config)
    try:
        host.run(0.15)
        host.send(Hello(schema_hash=SCHEMA_HASH, manufacturer="wd", model="floor", serial="W1"), flags=0)
        host.run(0.05)
        sent: list[int] = []
        for unit in range(config.n_units):
            # a unit's fragments, then its answers waited for, as BoardClient.upload_calibration does: the
            # next unit's set comes while the sets before it are still being written to EEPROM (what
            # made the main loop's pass long). (Streamed unit after unit without waiting, a 4-unit board
            # at 250 Hz overflows its 384-byte receive ring whatever its watchdog: the host retries those.)
            mine = []
            for part in fragment(unit, 10 + unit, set_bytes):
                mine += host.send(part)
                host.run(gap_s + 0.001, heartbeat_s=0.05)
            for _ in range(50):
                if all((CalibrationData.MSG_ID, seq) in host.answers for seq in mine):
                    break
                host.run(0.01, heartbeat_s=0.05)
            sent += mine
        host.run(2.0, heartbeat_s=0.05)  # the EEPROM writes finish (3.3 ms a byte)
        resets = [r for r in host.board.resets[1:]]  # the first is the power-on boot
        assert not resets, [(round(r.t, 3), r.cause.name) for r in resets]
        answers = {seq: host.answers.get((CalibrationData.MSG_ID, seq), []) for seq in sent}
        assert all(len(said) == 1 for said in answers.values()), answers
        assert not [text for text in host.logs if "damaged" in text], host.logs
    finally:
        host.close()
